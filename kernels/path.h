// path.h: the events of a camera path's vertex, one function each, in the
// order trace_paths (trace.cl) runs them:
//   path_start         a new camera ray
//   vertex_make        the surface the ray hit: point, normals, material, lobe probabilities
//   path_emission      emission found there, weighted by multiple importance
//                      sampling against light sampling and photon merging
//   path_photons       the photon map there: the gather at x, or a merge (CLPT_PHOTONS)
//   path_direct_light  next event estimation: a light sample, its weight, its shadow ray (CLPT_NEE)
//   path_scatter       a lobe and direction from the BSDF (bsdf.h), the next ray
//   path_class_update  where the path stands relative to the photon map's paths (CLPT_PHOTONS)
// Each works on the lanes its masks say and leaves the others as they were.
//
// Estimator: path tracing with next event estimation at every vertex with a
// non-delta lobe (CLPT_NEE), weighted against BSDF sampling by multiple
// importance sampling (power heuristic): emission found by a BSDF-sampled
// ray after a non-delta lobe is weighted by pdf_bsdf^2 / (pdf_bsdf^2 +
// pdf_light^2) and the light sample by the complement; after the camera or
// a delta lobe (which light sampling cannot reach) emission counts whole.
// A material's lobe is chosen by Russian roulette over kd, ks, kr, kt and
// absorption, as in the paper; before depth rr_depth the absorption branch
// is left out (lobe probabilities renormalized).
//
// Caustic photons (CLPT_PHOTONS; what a launch does is its PhotonLookup's
// choice, clpt/photons.py):
//   merge: photon merging at every vertex with a non-delta part, weighted by
//     multiple importance sampling against path tracing, for the paths both
//     can make: ... x D S+ L, where D is a non-delta vertex and S+ purely
//     specular ones (the paths trace_photons stores, L S+ D). With p_pt the
//     BSDF pdf at x of the direction towards the specular chain and p_m = pf
//     cos mis_k (pf = the photon's light-side pdf p_area p_dir / cos at the
//     light, mis_k = pi r^2 N photons), the merge gets p_m^2 / (p_m^2 +
//     p_pt^2) and the path-traced hit of the light at the end of the chain
//     the complement, both computed by the same function of the path, so the
//     two add up to one technique's worth (vertex merging, Georgiev et al.
//     2012, without connections).
//   owns: the photon map owns exactly the paths E S* x D S+ L where x is the
//     first vertex from the camera with a non-delta part; emission reached
//     along an owned path is not added. With gather, x gathers in every
//     sample (online); without, a per-pixel caustic buffer the host adds
//     does (offline). stop_at_x is the offline pre-pass: follow the camera
//     path to x, gather there, and stop.
//   Past x (owns), or past the first merge_vertices non-delta vertices
//   (merge), the vertices with a non-delta part gather the delta lights'
//   photons alone: path tracing cannot make the paths that end on those
//   lights (caustics seen after a diffuse bounce).

// Where a path stands relative to the photon map's paths (owns).
#define OWN_BEFORE_X 0  // no vertex with a non-delta part yet
#define OWN_AFTER_D 1   // x chose its non-delta lobe
#define OWN_OWNED 2     // ... and one or more purely specular vertices followed
#define OWN_NOT 3       // not a photon-map path

// Where a path stands relative to the paths photon merging can make (merge).
#define CHAIN_NONE 0    // the last vertex was not a non-delta lobe, nor after one via delta vertices
#define CHAIN_AFTER_D 1 // the last vertex chose a non-delta lobe
#define CHAIN_IN 2      // ... then one or more purely specular vertices followed

typedef struct {
    V3 o, d;         // current ray
    V3 beta;         // path throughput
    V3 L;            // radiance gathered so far by this sample
    vreal depth;     // scattering events so far
    vmask specular;  // last vertex was the camera or a delta lobe
    vreal pdf_prev;  // solid-angle pdf of the last BSDF sample; 0 after the camera or a delta lobe
    V3 x_prev;       // the last scattering vertex (for the light pdf of a BSDF-sampled hit)
    vreal own;       // OWN_*: relation to the owned photon map's paths
    vreal chain;     // CHAIN_*: relation to the paths photon merging can make
    vreal chain_k;   // at the last non-delta vertex: mis_k cos / pdf_bsdf of the direction taken
                     // (0 where no merge happened there); times pf at the light: p_m / p_pt
    vreal nd_count;  // vertices with a non-delta part met so far (merges at the first merge_vertices)
    vmask skip_le;   // the emission this ray meets was taken whole at its vertex (path_glass_split)
} PathState;

