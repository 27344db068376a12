// trace.cl: trace_paths, the path-tracing pass.
//
// Computes, for each pixel of a range, samples [sample_begin, sample_begin +
// n_samples) of the pixel's radiance estimate, and adds them one by one, in
// sample order, to the pixel's sums (accum.h). The order of additions
// never depends on how samples are split into launches or on the work-group
// size, so an image is bit-identical however it was scheduled.
//
// Launch: one work-item per group of CLPT_LANES consecutive pixels (row-major
// index group * CLPT_LANES + lane; with CLPT_TILE_W > 1, per tile of
// CLPT_TILE_W x CLPT_LANES / CLPT_TILE_W pixels, tiles in row-major order), each taking samples [sample_begin,
// sample_begin + n_samples) and max_depth; or, when n_list > 0 (adaptive
// sampling), one work-item per CLPT_LANES entries of pix_list, each entry a
// pixel with its own (samples, max depth, first sample index) in pix_jobs:
// the host continues each pixel's sample sequence where it stands. Global size = groups (or entries / CLPT_LANES),
// any local size. Each lane starts a new path as soon as its previous one
// ends, so lanes stay busy while paths have different lengths.
//
// Buffers:
//   scene     in   packed scene records (scene.h); unused when CLPT_BAKED
//   pix_sum   in/out  per pixel: sum r, sum g, sum b, sample count (accum.h)
//   pix_sq    in/out  per pixel: sum of squared luminance
//   stats     out  per work-item: non-finite samples dropped, camera rays,
//                  bounce rays, shadow rays (this launch)
//   pix_list, pix_jobs  in  adaptive passes: pixels, their (samples, depth, first sample)
//   aux_normal, aux_albedo, aux_emit, aux_caustic  in/out (CLPT_AUX): per
//                  pixel, sums over samples of the feature vertex's shading
//                  normal (w: count), of its albedo seen through the specular
//                  chain (rgb) and distance from the camera (w), of the
//                  emission reached up to and at that vertex (rgb; w: samples
//                  whose feature vertex is an emitter it sees), and of the
//                  photon map's contribution at the first vertex with a
//                  non-delta part (the gather there, or its merge; rgb; w: its
//                  squared luminance times lum_scale^2). The feature vertex is
//                  the first vertex with a non-delta part (aux_specular 0:
//                  mirrors and glass are seen through) or the first vertex (1:
//                  they are surfaces with albedo kr + kt). An emitter's albedo is its emission over its
//                  largest component, times the throughput; paths that meet no
//                  feature vertex get albedo 1 and no normal.
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
// Caustic photons (CLPT_PHOTONS, pm_mode):
//   PM_MERGE (1): photon merging at every vertex with a non-delta part,
//     weighted by multiple importance sampling against path tracing, for the
//     paths both can make: ... x D S+ L, where D is a non-delta vertex and S+
//     purely specular ones (the paths trace_photons stores, L S+ D). With
//     p_pt the BSDF pdf at x of the direction towards the specular chain and
//     p_m = pf cos mis_k (pf = the photon's light-side pdf p_area p_dir / cos
//     at the light, mis_k = pi r^2 N photons), the merge gets
//     p_m^2 / (p_m^2 + p_pt^2) and the path-traced hit of the light at the
//     end of the chain the complement, both computed by the same function of
//     the path, so the two add up to one technique's worth (vertex merging,
//     Georgiev et al. 2012, without connections).
//   PM_OWNED (2) / PM_OFFLINE (3): the photon map owns exactly the paths
//     E S* x D S+ L where x is the first vertex from the camera with a
//     non-delta part; 2 gathers at x in every sample, 3 leaves that to a
//     per-pixel caustic buffer the host adds; in both, emission reached along
//     an owned path is not added again. PM_PREPASS (4) is the offline
//     pre-pass: follow the camera path to x, gather there, and stop.
//   PM_OFF (0) ignores the photon map.
//
// Flags: CLPT_LANES, CLPT_TILE_W, CLPT_DOUBLE, CLPT_ACCUM_DOUBLE, CLPT_GENERIC, CLPT_BAKED, CLPT_NEE,
//   CLPT_PHOTONS, CLPT_AUX, CLPT_HAS_{SPHERES,QUADS,TRIANGLES,PLANES}, CLPT_HAS_{PHONG,MIRROR,GLASS},
//   CLPT_HAS_{TRIANGLE,SPHERE}_LIGHTS, CLPT_NUM_* (when not generic).

