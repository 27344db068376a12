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
// A textured spot (CLPT_HAS_TEXTURED_SPOTS; Mitsuba 3's spot `texture`)
// multiplies its intensity towards w by its texture at (u, v) = 1/2 +
// (a . w, b . w) / (axis . w), its light record's rows a = n.xyz and
// b = tex.yzw (the light's frame over 2 tan(cutoff), clpt/pack.py), tex.x
// naming the TEXTURE (spot_texture): at x for next event estimation, in the
// photon's direction for photon emission (photons.cl; LightSample.spot_tex).
// Lights at infinity come after the others (clpt/pack.py), the environment
// last. A directional light (CLPT_HAS_DIRECTIONAL_LIGHTS) is a delta light
// like a point light: Le = its irradiance, pdf = the pick probability, wi
// against its direction of travel. An environment (CLPT_HAS_ENV_LIGHT, at
// most one: an envmap or a constant) draws a direction by its texels'
// luminance times sin theta (env_sample) or, a constant, uniformly; rays
// that leave the scene see it (env_emission, with light_sample's pdf of
// their direction for the weight). Both stand at dist beyond the scene's
// bounding sphere from x (infinite_dist), where the shadow ray ends.
// A textured area light (CLPT_HAS_TEXTURED_EMITTERS; its LIGHT_TEX row
// names the texture) emits its texture's value at the point's (u, v):
// light_texture for light samples, for next event estimation and photon
// emission alike (a photon leaves by area as before and carries Le(y), so
// its flux Le(y) cos / pdf stays unbiased), texture.h emitter_textures_hit
// for rays that hit it. It is picked by its radiance's mean over its surface
// by area times its area (clpt/pack.py).
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
#if CLPT_HAS_TEXTURED_SPOTS
    vreal spot_tex;   // (photon emission) a textured spot's light record (0: none), for spot_texture
#endif
#if CLPT_HAS_DIRECTIONAL_LIGHTS || CLPT_HAS_ENV_LIGHT
    vmask parallel;   // (photon emission) a directional light's or environment's: the photon travels along n from p
#endif
#if CLPT_HAS_ENV_LIGHT
    vmask env_disk;   // (photon emission) an environment's: p still to be placed on the disk (env_photon_start)
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

#if CLPT_HAS_TEXTURED_SPOTS
// The texture of the spot light whose records are at r towards unit
// direction w (from the light, inside its cone: axis . w > 0), or 1 if the
// light has none.
inline real4 spot_texture_at(const Scene *sc, uint r, real4 w)
{
    real4 t = scene_rec(sc, r + LIGHT_TEX);
    if (t.x == R(0))
        return (real4)(R(1), R(1), R(1), R(0));
    real4 axis = scene_rec(sc, r + LIGHT_U), a = scene_rec(sc, r + LIGHT_N);
    real c = axis.x * w.x + axis.y * w.y + axis.z * w.z;
    real u = R(0.5) + (a.x * w.x + a.y * w.y + a.z * w.z) / c;
    real v = R(0.5) + (t.y * w.x + t.z * w.y + t.w * w.z) / c;
    return texture_eval(sc, (uint)t.x, u, v);
}

// Le of the lanes in pick times the texture of the spot light at r (if it
// has one) towards their directions w.
inline V3 spot_texture(const Scene *sc, uint r, vmask pick, V3 w, V3 Le)
{
    if (scene_rec(sc, r + LIGHT_TEX).x == R(0))
        return Le;
    for (int l = 0; l < CLPT_LANES; l++) {
        if (!VLANE_M(pick, l))
            continue;
        real4 c = spot_texture_at(sc, r, (real4)(VLANE_R(w.x, l), VLANE_R(w.y, l), VLANE_R(w.z, l), R(0)));
        VLANE_R(Le.x, l) *= c.x;
        VLANE_R(Le.y, l) *= c.y;
        VLANE_R(Le.z, l) *= c.z;
    }
    return Le;
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

// Where light_point's point lies on the light's primitive: edge coordinates
// a, b (a triangle's barycentrics of v1 and v2, as Hit.bu, .bv) and, on a
// mesh light, the triangle's index in the mesh (a sphere's point: its normal).
typedef struct { vreal a, b, tri; } LightUV;

#if CLPT_HAS_MESH_LIGHTS
// A point y on the mesh light whose records start at r, and the normal n of
// its triangle (winding order), for the lanes in pick: the triangle by area
// from the mesh's alias table (LTRI_* records), then a uniform point on it. u1
// picks the alias slot and, rescaled to [0, 1), serves again for the point.
inline void mesh_light_point(const Scene *sc, uint r, vmask pick, vreal u1, vreal u2, V3 *y, V3 *n, LightUV *q)
{
    real4 mi = scene_rec(sc, r + LIGHT_U);  // first triangle record, triangles
    uint base = (uint)mi.x, ntri = (uint)mi.y;
    V3 p = v3_zero(), eu = v3_zero(), ev = v3_zero();
    vreal ur = u1, tri = (vreal)R(0);
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
        VLANE_R(tri, l) = (real)j;
        VLANE_R(ur, l) = fmin(fmax(f, R(0)), R(1) - REAL_EPS);
        VLANE_R(p.x, l) = a.x; VLANE_R(p.y, l) = a.y; VLANE_R(p.z, l) = a.z;
        VLANE_R(eu.x, l) = b.x; VLANE_R(eu.y, l) = b.y; VLANE_R(eu.z, l) = b.z;
        VLANE_R(ev.x, l) = c.x; VLANE_R(ev.y, l) = c.y; VLANE_R(ev.z, l) = c.z;
    }
    vreal a, b;
    sample_uniform_triangle(ur, u2, &a, &b);
    *y = v3_fma(ev, b, v3_fma(eu, a, p));
    *n = v3_normalize(v3_cross(eu, ev));
    q->a = a;
    q->b = b;
    q->tri = tri;
}
#endif

