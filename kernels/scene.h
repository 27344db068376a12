// scene.h: the packed scene and ray queries against it.
//
// The scene is one array of real4 rows (float4, or double4 when
// CLPT_DOUBLE), in sections whose order clpt/pack.py defines and whose
// records clpt/layout.py defines (its generated <PREFIX>_STRIDE and
// <PREFIX>_<FIELD> row constants are stitched in before this file; a field
// is always read by its constant, scene_rec(sc, r + LIGHT_INFO), never at a
// number):
//   materials  MAT_*       spheres  SPHERE_*    quads, triangles  PLANAR_*
//   planes     PLANE_*     lights   LIGHT_*     caustics  CAUSTIC_*
//   then, when the scene has a BVH (NUM_NODES > 0): BVH nodes (BVH_*),
//   leaf blocks (BVHL_*: their items' PLANAR fields, spheres among them),
//   vertex normals (NORMALS_*)
//   and mesh-light triangles (LTRI_*); pointers into these are absolute
//   record indices stored as reals.
// Caustics are bounding spheres (centre.xyz, radius; radius < 0 if
// unbounded) of each purely specular object, for aiming photons.
// wu and wv are the dual vectors of the edges u, v in the plane: for a point
// q relative to the corner, (dot(q, wu), dot(q, wv)) are its coordinates
// along u and v, so quads and triangles share one test and one record shape.
// Material ids are small integers stored as floats (exact below 2^24).
//
// Section sizes come from CLPT_NUM_* (specialized builds: loops with compile-
// time trip counts) or, when CLPT_GENERIC, from the launch's SceneInfo at run
// time.

#define LIGHT_KIND_QUAD KIND_QUAD
#define LIGHT_KIND_TRIANGLE KIND_TRIANGLE
#define LIGHT_KIND_SPHERE KIND_SPHERE
#define LIGHT_KIND_POINT KIND_POINT
#define LIGHT_KIND_SPOT KIND_SPOT
#define LIGHT_KIND_MESH KIND_MESH
#define LIGHT_KIND_ENV KIND_ENV
#define LIGHT_KIND_DIRECTIONAL KIND_DIRECTIONAL

typedef struct {
    __global const real4 *rec;
    SceneInfo info;  // section sizes; eps_abs: the absolute part of the ray-origin offset
} Scene;

#if CLPT_GENERIC
#define NUM_MATERIALS (sc->info.materials)
#define NUM_SPHERES (sc->info.spheres)
#define NUM_QUADS (sc->info.quads)
#define NUM_TRIANGLES (sc->info.triangles)
#define NUM_PLANES (sc->info.planes)
#define NUM_LIGHTS (sc->info.lights)
#define NUM_CAUSTICS (sc->info.caustics)
#define NUM_NODES (sc->info.nodes)
#else
#define NUM_MATERIALS CLPT_NUM_MATERIALS
#define NUM_SPHERES CLPT_NUM_SPHERES
#define NUM_QUADS CLPT_NUM_QUADS
#define NUM_TRIANGLES CLPT_NUM_TRIANGLES
#define NUM_PLANES CLPT_NUM_PLANES
#define NUM_LIGHTS CLPT_NUM_LIGHTS
#define NUM_CAUSTICS CLPT_NUM_CAUSTICS
#define NUM_NODES CLPT_NUM_NODES
#endif

#define OFF_SPHERES (MAT_STRIDE * NUM_MATERIALS)
#define OFF_QUADS (OFF_SPHERES + SPHERE_STRIDE * NUM_SPHERES)
#define OFF_TRIANGLES (OFF_QUADS + PLANAR_STRIDE * NUM_QUADS)
#define OFF_PLANES (OFF_TRIANGLES + PLANAR_STRIDE * NUM_TRIANGLES)
#define OFF_LIGHTS (OFF_PLANES + PLANE_STRIDE * NUM_PLANES)
#define OFF_CAUSTICS (OFF_LIGHTS + LIGHT_STRIDE * NUM_LIGHTS)
// The BVH starts at the next multiple of 4 records (64 bytes in float builds).
#define OFF_BVH ((OFF_CAUSTICS + CAUSTIC_STRIDE * NUM_CAUSTICS + 3u) & ~3u)