// A vertex: the surface a path's ray hit.
typedef struct {
    Hit h;
    Material m;
    LobeProbs pr;      // the lobes' probabilities at this depth
    V3 x;              // the point
    V3 n, ng;          // shading and geometric normals, on the side of the incoming ray
    vmask hit, front;  // the ray hit something; it hit the front face (the normal's side)
    vmask nondelta;    // the surface has a diffuse, Phong or microfacet part
    vmask at_x;        // (photons) the first vertex with a non-delta part
    vmask merge_here;  // (photons) a vertex where merging may happen
    vmask split;       // (glass) the camera's first vertex on smooth glass: path_glass_split
#if CLPT_HAS_ENV_LIGHT
    vmask escaped;     // the ray left the scene (it sees the environment)
#endif
} Vertex;

inline PathState path_state_make(vmask active)
{
    PathState ps;
    ps.o = ps.d = ps.beta = ps.L = ps.x_prev = v3_zero();
    ps.depth = ps.pdf_prev = ps.own = ps.chain = ps.chain_k = ps.nd_count = (vreal)R(0);
    ps.specular = active;
    ps.skip_le = active && !active;
    return ps;
}

// A new camera ray through (px, py) + u of the image for the lanes in start.
inline void path_start(PathState *ps, const CameraRec *cam, vreal px, vreal py, CameraU u, vmask start)
{
    V3 d = camera_ray(cam->corner, cam->dx, cam->dy, px + u.x, py + u.y);
    ps->o = v3_sel(ps->o, v3_splat(cam->origin), start);
    ps->d = v3_sel(ps->d, d, start);
    ps->beta = v3_sel(ps->beta, v3((vreal)R(1), (vreal)R(1), (vreal)R(1)), start);
    ps->L = v3_sel(ps->L, v3_zero(), start);
    ps->depth = VSEL(ps->depth, (vreal)R(0), start);
    ps->own = VSEL(ps->own, (vreal)R(0), start);
    ps->chain = VSEL(ps->chain, (vreal)R(0), start);
    ps->pdf_prev = VSEL(ps->pdf_prev, (vreal)R(0), start);
    ps->nd_count = VSEL(ps->nd_count, (vreal)R(0), start);
    ps->specular = ps->specular || start;
    ps->skip_le = ps->skip_le && !start;
}

// The vertex at hit h of the lanes in `active` (rr_depth: the depth from
// which absorption may end paths).
inline Vertex vertex_make(const Scene *sc, const PathState *ps, Hit h, vmask active, uint rr_depth)
{
    Vertex v;
    v.h = h;
    v.hit = active && h.t < R(INFINITY);
    v.m = material_fetch(sc, h.mat);
#if CLPT_HAS_TEXTURES
    material_textures(sc, &v.m, &h, v.hit);
#endif
#if CLPT_HAS_TEXTURED_EMITTERS
    emitter_textures_hit(sc, &v.m, &h, v.hit);
#endif
    v.x = v3_fma(ps->d, h.t, ps->o);
    v.front = v3_dot(h.ng, ps->d) < R(0);
    v.ng = v3_sel(v3_neg(h.ng), h.ng, v.front);  // faces the incoming ray
    v.n = hit_shading_normal(sc, &h, v.ng);      // smooth triangles: the interpolated normal
#if CLPT_MITSUBA_SHADING
    shading_from_behind(&v.m, &v.n, ps->d, v.hit && h.nrm >= R(0));
#endif
#if CLPT_HAS_ANISOTROPY
    material_tangent(sc, &v.m, &h, v.n, v.hit);  // the microfacet lobes' shading frame
#endif
    material_face(&v.m, v.front);
    v.pr = lobe_probs(&v.m, ps->depth < (real)rr_depth);
    v.nondelta = v.hit && v.m.nondelta != R(0);
    v.at_x = v.merge_here = v.split = v.hit && !v.hit;
#if CLPT_HAS_ENV_LIGHT
    v.escaped = active && !(h.t < R(INFINITY));
#endif
    return v;
}