#if CLPT_HAS_TEXTURED_EMITTERS
// The radiance Le of light r (kind) replaced, for the lanes in pick, by its
// texture's at the point light_point drew (q; a sphere's from its unit
// normal ns there), if the light is textured (texture.h emitter_texture).
inline V3 light_texture(const Scene *sc, uint r, int kind, vmask pick, LightUV q, V3 ns, V3 Le)
{
    real4 t = scene_rec(sc, r + LIGHT_TEX);
    if (t.x == R(0))
        return Le;
    for (int l = 0; l < CLPT_LANES; l++) {
        if (!VLANE_M(pick, l))
            continue;
        real prim = t.y + (kind == LIGHT_KIND_MESH ? VLANE_R(q.tri, l) : R(0));
        real4 c = emitter_texture(sc, (uint)t.x, prim, VLANE_R(q.a, l), VLANE_R(q.b, l),
                                  (real4)(VLANE_R(ns.x, l), VLANE_R(ns.y, l), VLANE_R(ns.z, l), R(0)));
        VLANE_R(Le.x, l) = c.x;
        VLANE_R(Le.y, l) = c.y;
        VLANE_R(Le.z, l) = c.z;
    }
    return Le;
}
#endif

// A point y uniform by area on light r (kind, records at r: p its first
// row), its unit normal n there, the magnitude err its rounding error
// follows and (*q) its coordinates on the light's primitive, for the lanes in pick.
CLPT_INLINE void light_point(const Scene *sc, uint r, int kind, vmask pick, LightU u, V3 *y, V3 *n, vreal *err,
                             LightUV *q)
{
    q->a = u.u1;
    q->b = u.u2;
    q->tri = (vreal)R(0);
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
        mesh_light_point(sc, r, pick, u.u1, u.u2, y, n, q);
        *err = fmax(fabs(y->x), fmax(fabs(y->y), fabs(y->z)));  // each lane's triangle: the point's magnitude
        return;
    }
#endif
    real4 eu = scene_rec(sc, r + LIGHT_U), ev = scene_rec(sc, r + LIGHT_V);
    vreal a = u.u1, b = u.u2;
#if CLPT_HAS_TRIANGLE_LIGHTS
    if (kind == LIGHT_KIND_TRIANGLE) {
        sample_uniform_triangle(u.u1, u.u2, &a, &b);
        q->a = a;
        q->b = b;
    }
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
#if CLPT_HAS_TEXTURED_SPOTS
        ls->spot_tex = VSEL(ls->spot_tex, (vreal)(real)r, pick);  // photons.cl: the texture in the photon's direction
#endif
        return;
    }
    V3 w = v3_sub(y, x);
    vreal d2 = v3_dot(w, w);
    vreal dist = sqrt(d2);
    V3 wi = v3_scale(w, R(1) / dist);
    vreal fall = delta_falloff(axis, (vreal)a.w, (vreal)b.x, (vreal)b.y, (vreal)b.z, v3_neg(wi));
    vreal pdf = d2 * info.y;
    ls->Le = v3_sel(ls->Le, v3_scale(v3_splat(m), fall), pick);
#if CLPT_HAS_TEXTURED_SPOTS
    ls->Le = spot_texture(sc, r, pick && fall > R(0), v3_neg(wi), ls->Le);
#endif
    ls->wi = v3_sel(ls->wi, wi, pick);
    ls->dist = VSEL(ls->dist, dist, pick);
    ls->pdf = VSEL(ls->pdf, pdf, pick);
    ls->valid = ls->valid || (pick && fall > R(0) && pdf > R(0) && pdf < R(INFINITY));
}
#endif

#if CLPT_HAS_ENV_LIGHT || CLPT_HAS_DIRECTIONAL_LIGHTS
// A distance from x that stands for infinity: beyond the scene's bounding
// sphere (center c.xyz, area = pi R^2 its disk).
inline vreal infinite_dist(real4 c, real area, V3 x)
{
    V3 dc = v3_sub(x, v3_splat(c));
    return sqrt(v3_dot(dc, dc)) + R(2) * sqrt(area * R(M_1_PI));
}
#endif

#if CLPT_HAS_ENV_LIGHT
#define ENV_LIGHT_REC (OFF_LIGHTS + LIGHT_STRIDE * (NUM_LIGHTS - 1u))