#define PM_OFF 0
#define PM_MERGE 1
#define PM_OWNED 2
#define PM_OFFLINE 3
#define PM_PREPASS 4

// Where a path stands relative to the photon map's paths.
#define OWN_BEFORE_X 0  // no vertex with a non-delta part yet
#define OWN_AFTER_D 1   // x chose its non-delta lobe
#define OWN_OWNED 2     // ... and one or more purely specular vertices followed
#define OWN_NOT 3       // not a photon-map path

// Where a path stands relative to the paths photon merging can make.
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
    vreal own;       // OWN_*: relation to the owned photon map's paths (PM_OWNED, PM_OFFLINE)
    vreal chain;     // CHAIN_*: relation to the paths photon merging can make (PM_MERGE)
    vreal chain_k;   // at the last non-delta vertex: mis_k cos / pdf_bsdf of the direction taken
                     // (0 where no merge happened there); times pf at the light: p_m / p_pt
} PathState;

// Path throughput after choosing and sampling one lobe of m at a hit.
// Returns the mask of lanes whose path goes on; writes the new ray, flags and
// the pdf of a non-delta direction (ps->pdf_prev, 0 for delta lobes).
inline vmask scatter(const Scene *sc, const Material *m, LobeProbs pr, PathState *ps, V3 x, V3 n, vmask front,
                     vmask go, Rand4 r, vreal x_err)
{
    // --- Russian roulette over the lobes --------------------------------------
    vreal c = r.a;
    vmask is_d = c < pr.d;
    vmask is_s = !is_d && c < pr.d + pr.s;
    vmask is_r = !is_d && !is_s && c < pr.d + pr.s + pr.r;
    vmask is_t = !is_d && !is_s && !is_r && c < pr.d + pr.s + pr.r + pr.t;
    V3 d = ps->d;

    // --- diffuse: cosine-weighted; f cos / pdf = kd ---------------------------
    V3 lc = sample_cosine_hemisphere(r.b, r.c);
    V3 wi = frame_to_world(n, lc.x, lc.y, lc.z);
    V3 w = v3_scale(m->kd, R(1) / pr.d);
    vmask up = go;  // the new ray leaves on the normal's side
#if CLPT_HAS_PHONG
    // --- Phong lobe around the mirror direction --------------------------------
    // f = ks (n+2)/(2 pi) cos^n(alpha), pdf = (n+1)/(2 pi) cos^n(alpha):
    // f cos_i / pdf = ks (n+2)/(n+1) cos_i; directions below the surface are lost.
    if (VANY(is_s)) {
        V3 rdir = v3_reflect(d, n);
        V3 ll = sample_phong_lobe(r.b, r.c, m->shininess);
        V3 ws = frame_to_world(rdir, ll.x, ll.y, ll.z);
        vreal cos_i = v3_dot(ws, n);
        vreal k = (m->shininess + R(2)) / (m->shininess + R(1)) * fmax(cos_i, R(0)) / pr.s;
        wi = v3_sel(wi, ws, is_s);
        w = v3_sel(w, v3_scale(m->ks, k), is_s);
        is_s = is_s && cos_i > R(0);
    }
#endif
#if CLPT_HAS_MIRROR
    // --- perfect mirror ------------------------------------------------------------
    wi = v3_sel(wi, v3_reflect(d, n), is_r);
    w = v3_sel(w, v3_scale(m->kr, R(1) / pr.r), is_r);
#endif
#if CLPT_HAS_GLASS
    // --- dielectric: Fresnel picks reflection or refraction ----------------------
    // eta = n_t / n_i: entering through the front face, or leaving through the back.
    if (VANY(is_t)) {
        vmask refl;
        vreal eta;
        V3 wt = dielectric_sample(d, n, front, m->ior, r.d, &refl, &eta);
        wi = v3_sel(wi, wt, is_t);
        // Radiance is scaled by 1/eta^2 across the interface (pbrt, sec. 9.5.2).
        vreal k = VSEL(R(1) / (eta * eta), (vreal)R(1), refl) / pr.t;
        w = v3_sel(w, v3_scale(m->kt, k), is_t);
        up = up && !(is_t && !refl);
    }
#endif
    vmask cont = go && (is_d || is_s || is_r || is_t);
    vmask nondelta = is_d || is_s;
    V3 wn = v3_normalize(wi);
    // The pdf of the direction under the whole non-delta mixture (what light
    // sampling's weight is measured against), not only the chosen lobe's.
    vreal pdf = VSEL((vreal)R(0), bsdf_pdf(m, pr, d, n, wn), nondelta);
    ps->beta = v3_sel(ps->beta, v3_mul(ps->beta, w), cont);
    ps->o = v3_sel(ps->o, offset_scattered(sc, x, v3_sel(v3_neg(n), n, up), wn, x_err), cont);
    ps->d = v3_sel(ps->d, wn, cont);
    ps->specular = VSEL(ps->specular, is_r || is_t, cont);
    ps->pdf_prev = VSEL(ps->pdf_prev, pdf, cont);
    ps->x_prev = v3_sel(ps->x_prev, x, cont);
    return cont && v3_max_comp(ps->beta) > R(0);
}

