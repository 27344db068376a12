// lights.h: sampling the lights, for next event estimation and for photon
// emission alike. Every emissive quad, triangle or sphere, and every emissive
// mesh as a whole, is an area light; one light is picked per lane by power
// from the alias table the host built (O(1) in the number of lights), then a
// point on it uniformly by area:
//   quad, triangle  (pdf_area = 1 / area)
//   mesh            a triangle by area from the mesh's alias table (O(1)),
//                   then uniformly on it: uniform over the mesh's whole area
//   sphere          uniformly on its surface.
// Seen from a shading point x (next event estimation), a sphere is sampled in
// the cone it subtends instead (pdf_sa = 1 / (2 pi (1 - cos_max))), unless x
// is on or inside it; every other pdf is turned from area to solid angle.
// Emission leaves the side the normal points to, or both sides if two_sided.
// Point and spot lights (CLPT_HAS_DELTA_LIGHTS) are delta lights: picked by
// power like the others, then their one point, at pdf_area = the pick
// probability (area 1); seen from x, pdf = d^2 times it, so that Le cos / pdf
// = I cos / d^2 / pick with Le the intensity times the spot's falloff towards
// x, and delta is set: no BSDF sample finds them, so their sample's MIS
// weight is 1. For photon emission n is the spot's axis (0 for a point) and
// the falloff of the direction chosen is delta_falloff's.
// A new light kind is a case of light_point (and of light_pdf_hit, and of
// the light records' packing in clpt/pack.py).

typedef struct {
    V3 p;             // the light point
    V3 n;             // the light's unit normal there (winding order; outward for spheres)
    V3 Le;            // emitted radiance
    vmask two_sided;  // emits on both sides
    vreal pdf_area;   // area pdf of p, times the pick probability
    vreal err;        // magnitude of the light's position and size (p's rounding error follows it)
    // Seen from x (light_sample's at_x):
    V3 wi;            // unit direction from x to p
    vreal dist;       // distance from x to p
    vreal pdf;        // solid-angle pdf of wi, times the pick probability
    vmask valid;      // a usable sample (its emitting side faces x, 0 < pdf < inf)
#if CLPT_HAS_DELTA_LIGHTS
    vmask delta;      // a point or spot light (a delta light)
    vreal cos_cut, cut, inv_tr, cos_beam;  // the spot's falloff (a point light's: -2, 0, 0, -2, 1 everywhere)
#endif
} LightSample;

#if CLPT_HAS_DELTA_LIGHTS
// Mitsuba 3's spot falloff towards unit direction w (from the light), axis
// the spot's (ignored by a point light, whose cosines are -2): 1 within the
// beam width, (cutoff - theta) / (cutoff - beam) between, 0 from the cutoff on.
inline vreal delta_falloff(V3 axis, vreal cos_cut, vreal cut, vreal inv_tr, vreal cos_beam, V3 w)
{
    vreal c = v3_dot(w, axis);
    vreal mid = (cut - acos(fmin(fmax(c, (vreal)R(-1)), (vreal)R(1)))) * inv_tr;
    return VSEL((vreal)R(0), VSEL(mid, (vreal)R(1), c >= cos_beam), c > cos_cut);
}
#endif

// The light each lane picks, by power, in O(1): Walker's alias table (the
// host's pack.alias_table), slot j kept with probability info.z of light j
// and otherwise giving light n.w of light j's records. u_pick picks the
// slot and, rescaled, decides between the slot and its alias.
inline vreal light_pick_index(const Scene *sc, vreal u_pick)
{
    vreal li = (vreal)R(0);
    if (NUM_LIGHTS <= 1)
        return NUM_LIGHTS == 1 ? li : (vreal)R(INFINITY);
    for (int l = 0; l < CLPT_LANES; l++) {
        real u = VLANE_R(u_pick, l) * (real)NUM_LIGHTS;
        uint j = min((uint)u, (uint)NUM_LIGHTS - 1u);
        uint r = OFF_LIGHTS + LIGHT_STRIDE * j;
        real keep = scene_rec(sc, r + LIGHT_INFO).z;
        VLANE_R(li, l) = u - (real)j < keep ? (real)j : scene_rec(sc, r + LIGHT_N).w;
    }
    return li;
}