// The map's radiance for every lane between texels (x0, y0) and (x0 + 1
// (wrapping), y0 + 1), bilinear at (fx, fy) as Mitsuba looks it up, in *Le;
// *cell: the sampling probability of cell (x0, y0) (its first texel's w);
// both 0 outside m. The records' indices and the four corners' weights for
// all lanes at once, then the lanes' fetches, unrolled.
CLPT_INLINE void env_lookup(const Scene *sc, uint base, uint w, vreal x0, vreal y0, vreal fx, vreal fy, vmask m,
                            V3 *Le, vreal *cell)
{
    vuint xa = VUINT(x0), xb = xa + 1u;
    xb = xb == (vuint)w ? (vuint)0u : xb;
    vuint a00 = (vuint)base + (vuint)w * VUINT(y0) + xa, a10 = a00 - xa + xb;
    vreal w11 = fx * fy, w10 = fx - w11, w01 = fy - w11, w00 = (R(1) - fx) - w01;
    V3 L = v3_zero();
    vreal c = (vreal)R(0);
#pragma unroll
    for (int k = 0; k < CLPT_LANES; k++) {
        uint i00 = VLANE_U(a00, k), i10 = VLANE_U(a10, k);
        real4 t00 = scene_rec(sc, i00), t10 = scene_rec(sc, i10);
        real4 t01 = scene_rec(sc, i00 + w), t11 = scene_rec(sc, i10 + w);
        real4 t = t00 * VLANE_R(w00, k) + t10 * VLANE_R(w10, k) + t01 * VLANE_R(w01, k) + t11 * VLANE_R(w11, k);
        VLANE_R(c, k) = t00.w;
        VLANE_R(L.x, k) = t.x; VLANE_R(L.y, k) = t.y; VLANE_R(L.z, k) = t.z;
    }
    *cell = VSEL((vreal)R(0), c, m);
    *Le = v3_sel(v3_zero(), L, m);
}

// The frame of the environment whose record is at r: columns c0, c1, c2 of to_world's rotation.
inline void env_frame(const Scene *sc, uint r, real4 *c0, real4 *c1, real4 *c2)
{
    *c0 = scene_rec(sc, r + LIGHT_U);
    *c1 = scene_rec(sc, r + LIGHT_V);
    real hand = scene_rec(sc, r + LIGHT_N).y;
    real4 a = (real4)((*c0).xyz, R(0)), b = (real4)((*c1).xyz, R(0));
    *c2 = hand * cross(a, b);
}

// The map's cell (*xf, *yf) that unit world directions d fall in, and the
// fractions (*fx, *fy) within it, for the lanes in m (the frame's columns
// c0..c2, the map w x h); *l: d in the map's frame. fmin and fmax keep a
// NaN's lane in range; lanes outside m get cell (0, 0), whose line stays
// cached, not a random texel of a large map.
inline void env_cell_of(real4 c0, real4 c1, real4 c2, uint w, uint h, V3 d, vmask m, V3 *l, vreal *xf, vreal *yf,
                        vreal *fx, vreal *fy)
{
    *l = v3(v3_dot4(d, c0), v3_dot4(d, c1), v3_dot4(d, c2));
    vreal u = poly_atan2((*l).x, -(*l).z) * R(0.5 * M_1_PI) - R(0.5) / (real)w;
    vreal gx = (u - floor(u)) * (real)w;
    vreal gy = poly_acos(fmin(fmax((*l).y, (vreal)R(-1)), (vreal)R(1))) * (R(M_1_PI) * (real)(h - 1u));
    *xf = VSEL((vreal)R(0), fmax(fmin(floor(gx), (vreal)(real)(w - 1u)), (vreal)R(0)), m);
    *yf = VSEL((vreal)R(0), fmax(fmin(floor(gy), (vreal)(real)(h - 2u)), (vreal)R(0)), m);
    *fx = gx - *xf;
    *fy = gy - *yf;
}

// The environment's radiance towards -d (d: a unit world direction leaving
// the scene, unscaled) and, in *pdf_sa, the solid-angle pdf with which
// env_sample draws d, for the lanes in m. A constant: Le 1, pdf 1 / (4 pi).
// The angles are computed for all lanes at once; the texel fetches lane by lane.
inline V3 env_eval(const Scene *sc, uint r, V3 d, vmask m, vreal *pdf_sa)
{
    real4 c0, c1, c2;
    env_frame(sc, r, &c0, &c1, &c2);
    uint w = (uint)c0.w, h = (uint)c1.w, base = (uint)scene_rec(sc, r + LIGHT_N).x;
    if (w == 0u) {
        *pdf_sa = (vreal)R(0.25 * M_1_PI);
        return v3((vreal)R(1), (vreal)R(1), (vreal)R(1));
    }
    // The cells for all lanes at once, then every lane's fetches, unrolled, their results masked below.
    V3 l;
    vreal xf, yf, fx, fy;
    env_cell_of(c0, c1, c2, w, h, d, m, &l, &xf, &yf, &fx, &fy);
    V3 Le;
    vreal cell;
    env_lookup(sc, base, w, xf, yf, fx, fy, m, &Le, &cell);
    vreal sin_t = sqrt(fmax(l.x * l.x + l.z * l.z, (vreal)(REAL_EPS * REAL_EPS)));
    *pdf_sa = cell * ((real)(w * (h - 1u)) * R(0.5 * M_1_PI * M_1_PI)) / sin_t;
    return Le;
}