// Adds finished samples (lanes in `done`) to the pixel sums. A sample that is
// not finite is counted and left out: it never reaches the sums. The squares
// are of luminance times lum_scale (a power of two that brings the scene's
// brightest emission near 1), so they stay in float's range at any units.
inline void accumulate(vmask done, V3 L, real lum_scale, PixelAcc *acc, uint *nonfinite)
{
    vreal lum = v3_luminance(L) * lum_scale;
    vmask bad = done && !isfinite(L.x + L.y + L.z);
    *nonfinite += vpopcount(bad);
    vmask ok = done && !bad;
    acc_add(&acc->r, L.x, ok);
    acc_add(&acc->g, L.y, ok);
    acc_add(&acc->b, L.z, ok);
    acc_add(&acc->sq, lum * lum, ok);
    acc_add(&acc->n, (vreal)R(1), done);
}

#if CLPT_AUX
// Adds the photon map's part c of this sample (lanes in m, if finite) to the
// caustic feature sums: rgb and the squared luminance times lum_scale^2.
inline void aux_caustic_add(V3 c, vmask m, real lum_scale, vreal *r, vreal *g, vreal *b, vreal *sq)
{
    vreal l = v3_luminance(c) * lum_scale;
    vmask add = m && isfinite(c.x + c.y + c.z);
    *r = VSEL(*r, *r + c.x, add); *g = VSEL(*g, *g + c.y, add); *b = VSEL(*b, *b + c.z, add);
    *sq = VSEL(*sq, *sq + l * l, add);
}
#endif