inline real4 scene_rec(const Scene *sc, uint i) { return sc->rec[i]; }

// A hint that record i will be read soon: its cache line is fetched while
// other work goes on (CPU builds; elsewhere nothing).
#if CLPT_PREFETCH
#define scene_prefetch(sc, i) __builtin_prefetch((sc)->rec + (i), 0, 3)
#else
#define scene_prefetch(sc, i) ((void)0)
#endif

// The scene a kernel reads: its records and the launch's SceneInfo.
inline Scene scene_make(__global const real4 *records, SceneInfo info)
{
    Scene s;
    s.rec = records;
    s.info = info;
    return s;
}

// --- offsetting ray origins ----------------------------------------------
// A new ray starts a little off the surface, along the side it leaves by.
// How far follows the rounding error of the hit point itself, never the
// scene's extent (a ground sphere of radius 1e6 must not move every ray of a
// unit box by whole units): a hit at x found along a ray from o carries an
// error of a few ulps of the magnitudes its test worked with, |x|, |o| and the
// primitive's own position and size (Ray Tracing Gems ch. 6: offsets that
// follow the operands' magnitudes). scene_intersect gives that magnitude of
// the ray and the primitive as Hit.err; sc->eps_abs is only an absolute floor
// (the smallest normal numbers) for points at the origin.
#if CLPT_DOUBLE
#define OFFSET_REL R(CLPT_OFFSET_REL_DOUBLE)
#else
#define OFFSET_REL R(CLPT_OFFSET_REL_FLOAT)
#endif
inline vreal max_abs3(V3 p) { return fmax(fabs(p.x), fmax(fabs(p.y), fabs(p.z))); }
inline real max_abs4(real4 p) { return fmax(fabs(p.x), fmax(fabs(p.y), fabs(p.z))); }

inline vreal offset_distance(const Scene *sc, V3 p, vreal err)
{
    return (max_abs3(p) + err) * OFFSET_REL + sc->info.eps_abs;
}

inline V3 offset_origin(const Scene *sc, V3 p, V3 n_side, vreal err)
{
    return v3_fma(n_side, offset_distance(sc, p, err), p);
}

// The origin of a scattered ray of unit direction d: moved along d itself by
// as much as puts it the same distance off the surface, so the ray's line is
// the one the scattering gave. Offsets along the normal would shift the
// line: inside a glass ball each total internal reflection would move the
// ray closer to the centre, lowering its angle of incidence until it leaked
// out below the critical angle. Near grazing (cos < 1/8) the step along d
// would grow long, and the normal offset is kept.
inline V3 offset_scattered(const Scene *sc, V3 p, V3 n_side, V3 d, vreal err)
{
    vreal delta = offset_distance(sc, p, err);
    vreal c = v3_dot(d, n_side);
    vmask along = c >= R(0.125);
    V3 dir = v3_sel(n_side, d, along);
    return v3_fma(dir, VSEL(delta, delta / c, along), p);
}

// --- primitive tests --------------------------------------------------------
// Each returns the ray parameter of the hit or +inf; NaNs from rays parallel
// to a plane fail every comparison and so never count as hits.

// Quad (planar_tri = 0) or triangle (planar_tri = 1) with records p, n, wu,
// wv; *a and *b get the hit's coordinates along the edges (a triangle's
// barycentrics of v1 and v2).
inline vreal intersect_planar_recs(real4 p, real4 n, real4 wu, real4 wv, V3 o, V3 d, int planar_tri,
                                   vreal *a_out, vreal *b_out)
{
    V3 op = v3_sub4(o, p);  // relative to the corner first: no cancellation far from the origin
    vreal t = -v3_dot4(op, n) / v3_dot4(d, n);
    V3 q = v3_fma(d, t, op);
    vreal a = v3_dot4(q, wu), b = v3_dot4(q, wv);
    vmask in = planar_tri ? (a >= R(0) && b >= R(0) && a + b <= R(1))
                          : (a >= R(0) && b >= R(0) && a <= R(1) && b <= R(1));
    *a_out = a;
    *b_out = b;
    return VSEL((vreal)R(INFINITY), t, in && t > R(0));
}