// The slot of the map's alias tables (at texel record base, w x h) that
// (u1, u2) name for the lanes in m: the rows' cells' tables at *rows and the
// rows' at *marg (ENV_ALIAS); the column *jx and row *jy drawn uniformly, and
// the fractions (*fxs, *fys) they leave. Lanes outside m draw cell (0, 0):
// their fetches share cached lines.
inline void env_slot_of(uint base, uint w, uint h, vmask m, vreal u1, vreal u2, uint *rows, uint *marg, vreal *jx,
                        vreal *jy, vreal *fxs, vreal *fys)
{
    *rows = base + w * h;
    *marg = *rows + (w * (h - 1u) + ENVA_ENTRIES - 1u) / ENVA_ENTRIES;
    vreal sx = u1 * (real)w, sy = u2 * (real)(h - 1u);
    *jx = VSEL((vreal)R(0), fmin(floor(sx), (vreal)(real)(w - 1u)), m);
    *jy = VSEL((vreal)R(0), fmin(floor(sy), (vreal)(real)(h - 2u)), m);
    *fxs = fmin(sx - *jx, (vreal)(R(1) - REAL_EPS));
    *fys = fmin(sy - *jy, (vreal)(R(1) - REAL_EPS));
}

// A direction d (unit, world) from the environment at r for the lanes in m:
// a row of cells by the marginal's alias table (u2), a cell in it by the
// row's (u1), in O(1), a uniform point in the cell (the fractions the alias
// choices leave); its radiance (unscaled) and solid-angle pdf. A constant:
// a uniform direction. The fetches go lane by lane, the angles for all
// lanes at once.
inline V3 env_sample(const Scene *sc, uint r, vmask m, vreal u1, vreal u2, V3 *d, vreal *pdf_sa)
{
    real4 c0, c1, c2;
    env_frame(sc, r, &c0, &c1, &c2);
    uint w = (uint)c0.w, h = (uint)c1.w, base = (uint)scene_rec(sc, r + LIGHT_N).x;
    if (w == 0u) {
        *d = sample_uniform_sphere(u1, u2);
        *pdf_sa = (vreal)R(0.25 * M_1_PI);
        return v3((vreal)R(1), (vreal)R(1), (vreal)R(1));
    }
    uint rows, marg;
    vreal jx, jy, fxs, fys;
    env_slot_of(base, w, h, m, u1, u2, &rows, &marg, &jx, &jy, &fxs, &fys);
    // Every lane (an idle one's numbers are in range too) in unrolled loops that only fetch: the row's
    // slot (keep probability, alias), the cell's slot in that row, the cell's texels; the choices and
    // the fractions they leave for all lanes at once. The results are masked below.
    vreal keep = (vreal)R(0), alias = (vreal)R(0);
#pragma unroll
    for (int k = 0; k < CLPT_LANES; k++) {
        uint j = (uint)VLANE_R(jy, k);
        real4 q = scene_rec(sc, marg + j / ENVA_ENTRIES);
        VLANE_R(keep, k) = (j & 1u) ? q.z : q.x;
        VLANE_R(alias, k) = (j & 1u) ? q.w : q.y;
    }
    vmask own = fys < keep;
    vreal y0 = VSEL(alias, jy, own);
    vreal fy = VSEL(fys - keep, fys, own) / VSEL(R(1) - keep, keep, own);
#pragma unroll
    for (int k = 0; k < CLPT_LANES; k++) {
        uint j = w * (uint)VLANE_R(y0, k) + (uint)VLANE_R(jx, k);
        real4 q = scene_rec(sc, rows + j / ENVA_ENTRIES);
        VLANE_R(keep, k) = (j & 1u) ? q.z : q.x;
        VLANE_R(alias, k) = (j & 1u) ? q.w : q.y;
    }
    own = fxs < keep;
    vreal x0 = VSEL(alias, jx, own);
    vreal fx = VSEL(fxs - keep, fxs, own) / VSEL(R(1) - keep, keep, own);
    V3 Le;
    vreal cell;
    env_lookup(sc, base, w, x0, y0, fx, fy, m, &Le, &cell);
    vreal gx = x0 + fx, gy = y0 + fy;
    vreal phi = (gx + R(0.5)) * (R(2 * M_PI) / (real)w);
    vreal theta = gy * (R(M_PI) / (real)(h - 1u));
    vreal ct, cp;
    vreal st = poly_sincos(theta, &ct), sp = poly_sincos(phi, &cp);
    V3 l = v3(sp * st, ct, -cp * st);
    *d = v3(l.x * c0.x + l.y * c1.x + l.z * c2.x, l.x * c0.y + l.y * c1.y + l.z * c2.y,
            l.x * c0.z + l.y * c1.z + l.z * c2.z);
    *pdf_sa = cell * ((real)(w * (h - 1u)) * R(0.5 * M_1_PI * M_1_PI)) / fmax(st, (vreal)REAL_EPS);
    return Le;
}

// Prefetches what env_sample will read for the lanes in m drawing (u1,
// u2) (the same numbers): the row's alias slot, the cell's slot in it, and
// the cell's two rows of texels as a kept slot has them. Called well before
// next event estimation, so the lines come while the vertex is found.
inline void env_sample_prefetch(const Scene *sc, vmask m, vreal u1, vreal u2)
{
#if CLPT_PREFETCH
    uint r = ENV_LIGHT_REC;
    uint w = (uint)scene_rec(sc, r + LIGHT_U).w, h = (uint)scene_rec(sc, r + LIGHT_V).w;
    if (!VANY(m))
        return;
    uint base = (uint)scene_rec(sc, r + LIGHT_N).x, rows, marg;
    vreal jx, jy, fxs, fys;
    env_slot_of(base, w, h, m, u1, u2, &rows, &marg, &jx, &jy, &fxs, &fys);
#pragma unroll
    for (int k = 0; k < CLPT_LANES; k++) {
        if (!VLANE_M(m, k))
            continue;
        uint j = (uint)VLANE_R(jy, k);
        real4 q = scene_rec(sc, marg + j / ENVA_ENTRIES);  // a small table: cached
        bool own = VLANE_R(fys, k) < ((j & 1u) ? q.z : q.x);
        uint y0 = own ? j : (uint)((j & 1u) ? q.w : q.y), x0 = (uint)VLANE_R(jx, k);
        scene_prefetch(sc, rows + (w * y0 + x0) / ENVA_ENTRIES);
        scene_prefetch(sc, base + w * y0 + x0);
        scene_prefetch(sc, base + w * (y0 + 1u) + x0);
    }
#endif
}