// Emission at the vertex towards the path, times the throughput and its
// multiple-importance weight; *sees: the lanes it reaches (an emitter's
// side that emits; not a path the photon map owns). A ray that left the
// scene sees the environment, weighted against light sampling and photon
// merging as an emitter's hit is.
inline V3 path_emission(const Scene *sc, const PhotonLookup *pl, const PathState *ps, const Vertex *v,
                             vmask *sees)
{
    vmask s = v->hit && (v->front || v->m.two_sided != R(0));
    vreal w = (vreal)R(1);
#if CLPT_NEE
    // After a non-delta lobe light sampling could have found this point too.
    vmask bsdf_hit = s && ps->pdf_prev > R(0) && v->h.light > R(0);
    if (VANY(bsdf_hit)) {
        vreal pdf_l = light_pdf_hit(sc, v->h.light, ps->x_prev, v->x, v->h.ng, v->h.t);
        w = VSEL(w, mis_power(ps->pdf_prev, pdf_l), bsdf_hit);
    }
#endif
#if CLPT_PHOTONS
    if (pl->owns)
        s = s && ps->own != (real)OWN_OWNED && !pl->stop_at_x;
    // At the end of a purely specular chain from a non-delta vertex that
    // merged, photon merging could have made this path too.
    vmask merged_path = s && ps->chain == (real)CHAIN_IN && ps->chain_k > R(0) && v->h.light > R(0);
    if (pl->merge && VANY(merged_path)) {
        vreal pf = light_photon_pdf(sc, v->h.light, v->x, v->h.ng, v3_neg(ps->d), v->m.two_sided != R(0), pl->aim);
        w = VSEL(w, mis_power((vreal)R(1), pf * ps->chain_k), merged_path);
    }
#endif
    V3 Le = v3_scale(v3_mul(ps->beta, v->m.Le), w);
#if CLPT_HAS_ENV_LIGHT
    vmask esc = v->escaped;
#if CLPT_PHOTONS
    esc = esc && !pl->stop_at_x;
    if (pl->owns)
        esc = esc && ps->own != (real)OWN_OWNED;
#endif
    if (VANY(esc)) {
        vreal pdf_l;
        V3 Lenv = env_emission(sc, ps->d, esc, &pdf_l);
        vreal we = (vreal)R(1);
#if CLPT_NEE
        we = VSEL(we, mis_power(ps->pdf_prev, pdf_l), ps->pdf_prev > R(0));
#endif
#if CLPT_PHOTONS
        // After a merge and a purely specular chain: the environment's photons could have made this path too.
        vmask merged_esc = esc && ps->chain == (real)CHAIN_IN && ps->chain_k > R(0);
        if (pl->merge && VANY(merged_esc))
            we = VSEL(we, mis_power((vreal)R(1), env_photon_pdf(sc, ps->o, ps->d, pdf_l) * ps->chain_k), merged_esc);
#endif
        Le = v3_sel(Le, v3_scale(v3_mul(ps->beta, Lenv), we), esc);
        s = s || esc;
    }
#endif
    *sees = s;
    return Le;
}