// The lights the lanes picked (li, +inf where done), one at a time: light
// *i, the lanes that picked it (pick) and its records at *r; the lanes are
// marked done in li. Returns 0 when none is left. Light-sampling costs so
// grow with the lights the lanes picked, at most CLPT_LANES, not with all
// of the scene's lights.
inline int light_next(const Scene *sc, vreal *li, uint *i, vmask *pick, uint *r)
{
    if (NUM_LIGHTS == 1) {  // one light: no search (a constant in specialized builds)
        *pick = *li == R(0);
        if (!VANY(*pick))
            return 0;
        *li = (vreal)R(INFINITY);
        *i = 0;
        *r = OFF_LIGHTS;
        return 1;
    }
    real m = vmin_lane(*li);
    if (!(m < R(INFINITY)))
        return 0;
    *i = (uint)m;
    *pick = *li == m;
    *li = VSEL(*li, (vreal)R(INFINITY), *pick);
    *r = OFF_LIGHTS + LIGHT_STRIDE * *i;
    return 1;
}

#if CLPT_HAS_MESH_LIGHTS
// A point y on the mesh light whose records start at r, and the normal n of
// its triangle (winding order), for the lanes in pick: the triangle by area
// from the mesh's alias table (LTRI_* records), then a uniform point on it. u1
// picks the alias slot and, rescaled to [0, 1), serves again for the point.
inline void mesh_light_point(const Scene *sc, uint r, vmask pick, vreal u1, vreal u2, V3 *y, V3 *n)
{
    real4 mi = scene_rec(sc, r + LIGHT_U);  // first triangle record, triangles
    uint base = (uint)mi.x, ntri = (uint)mi.y;
    V3 p = v3_zero(), eu = v3_zero(), ev = v3_zero();
    vreal ur = u1;
    for (int l = 0; l < CLPT_LANES; l++) {
        if (VLANE_M(pick, l) == 0)
            continue;
        real u = VLANE_R(u1, l) * (real)ntri;
        uint j = min((uint)u, ntri - 1u);
        real f = u - (real)j;
        uint t = base + LTRI_STRIDE * j;
        real4 a = scene_rec(sc, t + LTRI_P_ALIAS), b = scene_rec(sc, t + LTRI_U_PROB);
        if (f >= b.w) {
            f = (f - b.w) / (R(1) - b.w);
            j = (uint)a.w;
            t = base + LTRI_STRIDE * j;
            a = scene_rec(sc, t + LTRI_P_ALIAS);
            b = scene_rec(sc, t + LTRI_U_PROB);
        } else {
            f = f / b.w;
        }
        real4 c = scene_rec(sc, t + LTRI_V);
        VLANE_R(ur, l) = fmin(fmax(f, R(0)), R(1) - REAL_EPS);
        VLANE_R(p.x, l) = a.x; VLANE_R(p.y, l) = a.y; VLANE_R(p.z, l) = a.z;
        VLANE_R(eu.x, l) = b.x; VLANE_R(eu.y, l) = b.y; VLANE_R(eu.z, l) = b.z;
        VLANE_R(ev.x, l) = c.x; VLANE_R(ev.y, l) = c.y; VLANE_R(ev.z, l) = c.z;
    }
    vreal a, b;
    sample_uniform_triangle(ur, u2, &a, &b);
    *y = v3_fma(ev, b, v3_fma(eu, a, p));
    *n = v3_normalize(v3_cross(eu, ev));
}
#endif

// A point y uniform by area on light r (kind, records at r: p its first
// row), its unit normal n there and the magnitude err its rounding error
// follows, for the lanes in pick.
CLPT_INLINE void light_point(const Scene *sc, uint r, int kind, vmask pick, LightU u, V3 *y, V3 *n, vreal *err)
{
    real4 p = scene_rec(sc, r + LIGHT_P_KIND);
#if CLPT_HAS_SPHERE_LIGHTS
    if (kind == LIGHT_KIND_SPHERE) {
        real rad = scene_rec(sc, r + LIGHT_U).x;
        *n = sample_uniform_sphere(u.u1, u.u2);
        *y = v3_fma(*n, (vreal)rad, v3_splat(p));
        *err = (vreal)(max_abs4(p) + rad);
        return;
    }
#endif
#if CLPT_HAS_MESH_LIGHTS
    if (kind == LIGHT_KIND_MESH) {
        mesh_light_point(sc, r, pick, u.u1, u.u2, y, n);
        *err = fmax(fabs(y->x), fmax(fabs(y->y), fabs(y->z)));  // each lane's triangle: the point's magnitude
        return;
    }
#endif
    real4 eu = scene_rec(sc, r + LIGHT_U), ev = scene_rec(sc, r + LIGHT_V);
    vreal a = u.u1, b = u.u2;
#if CLPT_HAS_TRIANGLE_LIGHTS
    if (kind == LIGHT_KIND_TRIANGLE)
        sample_uniform_triangle(u.u1, u.u2, &a, &b);
#endif
    *y = v3(p.x + a * eu.x + b * ev.x, p.y + a * eu.y + b * ev.y, p.z + a * eu.z + b * ev.z);
    *n = v3_splat(scene_rec(sc, r + LIGHT_N));
    *err = (vreal)(max_abs4(p) + max_abs4(eu) + max_abs4(ev));
}