// Whether prefetching the environment map's lines pays: the scene has an
// environment (a generic build's may not) with a map of at least
// ENV_PREFETCH_TEXELS texels, whose lines the caches do not keep.
#define ENV_PREFETCH_TEXELS (1u << 18)
inline bool env_prefetch_pays(const Scene *sc)
{
    if (NUM_LIGHTS == 0)
        return false;
    uint r = ENV_LIGHT_REC;
    if ((int)scene_rec(sc, r + LIGHT_P_KIND).w != LIGHT_KIND_ENV)
        return false;
    return scene_rec(sc, r + LIGHT_U).w * scene_rec(sc, r + LIGHT_V).w >= (real)ENV_PREFETCH_TEXELS;
}

// Prefetches the texels env_eval will read for the lanes in m if their
// rays (unit directions d) leave the scene: called as the rays start, so
// the lines come while they are traced.
inline void env_eval_prefetch(const Scene *sc, V3 d, vmask m)
{
#if CLPT_PREFETCH
    if (!VANY(m))
        return;
    real4 c0, c1, c2;
    env_frame(sc, ENV_LIGHT_REC, &c0, &c1, &c2);
    uint w = (uint)c0.w, h = (uint)c1.w, base = (uint)scene_rec(sc, ENV_LIGHT_REC + LIGHT_N).x;
    V3 l;
    vreal xf, yf, fx, fy;
    env_cell_of(c0, c1, c2, w, h, d, m, &l, &xf, &yf, &fx, &fy);
#pragma unroll
    for (int k = 0; k < CLPT_LANES; k++) {
        if (!VLANE_M(m, k))
            continue;
        uint t = base + w * (uint)VLANE_R(yf, k) + (uint)VLANE_R(xf, k);
        scene_prefetch(sc, t);
        scene_prefetch(sc, t + w);
    }
#endif
}

// What a ray leaving the scene along unit d sees of the environment (Le,
// scaled) for the lanes in m, and (*pdf) the solid-angle pdf with which
// light_sample picks the environment and draws d. Zero where the scene has
// no environment (a generic build's).
inline V3 env_emission(const Scene *sc, V3 d, vmask m, vreal *pdf)
{
    *pdf = (vreal)R(0);
    if (NUM_LIGHTS == 0)
        return v3_zero();
    uint r = ENV_LIGHT_REC;
    if ((int)scene_rec(sc, r + LIGHT_P_KIND).w != LIGHT_KIND_ENV)
        return v3_zero();
    real4 info = scene_rec(sc, r + LIGHT_INFO);
    real4 s = scene_rec(sc, MAT_STRIDE * (uint)info.w + MAT_LE_SIDES);
    vreal pdf_sa;
    V3 Le = env_eval(sc, r, d, m, &pdf_sa);
    *pdf = pdf_sa * info.y;
    return v3_mul(Le, v3_splat(s));
}
#endif

#if CLPT_HAS_DIRECTIONAL_LIGHTS || CLPT_HAS_ENV_LIGHT
// The density, per unit area across unit direction d, with which
// parallel_disk_point places a point whose line along d passes through p
// (p in the plane through c across d): the mixture of the caster disks
// (below) that hold it.
inline vreal parallel_disk_density(const Scene *sc, real4 c, real big, V3 d, V3 p)
{
    vreal dens = (vreal)R(0);
    for (uint k = 0; k < NUM_CAUSTICS; k++) {
        real4 s = scene_rec(sc, OFF_CAUSTICS + CAUSTIC_STRIDE * k + CAUSTIC_SPHERE);
        real rk = s.w < R(0) ? big : s.w;
        V3 qk = s.w < R(0) ? v3_splat(c) : v3_splat(s);
        qk = v3_fma(d, -v3_dot(v3_sub(qk, v3_splat(c)), d), qk);
        V3 e = v3_sub(p, qk);
        dens += VSEL((vreal)R(0), (vreal)(R(1) / (R(M_PI) * rk * rk)), v3_dot(e, e) <= rk * rk * R(1.000001));
    }
    return dens * (R(1) / (real)NUM_CAUSTICS);
}