inline vreal intersect_plane(const Scene *sc, uint r, V3 o, V3 d)
{
    real4 p = scene_rec(sc, r + PLANE_POINT_MAT), n = scene_rec(sc, r + PLANE_N);
    vreal t = -v3_dot4(v3_sub4(o, p), n) / v3_dot4(d, n);
    return VSEL((vreal)R(INFINITY), t, t > R(0));
}

// Nearest root > 0 of |o + t d - c| = r for unit d, each lane's own sphere
// (centre c, radius rad). The discriminant uses the closest-approach vector
// (Haines et al., Ray Tracing Gems ch. 7), which stays accurate for small
// spheres far away; q avoids cancellation in the roots.
inline vreal intersect_sphere_lanes(V3 c, vreal rad, V3 o, V3 d)
{
    V3 oc = v3_sub(o, c);
    vreal b = v3_dot(oc, d);
    V3 f = v3_fma(d, -b, oc);
    vreal r2 = rad * rad;
    vreal disc = r2 - v3_dot(f, f);
    vreal cc = v3_dot(oc, oc) - r2;
    vreal q = -b - copysign(sqrt(fmax(disc, R(0))), b);
    vreal t0 = cc / q, t1 = q;
    vreal tn = fmin(t0, t1), tf = fmax(t0, t1);
    vreal t = VSEL(tf, tn, tn > R(0));
    return VSEL((vreal)R(INFINITY), t, disc >= R(0) && t > R(0));
}

// The same for one sphere (centre cr.xyz, radius cr.w) for all lanes.
inline vreal intersect_sphere(real4 cr, V3 o, V3 d)
{
    return intersect_sphere_lanes(v3_splat(cr), (vreal)cr.w, o, d);
}

// --- closest hit ---------------------------------------------------------------
typedef struct {
    vreal t;    // +inf where the ray escaped
    V3 ng;      // unit geometric normal (sphere: outward; planar: winding)
    vreal mat;  // material id
    vreal light;  // light record index + 1 of an emissive primitive, 0 otherwise
    vreal err;  // magnitude the hit's rounding error follows: |o| + the primitive's position and size
    vreal prim;   // primitive id (scene order, boxes and meshes expanded); -1 where the ray escaped
    vreal bu, bv; // coordinates of the hit along the edges: a triangle's barycentrics of v1 and v2
    vreal nrm;    // record index of a smooth triangle's vertex normals, < 0 otherwise
} Hit;

inline Hit hit_none(void)
{
    Hit h;
    h.t = (vreal)R(INFINITY);
    h.ng = v3_zero();
    h.mat = (vreal)R(0);
    h.light = (vreal)R(0);
    h.prim = (vreal)R(-1);
    h.bu = h.bv = (vreal)R(0);
    h.nrm = (vreal)R(-1);
    h.err = (vreal)R(0);
    return h;
}

// Where closer: h takes the planar primitive with records p, n, wu, wv.
inline void hit_planar(Hit *h, vreal t, vmask closer, real4 p, real4 n, real4 wu, real4 wv, vreal a, vreal b)
{
    h->t = VSEL(h->t, t, closer);
    h->ng = v3_sel4(h->ng, n, closer);
    h->mat = VSEL(h->mat, (vreal)p.w, closer);
    h->light = VSEL(h->light, (vreal)n.w, closer);
    h->prim = VSEL(h->prim, (vreal)wu.w, closer);
    h->bu = VSEL(h->bu, a, closer);
    h->bv = VSEL(h->bv, b, closer);
    h->nrm = VSEL(h->nrm, (vreal)wv.w, closer);
    h->err = VSEL(h->err, (vreal)max_abs4(p), closer);  // |corner|: the test is relative to it
}

// Where closer: h takes the sphere cr (centre, radius) hit at t.
inline void hit_sphere(Hit *h, vreal t, vmask closer, real4 cr, V3 o, V3 d, real mat, real light1, real prim)
{
    h->t = VSEL(h->t, t, closer);
    // The normal is formed now, from the ray's origin relative to the centre.
    V3 n = v3_scale(v3_fma(d, t, v3_sub4(o, cr)), (vreal)(R(1) / cr.w));
    h->ng = v3_sel(h->ng, n, closer);
    h->mat = VSEL(h->mat, (vreal)mat, closer);
    h->light = VSEL(h->light, (vreal)light1, closer);
    h->prim = VSEL(h->prim, (vreal)prim, closer);
    h->bu = VSEL(h->bu, (vreal)R(0), closer);
    h->bv = VSEL(h->bv, (vreal)R(0), closer);
    h->nrm = VSEL(h->nrm, (vreal)R(-1), closer);
    h->err = VSEL(h->err, (vreal)(max_abs4(cr) + cr.w), closer);
}