__kernel void trace_paths(__global const real4 *scene, uint8 counts, real eps_abs, real lum_scale,
                          real4 cam_o, real4 corner, real4 dx, real4 dy,
                          uint width, uint height, uint group_offset,
                          uint sample_begin, uint n_samples, uint max_depth, uint rr_depth, uint seed,
                          __global pix_sum_t *pix_sum, __global pix_sq_t *pix_sq, __global uint4 *stats,
                          __global const uint *pix_list, __global const uint4 *pix_jobs, uint n_list
#if CLPT_AUX
                          , __global float4 *aux_normal, __global float4 *aux_albedo, __global float4 *aux_emit,
                          __global float4 *aux_caustic, uint aux_specular
#endif
#if CLPT_PHOTONS
                          , __global const float4 *ph_pos, __global const float4 *ph_dir,
                          __global const float4 *ph_pow, __global const uint *bucket_start,
                          uint pm_mask, uint pm_max, uint pm_budget, real pm_radius,
                          real pm_cone_k, uint pm_mode, real pm_mis_k, uint pm_merge_vertices, uint pm_aim, real pm_merge_p,
                          __global const uint *pm_occ, uint pm_occ_mask, real pm_inv_cell
#endif
                          )
{
    Scene scd = scene_make(scene, counts, eps_abs);
    const Scene *sc = &scd;
#if CLPT_PHOTONS
    PhotonMap pm;
    pm.pos = ph_pos; pm.dir = ph_dir; pm.pow = ph_pow;
    pm.bucket_start = bucket_start;
    pm.mask = pm_mask; pm.max_photons = pm_max;
    // The pre-pass gathers only a few times per pixel: subsampling noise would
    // not average out there, so it visits every photon.
    pm.budget = pm_mode == PM_PREPASS ? 0xFFFFFFFFu : pm_budget;
    pm.radius = pm_radius; pm.inv_cell = pm_inv_cell; pm.cone_k = pm_cone_k;
    pm.mis_k = pm_mis_k;
    pm.occ = pm_occ; pm.occ_mask = pm_occ_mask;
    int merge = pm_mode == PM_MERGE;
    int gather = pm_mode == PM_OWNED || pm_mode == PM_PREPASS;
    int prepass = pm_mode == PM_PREPASS;
    int owns = pm_mode == PM_OWNED || pm_mode == PM_OFFLINE || pm_mode == PM_PREPASS;
#endif

    uint gid = get_global_id(0);
    uint n_pix = width * height;
    vreal zero = (vreal)R(0);

    // --- the lanes' pixels, sample ranges and depth limits ---------------------------
    vuint pixel, s_begin;
    vreal lane_n, lane_depth;
    vmask pix_ok;
    if (n_list == 0) {
#if CLPT_TILE_W > 1
        // The lanes cover a tile of CLPT_TILE_W x (CLPT_LANES / CLPT_TILE_W) pixels;
        // work-items take tiles in row-major order.
        uint tiles_x = (width + CLPT_TILE_W - 1) / CLPT_TILE_W;
        uint tile = group_offset + gid;
        vuint px = (vuint)((tile % tiles_x) * CLPT_TILE_W) + VLANE_IDS % CLPT_TILE_W;
        vuint py = (vuint)((tile / tiles_x) * (CLPT_LANES / CLPT_TILE_W)) + VLANE_IDS / CLPT_TILE_W;
        pix_ok = VREAL(px) < (real)width && VREAL(py) < (real)height;
        pixel = py * width + px;
        for (int l = 0; l < CLPT_LANES; l++)
            if (!VLANE_M(pix_ok, l))
                VLANE_U(pixel, l) = 0xFFFFFFFFu;  // outside the image: no pixel
#else
        uint first = (group_offset + gid) * CLPT_LANES;
        pixel = (vuint)first + VLANE_IDS;
        pix_ok = VREAL(VLANE_IDS) < (real)(first < n_pix ? min(n_pix - first, (uint)CLPT_LANES) : 0u);
#endif
        s_begin = (vuint)sample_begin;
        lane_n = (vreal)(real)n_samples;
        lane_depth = (vreal)(real)max_depth;
    } else {
        pixel = s_begin = (vuint)0u;
        lane_n = lane_depth = zero;
        for (int l = 0; l < CLPT_LANES; l++) {
            uint e = gid * CLPT_LANES + l;
            uint p = e < n_list ? pix_list[e] : 0xFFFFFFFFu;
            uint4 job = e < n_list ? pix_jobs[e] : (uint4)(0u);
            VLANE_U(pixel, l) = p;
            VLANE_U(s_begin, l) = job.z;
            VLANE_R(lane_n, l) = (real)job.x;
            VLANE_R(lane_depth, l) = (real)job.y;
        }
        pix_ok = lane_n > zero;
    }
    vreal pxr = VREAL(pixel % width), pyr = VREAL(pixel / width);

    // Per-lane sums, read from and written back to this pixel's buffers.
    PixelAcc acc;
    pixel_acc_zero(&acc);
    for (int l = 0; l < CLPT_LANES; l++) {
        uint p = VLANE_U(pixel, l);
        if (p < n_pix)
            pixel_acc_load(&acc, l, pix_sum, pix_sq, p);
    }
#if CLPT_AUX
    // Feature sums: normal xyz + count, albedo rgb + distance.
    vreal fnx = zero, fny = zero, fnz = zero, fcount = zero, far = zero, fag = zero, fab = zero, fdist = zero;
    vreal fer = zero, feg = zero, feb = zero, flight = zero;
    vreal fcr = zero, fcg = zero, fcb = zero, fcsq = zero;  // the photon map's part, its squared luminance
    for (int l = 0; l < CLPT_LANES; l++) {
        uint p = VLANE_U(pixel, l);
        if (p < n_pix) {
            float4 a = aux_normal[p], b = aux_albedo[p], c = aux_emit[p], e = aux_caustic[p];
            VLANE_R(fnx, l) = a.x; VLANE_R(fny, l) = a.y; VLANE_R(fnz, l) = a.z; VLANE_R(fcount, l) = a.w;
            VLANE_R(far, l) = b.x; VLANE_R(fag, l) = b.y; VLANE_R(fab, l) = b.z; VLANE_R(fdist, l) = b.w;
            VLANE_R(fer, l) = c.x; VLANE_R(feg, l) = c.y; VLANE_R(feb, l) = c.z; VLANE_R(flight, l) = c.w;
            VLANE_R(fcr, l) = e.x; VLANE_R(fcg, l) = e.y; VLANE_R(fcb, l) = e.z; VLANE_R(fcsq, l) = e.w;
        }
    }
    vmask feat_done = zero != zero;  // this sample's features are recorded
    vreal path_len = zero;
#endif

    uint nonfinite = 0, n_camera = 0, n_bounce = 0, n_shadow = 0;
    vreal done_count = zero;  // samples finished per lane
    vmask active = pix_ok && lane_n > zero;
    vmask restart = active;

    PathState ps;
    ps.o = ps.d = ps.beta = ps.L = v3_zero();
    ps.depth = zero;
    ps.specular = active;
    ps.pdf_prev = zero;
    ps.x_prev = v3_zero();
    ps.own = ps.chain = ps.chain_k = zero;
    vreal nd_count = zero;  // vertices with a non-delta part met so far (merges allowed at the first pm_merge_vertices)

    while (VANY(active)) {
        // --- start new paths in lanes whose previous path ended ----------------
        if (VANY(restart)) {
            vuint sample = s_begin + VUINT(done_count);
            Rand4 rc = rng_uniform4(seed, pixel, sample, (vuint)0);
            V3 dcam = camera_ray(corner, dx, dy, pxr + rc.a, pyr + rc.b);
            ps.o = v3_sel(ps.o, v3_splat(cam_o), restart);
            ps.d = v3_sel(ps.d, dcam, restart);
            ps.beta = v3_sel(ps.beta, v3((vreal)R(1), (vreal)R(1), (vreal)R(1)), restart);
            ps.L = v3_sel(ps.L, v3_zero(), restart);
            ps.depth = VSEL(ps.depth, zero, restart);
            ps.own = VSEL(ps.own, zero, restart);
            ps.chain = VSEL(ps.chain, zero, restart);
            ps.pdf_prev = VSEL(ps.pdf_prev, zero, restart);
            nd_count = VSEL(nd_count, zero, restart);
            ps.specular = ps.specular || restart;
#if CLPT_AUX
            feat_done = feat_done && !restart;
            path_len = VSEL(path_len, zero, restart);
#endif
            n_camera += vpopcount(restart);
        }
        vuint sample = s_begin + VUINT(done_count);

        // --- closest hit --------------------------------------------------------------
        Hit h = scene_intersect_active(sc, ps.o, ps.d, active);  // ended lanes need no hit
        vmask hit = active && h.t < R(INFINITY);
        Material m = material_fetch(sc, h.mat);
        V3 x = v3_fma(ps.d, h.t, ps.o);
        vmask front = v3_dot(h.ng, ps.d) < R(0);
        V3 n = v3_sel(v3_neg(h.ng), h.ng, front);  // faces the incoming ray
        V3 ng_side = n;
        n = hit_shading_normal(sc, &h, ng_side);     // smooth triangles: the interpolated normal

#if CLPT_AUX
        // --- features for the denoisers, at the feature vertex -------------------------
        path_len = VSEL(path_len, path_len + h.t, hit);
        vmask before_x = !feat_done;  // this vertex is x or comes before it
        vmask rec = hit && !feat_done && (m.nondelta != R(0) || aux_specular != 0u);
        if (VANY(rec)) {
            V3 surf = v3_add(m.kd, m.ks);
            if (aux_specular != 0u) {  // a mirror or glass vertex is a surface of albedo kr + kt (at most 1)
                V3 spec = v3_add(m.kr, m.kt);
                surf = v3_sel(surf, v3(fmin(spec.x, R(1)), fmin(spec.y, R(1)), fmin(spec.z, R(1))),
                              m.nondelta == R(0));
            }
            // An emitter it sees is described by its own colour, and flagged.
            vreal le_max = fmax(m.Le.x, fmax(m.Le.y, m.Le.z));
            vmask light = rec && le_max > R(0) && (front || m.two_sided != R(0));
            surf = v3_sel(surf, v3_scale(m.Le, R(1) / fmax(le_max, R(1e-30))), light);
            flight = VSEL(flight, flight + R(1), light);
            V3 alb = v3_mul(ps.beta, surf);
            fnx = VSEL(fnx, fnx + n.x, rec); fny = VSEL(fny, fny + n.y, rec); fnz = VSEL(fnz, fnz + n.z, rec);
            far = VSEL(far, far + alb.x, rec); fag = VSEL(fag, fag + alb.y, rec); fab = VSEL(fab, fab + alb.z, rec);
            fdist = VSEL(fdist, fdist + path_len, rec);
            fcount = VSEL(fcount, fcount + R(1), rec);
            feat_done = feat_done || rec;
        }
#endif

        // --- emission ---------------------------------------------------------------------
        vmask sees = hit && (front || m.two_sided != R(0));
        vreal w_le = (vreal)R(1);
#if CLPT_NEE
        // After a non-delta lobe light sampling could have found this point too.
        vmask bsdf_hit = sees && ps.pdf_prev > R(0) && h.light > R(0);
        if (VANY(bsdf_hit)) {
            vreal pdf_l = light_pdf_hit(sc, h.light, ps.x_prev, x, h.ng, h.t);
            w_le = VSEL(w_le, mis_power(ps.pdf_prev, pdf_l), bsdf_hit);
        }
#endif
#if CLPT_PHOTONS
        if (owns)
            sees = sees && ps.own != (real)OWN_OWNED && !prepass;
        // At the end of a purely specular chain from a non-delta vertex that
        // merged, photon merging could have made this path too.
        vmask merged_path = sees && ps.chain == (real)CHAIN_IN && ps.chain_k > R(0) && h.light > R(0);
        if (merge && VANY(merged_path)) {
            vreal pf = light_photon_pdf(sc, h.light, x, h.ng, v3_neg(ps.d), m.two_sided != R(0), pm_aim);
            w_le = VSEL(w_le, mis_power((vreal)R(1), pf * ps.chain_k), merged_path);
        }
#endif
        ps.L = v3_sel(ps.L, v3_add(ps.L, v3_scale(v3_mul(ps.beta, m.Le), w_le)), sees);
#if CLPT_AUX
        vmask direct = sees && before_x;
        if (VANY(direct)) {
            V3 e = v3_scale(v3_mul(ps.beta, m.Le), w_le);
            fer = VSEL(fer, fer + e.x, direct); feg = VSEL(feg, feg + e.y, direct); feb = VSEL(feb, feb + e.z, direct);
        }
#endif

        vmask go = hit && ps.depth < lane_depth;
        go = go && (front || m.one_sided == R(0));  // a one-sided surface is black from behind
        vuint group = VUINT(ps.depth) * 2u + 1u;

        LobeProbs pr = lobe_probs(&m, ps.depth < (real)rr_depth);
        vmask nondelta = hit && m.nondelta != R(0);
#if CLPT_PHOTONS
        // --- caustic photons at x, the first vertex with a non-delta part -----------
        vmask at_x = hit && ps.own == (real)OWN_BEFORE_X && m.nondelta != R(0);
        if (gather && VANY(at_x)) {
            Rand4 rg = rng_uniform4(seed, pixel, sample, group);  // .d: unused by light sampling
            V3 Lc = photon_gather(&pm, &m, pr, x, n, ps.d, rg.d, at_x, 0, lane_depth - ps.depth - R(1));
            ps.L = v3_sel(ps.L, v3_add(ps.L, v3_mul(ps.beta, Lc)), at_x);
#if CLPT_AUX
            aux_caustic_add(v3_mul(ps.beta, Lc), at_x, lum_scale, &fcr, &fcg, &fcb, &fcsq);
#endif
        }
        if (prepass)
            go = go && !at_x;  // the pre-pass ends at x
        vmask pure_delta = m.nondelta == R(0);

        // --- photon merging, weighted against path tracing ---------------------------
        // A vertex merges with probability pm_merge_p (Russian roulette on the
        // technique, which bounds its cost); the weights count that in (the
        // host folds it into mis_k), so both sides still see the same pdfs.
        vmask merge_here = go && nondelta && nd_count < (real)pm_merge_vertices;
        if (merge && VANY(merge_here)) {
            Rand4 rg = rng_uniform4(seed, pixel, sample, group);  // .d: unused by light sampling
            vmask do_merge = merge_here && rg.d < pm_merge_p;
            if (VANY(do_merge)) {
                V3 Lm = photon_gather(&pm, &m, pr, x, n, ps.d, rg.d / pm_merge_p, do_merge, 1,
                                      lane_depth - ps.depth - R(1));
                ps.L = v3_sel(ps.L, v3_fma(v3_mul(ps.beta, Lm), R(1) / pm_merge_p, ps.L), do_merge);
#if CLPT_AUX
                // The merge at the first non-delta vertex: the caustic as seen.
                aux_caustic_add(v3_scale(v3_mul(ps.beta, Lm), R(1) / pm_merge_p), do_merge && nd_count == R(0),
                                lum_scale, &fcr, &fcg, &fcb, &fcsq);
#endif
            }
        }
        nd_count = VSEL(nd_count, nd_count + R(1), nondelta);
#endif

#if CLPT_NEE
        // --- next event estimation ---------------------------------------------------
        vmask nee = go && m.nondelta != R(0);
#if CLPT_PHOTONS
        nee = nee && !prepass;
#endif
        if (VANY(nee)) {
            Rand4 rl = rng_uniform4(seed, pixel, sample, group);
            LightSample ls = light_sample(sc, x, rl.a, rl.b, rl.c);
            vreal cos_x = v3_dot(n, ls.wi);
            nee = nee && ls.valid && cos_x > R(0) && v3_dot(ng_side, ls.wi) > R(0);
            if (VANY(nee)) {
                V3 f = bsdf_eval(&m, ps.d, n, ls.wi);
                vreal w_l = mis_power(ls.pdf, bsdf_pdf(&m, pr, ps.d, n, ls.wi));
                V3 c = v3_mul(v3_mul(ps.beta, f), v3_scale(ls.Le, w_l * cos_x / ls.pdf));
                // The shadow ray runs from the offset origin to the light point
                // itself: aimed along wi from there instead, it would cut into a
                // sphere light near its silhouette and see the light block itself.
                V3 so = offset_origin(sc, x, ng_side, h.err);
                V3 to = v3_sub(ls.p, so);
                vreal len = sqrt(v3_dot(to, to));
                vmask blocked = scene_occluded(sc, so, v3_scale(to, R(1) / len), len * R(0.9999), nee);
                n_shadow += vpopcount(nee);
                ps.L = v3_sel(ps.L, v3_add(ps.L, c), nee && !blocked);
            }
        }
#endif

        // --- scattering ------------------------------------------------------------------
        vmask cont = go;
        if (VANY(go)) {
            Rand4 rs = rng_uniform4(seed, pixel, sample, group + 1u);
            cont = scatter(sc, &m, pr, &ps, x, n, front, go, rs, h.err);
            keep_geometric_side(sc, &ps.o, &ps.d, x, n, ng_side, cont && h.nrm >= R(0), h.err);
            ps.depth = VSEL(ps.depth, ps.depth + R(1), cont);
#if CLPT_PHOTONS
            // x's lobe decides whether the path can be the photon map's; after
            // it, only purely specular vertices keep it so.
            vreal own = ps.own;
            own = VSEL(own, VSEL((vreal)R(OWN_NOT), (vreal)R(OWN_AFTER_D), !ps.specular), at_x);
            vmask after = ps.own == (real)OWN_AFTER_D || ps.own == (real)OWN_OWNED;
            own = VSEL(own, VSEL((vreal)R(OWN_NOT), (vreal)R(OWN_OWNED), pure_delta), after && hit);
            ps.own = own;
            // Merging: a non-delta lobe starts a chain (with its pdf, if a merge
            // happened at this vertex), purely specular vertices extend it, and
            // a delta lobe of a vertex with a non-delta part ends it.
            vmask took_nd = nondelta && !ps.specular;
            vmask extend = pure_delta && (ps.chain == (real)CHAIN_AFTER_D || ps.chain == (real)CHAIN_IN);
            vreal chain = VSEL((vreal)R(CHAIN_NONE), (vreal)R(CHAIN_IN), extend);
            chain = VSEL(chain, (vreal)R(CHAIN_AFTER_D), took_nd);
            vreal cos_o = v3_dot(n, ps.d);
            vreal k = VSEL((vreal)R(0), pm_mis_k * cos_o / ps.pdf_prev, merge_here && ps.pdf_prev > R(0));
            ps.chain_k = VSEL(ps.chain_k, k, took_nd);
            ps.chain = VSEL(ps.chain, chain, cont);
#endif
            n_bounce += vpopcount(cont);
        }

        // --- finished samples --------------------------------------------------------
        vmask done = active && !cont;
        if (VANY(done)) {
            accumulate(done, ps.L, lum_scale, &acc, &nonfinite);
#if CLPT_AUX
            // No non-delta vertex (an emitter seen directly or through glass, or
            // the void): no normal, albedo 1, the distance travelled.
            vmask fb = done && !feat_done;
            far = VSEL(far, far + R(1), fb); fag = VSEL(fag, fag + R(1), fb); fab = VSEL(fab, fab + R(1), fb);
            fdist = VSEL(fdist, fdist + path_len, fb);
            fcount = VSEL(fcount, fcount + R(1), fb);
#endif
            done_count = VSEL(done_count, done_count + R(1), done);
            restart = done && done_count < lane_n;
            active = (active && !done) || restart;
        } else {
            restart = zero != zero;
        }
    }

    for (int l = 0; l < CLPT_LANES; l++) {
        uint p = VLANE_U(pixel, l);
        if (p < n_pix) {
            pixel_acc_store(&acc, l, pix_sum, pix_sq, p);
#if CLPT_AUX
            int aux_store = 1;
#if CLPT_PHOTONS
            aux_store = !prepass;  // the offline pre-pass's samples are not the image's
#endif
            if (aux_store) {
                aux_normal[p] = (float4)(VLANE_R(fnx, l), VLANE_R(fny, l), VLANE_R(fnz, l), VLANE_R(fcount, l));
                aux_albedo[p] = (float4)(VLANE_R(far, l), VLANE_R(fag, l), VLANE_R(fab, l), VLANE_R(fdist, l));
                aux_emit[p] = (float4)(VLANE_R(fer, l), VLANE_R(feg, l), VLANE_R(feb, l), VLANE_R(flight, l));
                aux_caustic[p] = (float4)(VLANE_R(fcr, l), VLANE_R(fcg, l), VLANE_R(fcb, l), VLANE_R(fcsq, l));
            }
#endif
        }
    }
    stats[gid] = (uint4)(nonfinite, n_camera, n_bounce, n_shadow);
}