#if CLPT_PHOTONS
// The photon map at the vertex: the gather at x (gather), and merges at
// vertices with a non-delta part (merge), added to ps->L and to the caustic
// features; marks v->at_x and v->merge_here for path_class_update. The
// offline pre-pass ends paths at x (*go). A vertex merges with probability
// merge_p (Russian roulette on the technique, which bounds its cost); the
// weights count that in (the host folds it into mis_k), so both sides still
// see the same pdfs.
inline void path_photons(const PhotonMap *pm, const PhotonLookup *pl, PathState *ps, Vertex *v,
                              const Sampler *sp, vreal max_depth, vmask *go, VisibleSurface *vis, real lum_scale)
{
    // x is the first vertex with a non-delta part, if the map can estimate it there.
    vmask first_nd = v->hit && ps->own == (real)OWN_BEFORE_X && v->m.nondelta != R(0);
    v->at_x = first_nd && material_mergeable(&v->m);
    if (pl->gather && VANY(v->at_x)) {
        vreal m2;  // (no moments: the gather does not merge)
        V3 Lc = photon_gather(pm, &v->m, v->pr, v->x, v->n, ps->d, sample_merge(sp, ps->depth), v->at_x, 0,
                              max_depth - ps->depth - R(1), v3_zero(), &m2);
        ps->L = v3_sel(ps->L, v3_add(ps->L, v3_mul(ps->beta, Lc)), v->at_x);
#if CLPT_AUX
        visible_add_caustic(vis, v3_mul(ps->beta, Lc), v->at_x, lum_scale);
#endif
    }
    if (pl->stop_at_x)  // (a path whose first non-delta vertex is not x has nothing to gather either)
        *go = *go && !first_nd;

    v->merge_here = *go && v->nondelta && material_mergeable(&v->m) && ps->nd_count < (real)pl->merge_vertices;
    if (pl->merge && VANY(v->merge_here)) {
        vreal u = sample_merge(sp, ps->depth);
        vmask merges = v->merge_here && u < pl->merge_p;
        if (VANY(merges)) {
            V3 lw = v3_zero();  // the luminance weights of the merge's contributions, for the moments
#if CLPT_AUX
            if (pl->moments) {  // (photon_grid.h; only the pilot's trial asks)
                lw = v3_scale(ps->beta, lum_scale / pl->merge_p);
                lw.x *= R(CLPT_LUMA_R); lw.y *= R(CLPT_LUMA_G); lw.z *= R(CLPT_LUMA_B);
            }
#endif
            vreal m2;
            V3 Lm = photon_gather(pm, &v->m, v->pr, v->x, v->n, ps->d, u / pl->merge_p, merges, 1,
                                  max_depth - ps->depth - R(1), lw, &m2);
            ps->L = v3_sel(ps->L, v3_fma(v3_mul(ps->beta, Lm), R(1) / pl->merge_p, ps->L), merges);
#if CLPT_AUX
            if (pl->moments) {
                // The pilot's trial: the caustic plane's w sums path tracing's second moment for
                // the merged paths (in lum_scale^2 units, as the squares it otherwise holds).
                // With merge probability p, a merge adds (c / p)^2 / q with q's p_m counting p:
                // its expectation over the coin is the moment of one sample.
                v3_add_where(&vis->caustic, v3_scale(v3_mul(ps->beta, Lm), R(1) / pl->merge_p),
                             merges && ps->nd_count == R(0));
                vreal_add_where(&vis->caustic_sq, m2, merges && isfinite(m2));
            } else {
                // The merge at the first non-delta vertex: the caustic as seen.
                visible_add_caustic(vis, v3_scale(v3_mul(ps->beta, Lm), R(1) / pl->merge_p),
                                    merges && ps->nd_count == R(0), lum_scale);
            }
#endif
        }
    }
#if CLPT_HAS_DELTA_LIGHTS
    // The paths ... y D S+ L that end on a delta light (point, spot,
    // directional) are path tracing's at no vertex (no ray hits such a
    // light): where neither the gather at x nor a merge covers y (an owned
    // map past x; merging past the first merge_vertices non-delta vertices),
    // y's photons from delta lights (pf = inf) count whole, as a merge
    // gives them whole.
    vmask delta_only = *go && v->nondelta && material_mergeable(&v->m);
    if (pl->owns)
        delta_only = delta_only && !v->at_x;
    else
        delta_only = delta_only && ps->nd_count >= (real)pl->merge_vertices;
    if ((pl->owns || pl->merge) && VANY(delta_only)) {
        vreal m2;
        V3 Ld = photon_gather(pm, &v->m, v->pr, v->x, v->n, ps->d, sample_merge(sp, ps->depth), delta_only, 2,
                              max_depth - ps->depth - R(1), v3_zero(), &m2);
        ps->L = v3_sel(ps->L, v3_add(ps->L, v3_mul(ps->beta, Ld)), delta_only);
    }
#endif
    ps->nd_count = VSEL(ps->nd_count, ps->nd_count + R(1), v->nondelta);
}
#endif