// The BVH (bvh.h, after this file): closest hit and shadow queries over
// every sphere, quad and triangle of scenes large enough to have one.
#if CLPT_HAS_BVH
void bvh_closest(const Scene *sc, V3 o, V3 d, Hit *h, vmask active);
vmask bvh_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask occ);
#endif

// --- the walk over the scene's sections --------------------------------------------
// One walk serves both queries: the closest hit (any = 0), taken into *h,
// and any hit (any = 1): the lanes whose segment o + t d, 0 < t < tmax, is
// blocked, returned, the walk ending early once every tested lane is. `any`
// is a constant at both call sites, so each query compiles to its own plain
// loops. Lanes outside `active` may be left without a hit (the BVH does not
// walk them); untested lanes count as settled.

// The quads (tri = 0) or triangles (tri = 1) of one section: rows off...
CLPT_INLINE void walk_planar(const Scene *sc, uint off, uint count, int tri, V3 o, V3 d, vreal tmax, int any,
                             Hit *h, vmask *occ)
{
    for (uint i = 0; i < count; i++) {
        uint r = off + PLANAR_STRIDE * i;
        real4 p = scene_rec(sc, r + PLANAR_CORNER_MAT), n = scene_rec(sc, r + PLANAR_N_LIGHT);
        real4 wu = scene_rec(sc, r + PLANAR_WU_PRIM), wv = scene_rec(sc, r + PLANAR_WV_KIND);
        if (any && wv.w <= (real)ITEM_QUAD_NO_SHADOW)
            continue;  // a wall no shadow ray can cross (clpt/pack.py _mark_shadowless)
        vreal a, b;
        vreal t = intersect_planar_recs(p, n, wu, wv, o, d, tri, &a, &b);
        if (any)
            *occ = *occ || t < tmax;
        else
            hit_planar(h, t, t < h->t, p, n, wu, wv, a, b);
    }
}

CLPT_INLINE vmask scene_walk(const Scene *sc, V3 o, V3 d, vreal tmax, vmask active, int any, Hit *h)
{
    vmask occ = !active;
#if CLPT_HAS_SPHERES
    for (uint i = 0; i < NUM_SPHERES; i++) {
        uint r = OFF_SPHERES + SPHERE_STRIDE * i;
        real4 cr = scene_rec(sc, r + SPHERE_CENTER_RADIUS);
        vreal t = intersect_sphere(cr, o, d);
        if (any) {
            occ = occ || t < tmax;
        } else {
            real4 sm = scene_rec(sc, r + SPHERE_MAT);
            hit_sphere(h, t, t < h->t, cr, o, d, sm.x, sm.y, sm.z);
        }
    }
    if (any && VALL(occ)) return active;
#endif
#if CLPT_HAS_QUADS
    walk_planar(sc, OFF_QUADS, NUM_QUADS, 0, o, d, tmax, any, h, &occ);
    if (any && VALL(occ)) return active;
#endif
#if CLPT_HAS_TRIANGLES
    walk_planar(sc, OFF_TRIANGLES, NUM_TRIANGLES, 1, o, d, tmax, any, h, &occ);
#endif
#if CLPT_HAS_BVH
    if (NUM_NODES > 0) {
        if (!any)
            bvh_closest(sc, o, d, h, active);
        else if (!VALL(occ))
            occ = bvh_occluded(sc, o, d, tmax, occ);
    }
#endif
#if CLPT_HAS_PLANES
    for (uint i = 0; i < NUM_PLANES; i++) {
        uint r = OFF_PLANES + PLANE_STRIDE * i;
        vreal t = intersect_plane(sc, r, o, d);
        if (any) {
            occ = occ || t < tmax;
            continue;
        }
        vmask closer = t < h->t;
        real4 pp = scene_rec(sc, r + PLANE_POINT_MAT), pn = scene_rec(sc, r + PLANE_N);
        h->t = VSEL(h->t, t, closer);
        h->ng = v3_sel4(h->ng, pn, closer);
        h->mat = VSEL(h->mat, (vreal)pp.w, closer);
        h->light = VSEL(h->light, (vreal)R(0), closer);
        h->err = VSEL(h->err, (vreal)max_abs4(pp), closer);
        h->prim = VSEL(h->prim, (vreal)pn.w, closer);
        h->bu = VSEL(h->bu, (vreal)R(0), closer);
        h->bv = VSEL(h->bv, (vreal)R(0), closer);
        h->nrm = VSEL(h->nrm, (vreal)R(-1), closer);
    }
#endif
    if (!any)
        h->err = h->err + max_abs3(o);
    return occ && active;
}