#if CLPT_HAS_DELTA_LIGHTS
// light_sample's point or spot light (records at r; info and m its LIGHT_INFO
// and material's Le row) for the lanes in pick, into *ls: its one point, the
// falloff's parameters, pdf_area = the pick probability; at x, the direction
// to it, pdf = d^2 times the pick probability and Le = the intensity times
// the falloff towards x.
CLPT_INLINE void delta_light_sample(const Scene *sc, uint r, real4 info, real4 m, vmask pick, V3 x, int at_x,
                                    LightSample *ls)
{
    real4 p = scene_rec(sc, r + LIGHT_P_KIND);
    real4 a = scene_rec(sc, r + LIGHT_U), b = scene_rec(sc, r + LIGHT_V);  // axis, cos cutoff | cutoff, ...
    V3 y = v3_splat(p), axis = v3((vreal)a.x, (vreal)a.y, (vreal)a.z);
    ls->delta = ls->delta || pick;
    ls->cos_cut = VSEL(ls->cos_cut, (vreal)a.w, pick);
    ls->cut = VSEL(ls->cut, (vreal)b.x, pick);
    ls->inv_tr = VSEL(ls->inv_tr, (vreal)b.y, pick);
    ls->cos_beam = VSEL(ls->cos_beam, (vreal)b.z, pick);
    ls->p = v3_sel(ls->p, y, pick);
    ls->n = v3_sel(ls->n, axis, pick);
    ls->err = VSEL(ls->err, (vreal)max_abs4(p), pick);
    ls->pdf_area = VSEL(ls->pdf_area, (vreal)info.y, pick);
    if (!at_x) {
        ls->Le = v3_sel(ls->Le, v3_splat(m), pick);
        return;
    }
    V3 w = v3_sub(y, x);
    vreal d2 = v3_dot(w, w);
    vreal dist = sqrt(d2);
    V3 wi = v3_scale(w, R(1) / dist);
    vreal fall = delta_falloff(axis, (vreal)a.w, (vreal)b.x, (vreal)b.y, (vreal)b.z, v3_neg(wi));
    vreal pdf = d2 * info.y;
    ls->Le = v3_sel(ls->Le, v3_scale(v3_splat(m), fall), pick);
    ls->wi = v3_sel(ls->wi, wi, pick);
    ls->dist = VSEL(ls->dist, dist, pick);
    ls->pdf = VSEL(ls->pdf, pdf, pick);
    ls->valid = ls->valid || (pick && fall > R(0) && pdf > R(0) && pdf < R(INFINITY));
}
#endif