// Where a photon travelling along unit d (per lane) from infinity starts:
// on the disk of radius R (big) across the scene's bounding sphere (center
// c), at R before its center along d, aimed at the caustic casters: a
// caster picked in equal shares (u1), a uniform point in the disk its
// bounding sphere casts along d (u1 rescaled, u2; an unbounded caster's:
// the whole disk). *dens: the mixture of those disks' uniform densities at
// the point (parallel_disk_density).
inline V3 parallel_disk_point(const Scene *sc, real4 c, real big, V3 d, vreal u1, vreal u2, vreal *dens)
{
    V3 t, b;
    frame_from_z(d, &t, &b);
    vreal uk = u1 * (real)NUM_CAUSTICS;
    vreal kf = fmin(floor(uk), (vreal)(real)(NUM_CAUSTICS - 1));
    vreal ur = fmin(uk - kf, (vreal)R(1));
    V3 q = v3_zero();
    vreal rad = (vreal)big;
    for (uint k = 0; k < NUM_CAUSTICS; k++) {
        real4 s = scene_rec(sc, OFF_CAUSTICS + CAUSTIC_STRIDE * k + CAUSTIC_SPHERE);
        vmask is = kf == (real)k;
        q = v3_sel(q, s.w < R(0) ? v3_splat(c) : v3_splat(s), is);
        rad = VSEL(rad, (vreal)(s.w < R(0) ? big : s.w), is);
    }
    // The point in the plane through c across d, then moved back by R.
    q = v3_fma(d, -v3_dot(v3_sub(q, v3_splat(c)), d), q);
    vreal pr = rad * sqrt(ur), phi = u2 * R(2 * M_PI);
    V3 p = v3_fma(t, pr * cos(phi), v3_fma(b, pr * sin(phi), q));
    *dens = parallel_disk_density(sc, c, big, d, p);
    return v3_fma(d, (vreal)(-big * R(1.001)), p);
}
#endif

#if CLPT_HAS_DIRECTIONAL_LIGHTS
// Where a directional light's photon starts (lanes in pick; records at r,
// c its bounding-sphere row, info and m as light_sample's), into *ls: on
// parallel_disk_point's disk along the light's direction d (u1, u2).
// pdf_area = the pick probability times the disk's density at the point;
// n = d, Le = the irradiance, delta and parallel set (the photon leaves p along n).
CLPT_INLINE void directional_photon_start(const Scene *sc, uint r, real4 c, real4 info, real4 m, vmask pick,
                                          LightU u, LightSample *ls)
{
    real4 d4 = scene_rec(sc, r + LIGHT_U);
    V3 d = v3((vreal)d4.x, (vreal)d4.y, (vreal)d4.z);
    vreal dens;
    V3 p = parallel_disk_point(sc, c, sqrt(info.x * R(M_1_PI)), d, u.u1, u.u2, &dens);
    ls->p = v3_sel(ls->p, p, pick);
    ls->n = v3_sel(ls->n, d, pick);
    ls->Le = v3_sel(ls->Le, v3_splat(m), pick);
    ls->err = VSEL(ls->err, fmax(fabs(p.x), fmax(fabs(p.y), fabs(p.z))), pick);
    ls->pdf_area = VSEL(ls->pdf_area, dens * info.y, pick);
    ls->delta = ls->delta || pick;
    ls->parallel = ls->parallel || pick;
    ls->cos_cut = VSEL(ls->cos_cut, (vreal)R(-2), pick);  // no falloff
    ls->cos_beam = VSEL(ls->cos_beam, (vreal)R(-2), pick);
}
#endif

#if CLPT_HAS_ENV_LIGHT
// An environment's photon (lanes in pick; records at r, c its
// bounding-sphere row, info and m as light_sample's), into *ls: a
// direction w drawn as next event estimation draws it (env_sample, u1,
// u2); the photon travels along n = -w with Le the radiance from w, and
// pdf_area = the pick probability times w's solid-angle pdf, still to be
// multiplied by the density of its start on the disk (env_disk set:
// env_photon_start, with random numbers of its own).
CLPT_INLINE void env_photon_dir(const Scene *sc, uint r, real4 info, real4 m, vmask pick, LightU u,
                                LightSample *ls)
{
    V3 w;
    vreal pdf_sa;
    V3 Le = v3_mul(env_sample(sc, r, pick, u.u1, u.u2, &w, &pdf_sa), v3_splat(m));
    ls->n = v3_sel(ls->n, v3_neg(w), pick);
    ls->Le = v3_sel(ls->Le, Le, pick);
    ls->pdf_area = VSEL(ls->pdf_area, pdf_sa * info.y, pick);
    ls->parallel = ls->parallel || pick;
    ls->env_disk = ls->env_disk || pick;
}

// The start of the environment photons in env_disk on parallel_disk_point's
// disk along their direction n (u1, u2); pdf_area times its density there.
inline void env_photon_start(const Scene *sc, vreal u1, vreal u2, LightSample *ls)
{
    if (!VANY(ls->env_disk))
        return;
    uint r = ENV_LIGHT_REC;
    real4 c = scene_rec(sc, r + LIGHT_P_KIND);
    vreal dens;
    V3 p = parallel_disk_point(sc, c, sqrt(scene_rec(sc, r + LIGHT_INFO).x * R(M_1_PI)), ls->n, u1, u2, &dens);
    ls->p = v3_sel(ls->p, p, ls->env_disk);
    ls->err = VSEL(ls->err, fmax(fabs(p.x), fmax(fabs(p.y), fabs(p.z))), ls->env_disk);
    ls->pdf_area = VSEL(ls->pdf_area, ls->pdf_area * dens, ls->env_disk);
}

// The light-side pdf factor of an environment photon that a camera ray
// leaving along unit d from o would meet (pdf_l: light_sample's pdf of d,
// env_emission's): its direction's pdf times its disk density there, as
// trace_photons stores it, for the weight of an escape after a merge.
inline vreal env_photon_pdf(const Scene *sc, V3 o, V3 d, vreal pdf_l)
{
    uint r = ENV_LIGHT_REC;
    real4 c = scene_rec(sc, r + LIGHT_P_KIND);
    V3 w = v3_neg(d), p = v3_fma(w, -v3_dot(v3_sub(o, v3_splat(c)), w), o);  // into the plane through c
    vreal dens = parallel_disk_density(sc, c, sqrt(scene_rec(sc, r + LIGHT_INFO).x * R(M_1_PI)), w, p);
    return pdf_l * dens;
}
#endif