// Closest hits; lanes outside `active` may be left without one.
inline Hit scene_intersect_active(const Scene *sc, V3 o, V3 d, vmask active)
{
    Hit h = hit_none();
    scene_walk(sc, o, d, (vreal)R(0), active, 0, &h);
    return h;
}

inline Hit scene_intersect(const Scene *sc, V3 o, V3 d)
{
    return scene_intersect_active(sc, o, d, (vreal)R(0) == (vreal)R(0));
}

// Mask of lanes (among `test`) whose segment o + t d, 0 < t < tmax, is blocked.
inline vmask scene_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask test)
{
    return scene_walk(sc, o, d, tmax, test, 1, 0);
}

// --- shading normals -----------------------------------------------------------
// The shading normal at h: a smooth triangle's vertex normals interpolated
// at the hit, turned to the side of n_side (the geometric normal facing the
// incoming ray); n_side itself elsewhere.
inline V3 hit_shading_normal(const Scene *sc, const Hit *h, V3 n_side)
{
#if CLPT_HAS_SMOOTH
    vmask smooth = h->nrm >= R(0);
    if (!VANY(smooth))
        return n_side;
    V3 ns = n_side;
    for (int l = 0; l < CLPT_LANES; l++) {
        vreal nrm = h->nrm, bu = h->bu, bv = h->bv;
        real k = VLANE_R(nrm, l);
        if (k >= R(0)) {
            uint r = (uint)k;
            real a = VLANE_R(bu, l), b = VLANE_R(bv, l);
            real4 s = (R(1) - a - b) * scene_rec(sc, r + NORMALS_N0) + a * scene_rec(sc, r + NORMALS_N1)
                      + b * scene_rec(sc, r + NORMALS_N2);
            VLANE_R(ns.x, l) = s.x;
            VLANE_R(ns.y, l) = s.y;
            VLANE_R(ns.z, l) = s.z;
        }
    }
    ns = v3_normalize(ns);
    ns = v3_sel(ns, v3_neg(ns), v3_dot(ns, n_side) < R(0));
    return v3_sel(n_side, ns, smooth);
#else
    return n_side;
#endif
}

// A ray scattered at x with a shading normal ns_side must still leave on the
// side of the geometric surface (ng_side) that its lobe meant: the side of
// ns_side for reflection, the other for refraction. A tilted shading normal
// can send it across; there it is mirrored across the geometric plane
// (under Mitsuba 3's convention, CLPT_MITSUBA_SHADING, it goes on across).
// Its origin is offset along the geometric normal's side it leaves by.
// Lanes in m.
inline void keep_geometric_side(const Scene *sc, V3 *o, V3 *d, V3 x, V3 ns_side, V3 ng_side, vmask m, vreal err)
{
#if CLPT_HAS_SMOOTH
    vreal cs = v3_dot(*d, ns_side), cg = v3_dot(*d, ng_side);
    vmask wrong = m && ((cs > R(0) && cg <= R(0)) || (cs <= R(0) && cg > R(0)));
    if (!VANY(wrong))
        return;
#if !CLPT_MITSUBA_SHADING
    *d = v3_sel(*d, v3_normalize(v3_fma(ng_side, R(-2) * cg, *d)), wrong);
    cg = v3_dot(*d, ng_side);
#endif
    *o = v3_sel(*o, offset_scattered(sc, x, v3_sel(v3_neg(ng_side), ng_side, cg > R(0)), *d, err), wrong);
#endif
}