// A light picked by power and a point on it, into *out. With at_x (a
// constant where this is inlined), as seen from the shading point x, for
// next event estimation: wi, dist, the solid-angle pdf and validity are
// filled and p is recomputed as x + dist wi; without, for photon emission:
// the point, its normal, the area pdf and err. (An always-inlined function
// returns no struct: Oclgrind cannot run the noalias scope its inlining leaves.)
CLPT_INLINE void light_sample(const Scene *sc, V3 x, LightU u, int at_x, LightSample *out)
{
    LightSample ls;
    ls.p = ls.n = ls.Le = ls.wi = v3_zero();
    ls.dist = ls.pdf = ls.pdf_area = ls.err = (vreal)R(0);
    ls.two_sided = ls.valid = ls.pdf != ls.pdf;
#if CLPT_HAS_DELTA_LIGHTS
    ls.delta = ls.valid;
    ls.cos_cut = ls.cut = ls.inv_tr = ls.cos_beam = (vreal)R(0);
#endif
    vreal li = light_pick_index(sc, u.pick);
    uint i, r;
    vmask pick;
    while (light_next(sc, &li, &i, &pick, &r)) {
        real4 info = scene_rec(sc, r + LIGHT_INFO);  // area, pick probability, alias probability, material
        int kind = (int)scene_rec(sc, r + LIGHT_P_KIND).w;
        real4 m = scene_rec(sc, MAT_STRIDE * (uint)info.w + MAT_LE_SIDES);  // Le.rgb, two_sided
#if CLPT_HAS_DELTA_LIGHTS
        if (kind == LIGHT_KIND_POINT || kind == LIGHT_KIND_SPOT) {
            delta_light_sample(sc, r, info, m, pick, x, at_x, &ls);
            continue;
        }
#endif
        V3 y, n;
        vreal err;
        light_point(sc, r, kind, pick, u, &y, &n, &err);
        ls.Le = v3_sel(ls.Le, v3_splat(m), pick);
        if (!at_x) {
            ls.p = v3_sel(ls.p, y, pick);
            ls.n = v3_sel(ls.n, n, pick);
            ls.two_sided = ls.two_sided || (pick && (vreal)m.w != R(0));
            ls.pdf_area = VSEL(ls.pdf_area, (vreal)(info.y / info.x), pick);
            ls.err = VSEL(ls.err, err, pick);
            continue;
        }
        // From area to solid angle at x.
        V3 w = v3_sub(y, x);
        vreal d2 = v3_dot(w, w);
        vreal dist = sqrt(d2);
        V3 wi = v3_scale(w, R(1) / dist);
        vreal cos_l = -v3_dot(wi, n);
        vreal pdf_sa = d2 / (info.x * fabs(cos_l));
#if CLPT_HAS_SPHERE_LIGHTS
        if (kind == LIGHT_KIND_SPHERE) {
            // Clearly outside the sphere: a direction uniform in the cone it
            // subtends (on or near the surface, a sphere light lit by itself,
            // the point by area stays).
            real4 p = scene_rec(sc, r + LIGHT_P_KIND);
            real rad = scene_rec(sc, r + LIGHT_U).x;
            V3 dc = v3_sub(v3_splat(p), x);
            vreal dc2 = v3_dot(dc, dc);
            vmask outside = dc2 > rad * rad * R(1.001);
            vreal omc = sphere_cone_omc(rad * rad, dc2);
            V3 axis = v3_scale(dc, vrsqrt(dc2));
            V3 lc = sample_uniform_cone(u.u1, u.u2, omc);
            V3 wc = frame_to_world(axis, lc.x, lc.y, lc.z);
            vreal tc = intersect_sphere((real4)(p.x, p.y, p.z, rad), x, wc);
            // Grazing cone-edge directions may round to a miss: take the tangent point.
            tc = VSEL(tc, v3_dot(dc, wc), isinf(tc));
            wi = v3_sel(wi, wc, outside);
            dist = VSEL(dist, tc, outside);
            pdf_sa = VSEL(pdf_sa, uniform_cone_pdf(omc), outside);
            cos_l = VSEL(cos_l, (vreal)R(1), outside);
        }
#endif
        vmask emits = cos_l > R(0) || (m.w != R(0) && cos_l < R(0));
        ls.wi = v3_sel(ls.wi, wi, pick);
        ls.p = v3_sel(ls.p, v3_fma(wi, dist, x), pick);
        ls.dist = VSEL(ls.dist, dist, pick);
        ls.pdf = VSEL(ls.pdf, pdf_sa * info.y, pick);
        ls.valid = ls.valid || (pick && emits && pdf_sa > R(0) && pdf_sa < R(INFINITY));
    }
    *out = ls;
}

// Solid-angle pdf with which light_sample, called at x, draws the point y on
// the light it hits (light1: the hit's light index + 1; ng: the unit
// geometric normal at y; dist: |y - x|): the pick probability times the
// per-light pdf, for the multiple-importance weights of BSDF-sampled hits.
inline vreal light_pdf_hit(const Scene *sc, vreal light1, V3 x, V3 y, V3 ng, vreal dist)
{
    vreal pdf = (vreal)R(0);
    V3 w = v3_sub(y, x);
    vreal d2 = dist * dist;
    vreal li = VSEL(light1 - R(1), (vreal)R(INFINITY), light1 <= R(0));  // the lights hit, as light_next takes them
    uint i, r;
    vmask is;
    while (light_next(sc, &li, &i, &is, &r)) {
        real4 p = scene_rec(sc, r + LIGHT_P_KIND);
        real4 info = scene_rec(sc, r + LIGHT_INFO);  // area, pick probability, alias probability, material
        vreal cos_l = fabs(v3_dot(ng, w)) / dist;
        vreal per = d2 / (info.x * cos_l);
#if CLPT_HAS_SPHERE_LIGHTS
        if ((int)p.w == LIGHT_KIND_SPHERE) {
            real rad = scene_rec(sc, r + LIGHT_U).x;
            V3 dc = v3_sub(v3_splat(p), x);
            vreal dc2 = v3_dot(dc, dc);
            per = VSEL(per, uniform_cone_pdf(sphere_cone_omc(rad * rad, dc2)), dc2 > rad * rad * R(1.001));
        }
#endif
        pdf = VSEL(pdf, per * info.y, is);
    }
    return VSEL(pdf, (vreal)R(0), !(pdf < R(INFINITY)));
}