#if CLPT_HAS_ENV_LIGHT || CLPT_HAS_DIRECTIONAL_LIGHTS
// light_sample's light at infinity (records at r; info and m its LIGHT_INFO
// and material's Le row) for the lanes in pick, into *ls. At x: an
// environment's direction and pdf (env_sample), or a directional light's
// (delta: pdf = the pick probability), at a point beyond the scene. For
// photon emission: a directional light's start (directional_photon_start)
// or an environment's direction (env_photon_dir).
CLPT_INLINE void infinite_light_sample(const Scene *sc, uint r, int kind, real4 info, real4 m, vmask pick, V3 x,
                                       int at_x, LightU u, LightSample *ls)
{
    real4 c = scene_rec(sc, r + LIGHT_P_KIND);
    if (!at_x) {
#if CLPT_HAS_ENV_LIGHT
        if (kind == LIGHT_KIND_ENV)
            env_photon_dir(sc, r, info, m, pick, u, ls);
#endif
#if CLPT_HAS_DIRECTIONAL_LIGHTS
        if (kind == LIGHT_KIND_DIRECTIONAL)
            directional_photon_start(sc, r, c, info, m, pick, u, ls);
#endif
        return;
    }
    V3 wi = v3_zero(), Le = v3_splat(m);
    vreal pdf = (vreal)info.y;
#if CLPT_HAS_ENV_LIGHT
    if (kind == LIGHT_KIND_ENV) {
        vreal pdf_sa;
        Le = v3_mul(env_sample(sc, r, pick, u.u1, u.u2, &wi, &pdf_sa), Le);
        pdf = pdf_sa * info.y;
    }
#endif
#if CLPT_HAS_DIRECTIONAL_LIGHTS
    if (kind == LIGHT_KIND_DIRECTIONAL) {
        real4 d = scene_rec(sc, r + LIGHT_U);
        wi = v3((vreal)-d.x, (vreal)-d.y, (vreal)-d.z);
        ls->delta = ls->delta || pick;
        ls->cos_cut = VSEL(ls->cos_cut, (vreal)R(-2), pick);  // no falloff
        ls->cos_beam = VSEL(ls->cos_beam, (vreal)R(-2), pick);
    }
#endif
    vreal dist = infinite_dist(c, info.x, x);
    ls->Le = v3_sel(ls->Le, Le, pick);
    ls->wi = v3_sel(ls->wi, wi, pick);
    ls->dist = VSEL(ls->dist, dist, pick);
    ls->p = v3_sel(ls->p, v3_fma(wi, dist, x), pick);
    ls->pdf = VSEL(ls->pdf, pdf, pick);
    ls->valid = ls->valid || (pick && pdf > R(0) && pdf < R(INFINITY));
}
#endif

#if CLPT_HAS_SPHERE_LIGHTS && !CLPT_HAS_TEXTURED_EMITTERS
// Next event estimation's sample of the sphere lights, all at once: the
// lanes of li (light_pick_index's, +inf where done) whose light is a sphere
// take its centre, radius, area, pick probability and radiance lane by lane,
// then one pass does what light_sample's loop does for one light at a time
// (the same arithmetic on each lane's values, so the same result), and
// those lanes are marked done in li. Scenes with several sphere lights so
// pay for one sphere light per vertex, not for each sphere the lanes picked.
CLPT_INLINE void sphere_lights_sample_at(const Scene *sc, V3 x, LightU u, vreal *li, LightSample *ls)
{
    vmask pick = *li != *li;  // none
    V3 pc = v3_zero(), Le = v3_zero();
    vreal rad = (vreal)R(1), area = (vreal)R(1), prob = (vreal)R(0), two = (vreal)R(0);
    for (int l = 0; l < CLPT_LANES; l++) {
        real lf = VLANE_R(*li, l);
        if (!(lf < R(INFINITY)))
            continue;
        uint r = OFF_LIGHTS + LIGHT_STRIDE * (uint)lf;
        real4 p = scene_rec(sc, r + LIGHT_P_KIND);
        if ((int)p.w != LIGHT_KIND_SPHERE)
            continue;
        real4 info = scene_rec(sc, r + LIGHT_INFO);
        real4 m = scene_rec(sc, MAT_STRIDE * (uint)info.w + MAT_LE_SIDES);
        VLANE_M(pick, l) = CLPT_LANES == 1 ? 1 : -1;
        VLANE_R(*li, l) = R(INFINITY);
        VLANE_R(pc.x, l) = p.x; VLANE_R(pc.y, l) = p.y; VLANE_R(pc.z, l) = p.z;
        VLANE_R(rad, l) = scene_rec(sc, r + LIGHT_U).x;
        VLANE_R(area, l) = info.x;
        VLANE_R(prob, l) = info.y;
        VLANE_R(Le.x, l) = m.x; VLANE_R(Le.y, l) = m.y; VLANE_R(Le.z, l) = m.z;
        VLANE_R(two, l) = m.w;
    }
    if (!VANY(pick))
        return;
    // light_point's sphere point, then light_sample's sphere case (per lane, as there).
    V3 n = sample_uniform_sphere(u.u1, u.u2);
    V3 y = v3_fma(n, rad, pc);
    ls->Le = v3_sel(ls->Le, Le, pick);
    V3 w = v3_sub(y, x);
    vreal d2 = v3_dot(w, w);
    vreal dist = sqrt(d2);
    V3 wi = v3_scale(w, R(1) / dist);
    vreal cos_l = -v3_dot(wi, n);
    vreal pdf_sa = d2 / (area * fabs(cos_l));
    V3 dc = v3_sub(pc, x);
    vreal dc2 = v3_dot(dc, dc);
    vreal r2 = rad * rad;
    vmask outside = dc2 > r2 * R(1.001);
    vreal sin2 = fmin(r2 / dc2, R(1));  // sphere_cone_omc, each lane's radius
    vreal omc = sin2 / (R(1) + vsafe_sqrt(R(1) - sin2));
    V3 axis = v3_scale(dc, vrsqrt(dc2));
    V3 lc = sample_uniform_cone(u.u1, u.u2, omc);
    V3 wc = frame_to_world(axis, lc.x, lc.y, lc.z);
    vreal tc = intersect_sphere_lanes(pc, rad, x, wc);
    tc = VSEL(tc, v3_dot(dc, wc), isinf(tc));
    wi = v3_sel(wi, wc, outside);
    dist = VSEL(dist, tc, outside);
    pdf_sa = VSEL(pdf_sa, uniform_cone_pdf(omc), outside);
    cos_l = VSEL(cos_l, (vreal)R(1), outside);
    vmask emits = cos_l > R(0) || (two != R(0) && cos_l < R(0));
    ls->wi = v3_sel(ls->wi, wi, pick);
    ls->p = v3_sel(ls->p, v3_fma(wi, dist, x), pick);
    ls->dist = VSEL(ls->dist, dist, pick);
    ls->pdf = VSEL(ls->pdf, pdf_sa * prob, pick);
    ls->valid = ls->valid || (pick && emits && pdf_sa > R(0) && pdf_sa < R(INFINITY));
}
#endif