// --- materials -------------------------------------------------------------------
typedef struct {
    V3 kd, ks, kr, kt, Le;
    vreal p_d, p_s, p_r, p_t;  // lobe probabilities (absorption takes the rest)
    vreal shininess, ior;
    vreal two_sided;           // emission on both sides (else the normal's side)
    vreal nondelta;            // 1 if kd, ks or km is nonzero (light sampling applies)
    vreal one_sided;           // 1: black from behind (no reflection or transmission)
    V3 km, eta, k;             // rough conductor: reflectance, complex index eta + i k
    vreal p_m, alpha;          // ... its lobe probability, roughness
    vreal beckmann;            // ... 1: Beckmann, 0: GGX
#if CLPT_HAS_PLASTIC
    V3 kp, kps;                // plastic: diffuse base and coating's specular reflectance
    vreal p_p, spec_w;         // ... its lobe probability, Mitsuba's specular sampling weight
    vreal c_eta, c_fdr;        // ... coating index (inside over outside), internal reflectance
    vreal c_alpha, c_beckmann; // ... roughness (0: smooth), 1: Beckmann, 0: GGX
    vreal c_tab, c_nonlinear;  // ... record index of its transmittance table; nonlinear
    __global const real4 *rec; // the scene's records (the tables)
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    V3 gr, gt;                 // rough dielectric: specular reflectance and transmittance
    vreal p_g, g_eta;          // ... its lobe probability; index inside over outside (material_face:
                               //     beyond the surface over the incoming ray's side)
    vreal g_alpha, g_beckmann; // ... roughness, 1: Beckmann, 0: GGX
    vreal g_visible;           // ... 1: sampled from the visible normals (Mitsuba's sample_visible)
#endif
#if CLPT_HAS_ANISOTROPY
    vreal alpha_v;             // rough conductor or dielectric: roughness along n x s (alpha, g_alpha: along s)
    V3 s;                      // unit tangent of the shading frame (material_tangent)
#endif
} Material;

// A vertex whose non-delta part photon merging and the photon map can
// estimate (diffuse and Phong lobes; the photon gathers evaluate no
// microfacet lobe, so a material with one is left to path tracing).
inline vmask material_mergeable(const Material *m)
{
    vmask r = m->nondelta != R(0);
#if CLPT_HAS_MICROFACET
    r = r && m->p_m == R(0);
#endif
#if CLPT_HAS_PLASTIC
    r = r && m->p_p == R(0);  // a plastic too (its lobe is not in the gathers)
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    r = r && m->p_g == R(0);  // and a rough dielectric
#endif
    return r;
}

// The material as seen by a ray arriving on the front (the normal's side)
// or the back: the rough dielectric's relative index becomes the index
// beyond the surface over the index on the ray's side.
inline void material_face(Material *m, vmask front)
{
#if CLPT_HAS_ROUGH_DIELECTRIC
    m->g_eta = VSEL(R(1) / m->g_eta, m->g_eta, front);
#endif
}

#if CLPT_MITSUBA_SHADING
// Mitsuba 3's shading frame at a smooth triangle whose shading normal *ns
// (on the geometric normal's side) the incoming ray d sees from behind (in
// the lanes in m): a two-sided material shades with the normal turned to
// d's side; a one-sided one is black there (no lobe at all, as Mitsuba's
// BSDFs, delta ones included, are with cos_theta_i <= 0). Returns the
// lanes left black.
inline vmask shading_from_behind(Material *mt, V3 *ns, V3 d, vmask m)
{
    vmask behind = m && v3_dot(*ns, d) > R(0);
    *ns = v3_sel(*ns, v3_neg(*ns), behind);
    vmask black = behind && mt->one_sided != R(0);
    if (VANY(black)) {
        mt->kd = v3_sel(mt->kd, v3_zero(), black);
        mt->ks = v3_sel(mt->ks, v3_zero(), black);
        mt->kr = v3_sel(mt->kr, v3_zero(), black);
        mt->kt = v3_sel(mt->kt, v3_zero(), black);
        mt->km = v3_sel(mt->km, v3_zero(), black);
        mt->p_d = VSEL(mt->p_d, (vreal)R(0), black);
        mt->p_s = VSEL(mt->p_s, (vreal)R(0), black);
        mt->p_r = VSEL(mt->p_r, (vreal)R(0), black);
        mt->p_t = VSEL(mt->p_t, (vreal)R(0), black);
        mt->p_m = VSEL(mt->p_m, (vreal)R(0), black);
        mt->nondelta = VSEL(mt->nondelta, (vreal)R(0), black);
#if CLPT_HAS_PLASTIC
        mt->p_p = VSEL(mt->p_p, (vreal)R(0), black);
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
        mt->p_g = VSEL(mt->p_g, (vreal)R(0), black);
#endif
    }
    return black;
}
#endif