// Next event estimation at the vertex for the lanes in nee: a light sample
// weighted against BSDF sampling by the power heuristic, added to ps->L
// where its shadow ray is clear. Returns the shadow rays traced.
inline uint path_direct_light(const Scene *sc, PathState *ps, const Vertex *v, vmask nee, const Sampler *sp)
{
    if (!VANY(nee))
        return 0;
    LightSample ls;
    light_sample(sc, v->x, sample_light(sp, ps->depth), 1, nee, &ls);
    vreal cos_x = v3_dot(v->n, ls.wi);
#if CLPT_HAS_ROUGH_DIELECTRIC
    // A rough dielectric also sees lights through itself (both normals agreeing).
    vmask through = v->m.p_g > R(0) && cos_x < R(0) && v3_dot(v->ng, ls.wi) < R(0);
    nee = nee && ls.valid && ((cos_x > R(0) && v3_dot(v->ng, ls.wi) > R(0)) || through);
    cos_x = fabs(cos_x);
#else
    nee = nee && ls.valid && cos_x > R(0) && v3_dot(v->ng, ls.wi) > R(0);
#endif
    if (!VANY(nee))
        return 0;
    vreal pdf_b;
    V3 f = bsdf_eval_pdf(&v->m, v->pr, ps->d, v->n, ls.wi, &pdf_b);
    vreal w = mis_power(ls.pdf, pdf_b);
#if CLPT_HAS_DELTA_LIGHTS
    w = VSEL(w, (vreal)R(1), ls.delta);  // no BSDF sample finds a point or spot light
#endif
    V3 c = v3_mul(v3_mul(ps->beta, f), v3_scale(ls.Le, w * cos_x / ls.pdf));
    // The shadow ray runs from the offset origin to the light point itself:
    // aimed along wi from there instead, it would cut into a sphere light
    // near its silhouette and see the light block itself.
#if CLPT_HAS_ROUGH_DIELECTRIC
    V3 so = offset_origin(sc, v->x, v3_sel(v->ng, v3_neg(v->ng), through), v->h.err);
#else
    V3 so = offset_origin(sc, v->x, v->ng, v->h.err);
#endif
    V3 to = v3_sub(ls.p, so);
    vreal len = sqrt(v3_dot(to, to));
    vmask blocked = scene_occluded(sc, so, v3_scale(to, R(1) / len), len * R(0.9999), nee);
    ps->L = v3_sel(ps->L, v3_add(ps->L, c), nee && !blocked);
    return vpopcount(nee);
}

#if CLPT_HAS_GLASS
// Splitting at the camera's first vertex on smooth glass (a material of
// delta lobes with a dielectric one, lanes in go at depth 0; v->split):
// the emission its reflection meets next (a lamp reflected in the glass)
// is taken in every sample, with the reflection's expected weight kr + F kt
// (the mirror lobe's and the dielectric's, which reflect alike), instead
// of whole in the share F of samples the Fresnel coin sends that way (a
// sample that reflects leaves that emission out: ps->skip_le, set by
// path_scatter). Same expectation; the reflection of a lamp in a glass ball
// is then seen by every sample instead of one in 10-25 (F = 0.04-0.1), so
// its pixels are no longer noise to the denoisers (the lamp's emission is
// confirmed and kept out of the filtering: clpt/denoise.py). One more ray
// for the lanes on glass: the emission is added to ps->L and to the
// features' (those that see a lamp counted); returns the rays traced.
inline uint path_glass_split(const Scene *sc, const PhotonLookup *pl, PathState *ps, Vertex *v, vmask go,
                             VisibleSurface *vis)
{
    v->split = go && ps->depth == R(0) && v->m.nondelta == R(0) && v->pr.t > R(0);
    if (!VANY(v->split))
        return 0;
    // The reflection as path_scatter makes it (bsdf_sample's dielectric lobe, offset_scattered,
    // keep_geometric_side), so the ray is the one the coin's reflection would trace.
    vreal e = VSEL(R(1) / v->m.ior, v->m.ior, v->front);
    vreal cos_t;
    vreal F = fresnel_dielectric(-v3_dot(ps->d, v->n), e, &cos_t);
    V3 d = v3_normalize(v3_reflect(ps->d, v->n));
    V3 o = offset_scattered(sc, v->x, v->n, d, v->h.err);
    keep_geometric_side(sc, &o, &d, v->x, v->n, v->ng, v->split && v->h.nrm >= R(0), v->h.err);
    // The hit as path_emission reads it, without the rest of vertex_make (a
    // second inlined copy of it lengthened the glass scenes' builds by a
    // quarter): point, faces, material (emitter textures applied). After the
    // camera and a delta lobe every weight is 1 and the path is not the
    // photon map's, as path_state_make leaves it.
    PathState r = *ps;
    r.o = o;
    r.d = d;
    r.beta = v3_mul(ps->beta, v3_fma(v->m.kt, F, v->m.kr));
    r.pdf_prev = (vreal)R(0);
    Vertex w;
    w.h = scene_intersect_active(sc, o, d, v->split);
    w.hit = v->split && w.h.t < R(INFINITY);
    w.m = material_fetch(sc, w.h.mat);
#if CLPT_HAS_TEXTURED_EMITTERS
    emitter_textures_hit(sc, &w.m, &w.h, w.hit);
#endif
    w.x = v3_fma(d, w.h.t, o);
    w.front = v3_dot(w.h.ng, d) < R(0);
#if CLPT_HAS_ENV_LIGHT
    w.escaped = v->split && !(w.h.t < R(INFINITY));
#endif
    vmask sees;
    V3 Le = path_emission(sc, pl, &r, &w, &sees);
    sees = sees && v->split;
    ps->L = v3_sel(ps->L, v3_add(ps->L, Le), sees);
#if CLPT_AUX
    visible_add_split(vis, Le, sees, w.hit && emitter_facing(&w.m, w.front));
#endif
    return vpopcount(v->split);
}
#endif