// A LightSample with nothing drawn yet: every lane invalid, every field 0.
CLPT_INLINE void light_sample_clear(LightSample *ls)
{
    ls->p = ls->n = ls->Le = ls->wi = v3_zero();
    ls->dist = ls->pdf = ls->pdf_area = ls->err = (vreal)R(0);
    ls->two_sided = ls->valid = ls->pdf != ls->pdf;
#if CLPT_HAS_DELTA_LIGHTS
    ls->delta = ls->valid;
    ls->cos_cut = ls->cut = ls->inv_tr = ls->cos_beam = (vreal)R(0);
#endif
#if CLPT_HAS_TEXTURED_SPOTS
    ls->spot_tex = (vreal)R(0);
#endif
#if CLPT_HAS_DIRECTIONAL_LIGHTS || CLPT_HAS_ENV_LIGHT
    ls->parallel = ls->valid;
#endif
#if CLPT_HAS_ENV_LIGHT
    ls->env_disk = ls->valid;
#endif
}

// A light picked by power and a point on it, for the lanes in active, into *out. With at_x (a
// constant where this is inlined), as seen from the shading point x, for
// next event estimation: wi, dist, the solid-angle pdf and validity are
// filled and p is recomputed as x + dist wi; without, for photon emission:
// the point, its normal, the area pdf and err. (An always-inlined function
// returns no struct: Oclgrind cannot run the noalias scope its inlining leaves.)
CLPT_INLINE void light_sample(const Scene *sc, V3 x, LightU u, int at_x, vmask active, LightSample *out)
{
    LightSample ls;
    light_sample_clear(&ls);
    vreal li = VSEL((vreal)R(INFINITY), light_pick_index(sc, u.pick), active);  // only the active lanes pick
    uint i, r;
    vmask pick;
#if CLPT_HAS_SPHERE_LIGHTS && !CLPT_HAS_TEXTURED_EMITTERS
    if (at_x && NUM_LIGHTS > 1)
        sphere_lights_sample_at(sc, x, u, &li, &ls);
#endif
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
#if CLPT_HAS_ENV_LIGHT || CLPT_HAS_DIRECTIONAL_LIGHTS
        if (kind == LIGHT_KIND_ENV || kind == LIGHT_KIND_DIRECTIONAL) {
            infinite_light_sample(sc, r, kind, info, m, pick, x, at_x, u, &ls);
            continue;
        }
#endif
        V3 y, n;
        vreal err;
        LightUV q;
        light_point(sc, r, kind, pick, u, &y, &n, &err, &q);
        ls.Le = v3_sel(ls.Le, v3_splat(m), pick);
#if CLPT_HAS_TEXTURED_EMITTERS
        if (!at_x)  // photon emission: the radiance where the photon leaves (flux = Le(y) cos / pdf)
            ls.Le = v3_sel(ls.Le, light_texture(sc, r, kind, pick, q, n, ls.Le), pick);
#endif
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
#if CLPT_HAS_TEXTURED_EMITTERS
            n = v3_sel(n, v3_scale(v3_sub(v3_fma(wc, tc, x), v3_splat(p)), R(1) / rad), outside);  // the cone's point
#endif
        }
#endif
#if CLPT_HAS_TEXTURED_EMITTERS
        ls.Le = v3_sel(ls.Le, light_texture(sc, r, kind, pick, q, n, ls.Le), pick);
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