// A material with no lobe: every field at its neutral value (tables at rec).
inline Material material_blank(__global const real4 *rec)
{
    Material m;
    m.kd = m.ks = m.kr = m.kt = m.Le = v3_zero();
    m.p_d = m.p_s = m.p_r = m.p_t = m.shininess = m.two_sided = m.nondelta = m.one_sided = (vreal)R(0);
    m.ior = (vreal)R(1);
    m.km = m.eta = m.k = v3_zero();
    m.p_m = m.beckmann = (vreal)R(0);
    m.alpha = (vreal)R(1);
#if CLPT_HAS_PLASTIC
    m.kp = m.kps = v3_zero();
    m.p_p = m.spec_w = m.c_fdr = m.c_alpha = m.c_beckmann = m.c_tab = m.c_nonlinear = (vreal)R(0);
    m.c_eta = (vreal)R(1.5);
    m.rec = rec;
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    m.gr = m.gt = v3_zero();
    m.p_g = m.g_beckmann = m.g_visible = (vreal)R(0);
    m.g_eta = m.g_alpha = (vreal)R(1);
#endif
#if CLPT_HAS_ANISOTROPY
    m.alpha_v = (vreal)R(1);
    m.s = v3_zero();
#endif
    return m;
}

// Per-lane material by selecting over the (few) materials: cheaper on a CPU
// than eight scattered loads per field.
inline Material material_fetch(const Scene *sc, vreal id)
{
    Material m = material_blank(sc->rec);
    for (uint i = 0; i < NUM_MATERIALS; i++) {
        uint r = MAT_STRIDE * i;
        vmask is = id == (real)i;
        if (!VANY(is)) continue;
        real4 a = scene_rec(sc, r + MAT_KD_PD), f = scene_rec(sc, r + MAT_LE_SIDES), g = scene_rec(sc, r + MAT_PARAMS);
        m.kd = v3_sel4(m.kd, a, is); m.p_d = VSEL(m.p_d, (vreal)a.w, is);
#if CLPT_HAS_PHONG
        real4 b = scene_rec(sc, r + MAT_KS_PS);
        m.ks = v3_sel4(m.ks, b, is); m.p_s = VSEL(m.p_s, (vreal)b.w, is);
        m.shininess = VSEL(m.shininess, (vreal)g.x, is);
#endif
#if CLPT_HAS_MIRROR
        real4 c = scene_rec(sc, r + MAT_KR_PR);
        m.kr = v3_sel4(m.kr, c, is); m.p_r = VSEL(m.p_r, (vreal)c.w, is);
#endif
#if CLPT_HAS_GLASS
        real4 e = scene_rec(sc, r + MAT_KT_PT);
        m.kt = v3_sel4(m.kt, e, is); m.p_t = VSEL(m.p_t, (vreal)e.w, is);
        m.ior = VSEL(m.ior, (vreal)g.y, is);
#endif
#if CLPT_HAS_MICROFACET
        real4 mk = scene_rec(sc, r + MAT_KM_PM), me = scene_rec(sc, r + MAT_ETA_ALPHA),
              mq = scene_rec(sc, r + MAT_K_DIST);
        m.km = v3_sel4(m.km, mk, is); m.p_m = VSEL(m.p_m, (vreal)mk.w, is);
        m.eta = v3_sel4(m.eta, me, is); m.alpha = VSEL(m.alpha, (vreal)me.w, is);
        m.k = v3_sel4(m.k, mq, is); m.beckmann = VSEL(m.beckmann, (vreal)mq.w, is);
#endif
#if CLPT_HAS_PLASTIC
        real4 pa = scene_rec(sc, r + MAT_KP_PP), pb = scene_rec(sc, r + MAT_KPS_W),
              pc = scene_rec(sc, r + MAT_COAT), pt = scene_rec(sc, r + MAT_COAT_TAB);
        m.kp = v3_sel4(m.kp, pa, is); m.p_p = VSEL(m.p_p, (vreal)pa.w, is);
        m.kps = v3_sel4(m.kps, pb, is); m.spec_w = VSEL(m.spec_w, (vreal)pb.w, is);
        m.c_eta = VSEL(m.c_eta, (vreal)pc.x, is); m.c_fdr = VSEL(m.c_fdr, (vreal)pc.y, is);
        m.c_alpha = VSEL(m.c_alpha, (vreal)pc.z, is); m.c_beckmann = VSEL(m.c_beckmann, (vreal)pc.w, is);
        m.c_tab = VSEL(m.c_tab, (vreal)pt.x, is); m.c_nonlinear = VSEL(m.c_nonlinear, (vreal)pt.y, is);
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
        real4 ga = scene_rec(sc, r + MAT_GR_PG), gb = scene_rec(sc, r + MAT_GT), gc = scene_rec(sc, r + MAT_GLASS_ROUGH);
        m.gr = v3_sel4(m.gr, ga, is); m.p_g = VSEL(m.p_g, (vreal)ga.w, is);
        m.gt = v3_sel4(m.gt, gb, is);
        m.g_eta = VSEL(m.g_eta, (vreal)gc.x, is); m.g_alpha = VSEL(m.g_alpha, (vreal)gc.y, is);
        m.g_beckmann = VSEL(m.g_beckmann, (vreal)gc.z, is); m.g_visible = VSEL(m.g_visible, (vreal)gc.w, is);
#endif
#if CLPT_HAS_ANISOTROPY
        m.alpha_v = VSEL(m.alpha_v, (vreal)scene_rec(sc, r + MAT_ANISO).x, is);
#endif
        m.Le = v3_sel4(m.Le, f, is); m.two_sided = VSEL(m.two_sided, (vreal)f.w, is);
        m.nondelta = VSEL(m.nondelta, (vreal)g.z, is);
        m.one_sided = VSEL(m.one_sided, (vreal)g.w, is);
    }
    return m;
}