// Scattering at the vertex for the lanes in go: a lobe and a direction from
// the BSDF, the throughput, and the next ray (kept on the side of the
// geometric surface its lobe meant). Returns the lanes whose path goes on.
inline vmask path_scatter(const Scene *sc, PathState *ps, const Vertex *v, vmask go, BsdfU u)
{
    BsdfSample bs;
    bsdf_sample(&v->m, v->pr, ps->d, v->n, v->front, go, u, TRANSPORT_RADIANCE, 1, &bs);
    vmask cont = go && bs.chosen;
    ps->beta = v3_sel(ps->beta, v3_mul(ps->beta, bs.weight), cont);
    ps->o = v3_sel(ps->o, offset_scattered(sc, v->x, v3_sel(v3_neg(v->n), v->n, bs.up), bs.wi, v->h.err), cont);
    ps->d = v3_sel(ps->d, bs.wi, cont);
    ps->specular = VSEL(ps->specular, bs.delta, cont);
    ps->pdf_prev = VSEL(ps->pdf_prev, bs.pdf, cont);
    ps->x_prev = v3_sel(ps->x_prev, v->x, cont);
    cont = cont && v3_max_comp(ps->beta) > R(0);
    keep_geometric_side(sc, &ps->o, &ps->d, v->x, v->n, v->ng, cont && v->h.nrm >= R(0), v->h.err);
    ps->depth = VSEL(ps->depth, ps->depth + R(1), cont);
#if CLPT_HAS_GLASS
    ps->skip_le = cont && v->split && bs.delta && bs.up;  // (a reflection: the split took its emission)
#endif
    return cont;
}

#if CLPT_PHOTONS
// After scattering (cont: the lanes going on): x's lobe decides whether the
// path can be the photon map's, and after it only purely specular vertices
// keep it so (own); for merging, a non-delta lobe starts a chain (with its
// pdf, if a merge happened at this vertex), purely specular vertices extend
// it, and a delta lobe of a vertex with a non-delta part ends it (chain).
inline void path_class_update(PathState *ps, const Vertex *v, vmask cont, real mis_k)
{
    vmask pure_delta = v->m.nondelta == R(0);
    vreal own = ps->own;
    own = VSEL(own, VSEL((vreal)R(OWN_NOT), (vreal)R(OWN_AFTER_D), !ps->specular), v->at_x);
#if CLPT_HAS_MICROFACET || CLPT_HAS_PLASTIC || CLPT_HAS_ROUGH_DIELECTRIC
    // A first non-delta vertex the photon map cannot estimate (a microfacet
    // lobe, a plastic or a rough dielectric): the path is path tracing's alone.
    own = VSEL(own, (vreal)R(OWN_NOT), v->hit && ps->own == (real)OWN_BEFORE_X && v->nondelta &&
                                           !material_mergeable(&v->m));
#endif
    vmask after = ps->own == (real)OWN_AFTER_D || ps->own == (real)OWN_OWNED;
    own = VSEL(own, VSEL((vreal)R(OWN_NOT), (vreal)R(OWN_OWNED), pure_delta), after && v->hit);
    ps->own = own;
    vmask took_nd = v->nondelta && !ps->specular;
    vmask extend = pure_delta && (ps->chain == (real)CHAIN_AFTER_D || ps->chain == (real)CHAIN_IN);
    vreal chain = VSEL((vreal)R(CHAIN_NONE), (vreal)R(CHAIN_IN), extend);
    chain = VSEL(chain, (vreal)R(CHAIN_AFTER_D), took_nd);
    vreal cos_o = v3_dot(v->n, ps->d);
    vreal k = VSEL((vreal)R(0), mis_k * cos_o / ps->pdf_prev, v->merge_here && ps->pdf_prev > R(0));
    ps->chain_k = VSEL(ps->chain_k, k, took_nd);
    ps->chain = VSEL(ps->chain, chain, cont);
}
#endif