#if CLPT_HAS_ANISOTROPY
// The shading frame's tangent m->s at the hits h of the lanes in `hit`, n
// their shading normal: as Mitsuba's initialize_sh_frame, the primitive's
// dp/du (its TANGENT record; a sphere's z x n) made normal to n. Where the
// material is isotropic (no TANGENT section) or dp/du is 0 (a sphere's
// poles, a plane), the tangent of frame_from_z(n): any serves there.
inline void material_tangent(const Scene *sc, Material *m, const Hit *h, V3 n, vmask hit)
{
    V3 t, b;
    frame_from_z(n, &t, &b);
    V3 g = v3_zero();
    for (int l = 0; l < CLPT_LANES; l++) {
        if (!VLANE_M(hit, l))
            continue;
        vreal mat = h->mat, prim = h->prim;
        real base = scene_rec(sc, MAT_STRIDE * (uint)VLANE_R(mat, l) + MAT_ANISO).y;
        if (base == R(0))
            continue;
        real4 r = scene_rec(sc, (uint)base + TAN_STRIDE * (uint)VLANE_R(prim, l) + TAN_DPDU);
        if ((int)r.w == TAN_SPHERE) {
            vreal nx = h->ng.x, ny = h->ng.y, nz = h->ng.z;
            r = cross(r, (real4)(VLANE_R(nx, l), VLANE_R(ny, l), VLANE_R(nz, l), R(0)));
        }
        VLANE_R(g.x, l) = r.x;
        VLANE_R(g.y, l) = r.y;
        VLANE_R(g.z, l) = r.z;
    }
    V3 p = v3_fma(n, -v3_dot(n, g), g);
    vreal len2 = v3_dot(p, p);
    m->s = v3_sel(t, v3_scale(p, vrsqrt(fmax(len2, (vreal)R(1e-30)))), len2 > R(0));
}
#endif
