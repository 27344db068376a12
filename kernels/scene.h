// scene.h: the packed scene and ray queries against it.
//
// The scene is one array of real4 records (float4, or double4 when
// CLPT_DOUBLE), in sections whose order and
// strides clpt/pack.py defines (and this file mirrors):
//   materials  MAT_STRIDE records each
//     0 kd.rgb, p_diffuse     1 ks.rgb, p_phong     2 kr.rgb, p_mirror
//     3 kt.rgb, p_refract     4 Le.rgb, two_sided   5 shininess, ior, nondelta, emissive
//   spheres    2 records: center.xyz, radius | material, light + 1, 0, 0
//   quads      4 records: corner.xyz, material | n.xyz, light + 1 | wu.xyz, 0 | wv.xyz, 0
//   triangles  4 records, as quads (corner = v0)
//   planes     2 records: point.xyz, material | n.xyz, 0
//   lights     5 records: p.xyz, kind | u.xyz, 0 | v.xyz, 0 | n.xyz, 0 |
//              area, pick probability, cumulative probability, material
//   caustics   1 record: bounding sphere (centre.xyz, radius; radius < 0 if
//              unbounded) of each purely specular object, for aiming photons
// wu and wv are the dual vectors of the edges u, v in the plane: for a point
// q relative to the corner, (dot(q, wu), dot(q, wv)) are its coordinates
// along u and v, so quads and triangles share one test and one record shape.
// Material ids are small integers stored as floats (exact below 2^24).
//
// Section sizes come from CLPT_NUM_* (specialized builds: loops with compile-
// time trip counts) or, when CLPT_GENERIC, from the Scene counts at run time.

#define MAT_STRIDE 6
#define SPHERE_STRIDE 2
#define PLANAR_STRIDE 4
#define PLANE_STRIDE 2
#define LIGHT_STRIDE 5

#define LIGHT_KIND_QUAD 0
#define LIGHT_KIND_TRIANGLE 1
#define LIGHT_KIND_SPHERE 2

typedef struct {
    SCENE_SPACE const real4 *rec;
    uint n_materials, n_spheres, n_quads, n_triangles, n_planes, n_lights, n_caustics;
    real eps_abs;  // absolute part of the ray-origin offset (scene size * k eps)
} Scene;

#if CLPT_GENERIC
#define NUM_MATERIALS (sc->n_materials)
#define NUM_SPHERES (sc->n_spheres)
#define NUM_QUADS (sc->n_quads)
#define NUM_TRIANGLES (sc->n_triangles)
#define NUM_PLANES (sc->n_planes)
#define NUM_LIGHTS (sc->n_lights)
#define NUM_CAUSTICS (sc->n_caustics)
#else
#define NUM_MATERIALS CLPT_NUM_MATERIALS
#define NUM_SPHERES CLPT_NUM_SPHERES
#define NUM_QUADS CLPT_NUM_QUADS
#define NUM_TRIANGLES CLPT_NUM_TRIANGLES
#define NUM_PLANES CLPT_NUM_PLANES
#define NUM_LIGHTS CLPT_NUM_LIGHTS
#define NUM_CAUSTICS CLPT_NUM_CAUSTICS
#endif

#define OFF_SPHERES (MAT_STRIDE * NUM_MATERIALS)
#define OFF_QUADS (OFF_SPHERES + SPHERE_STRIDE * NUM_SPHERES)
#define OFF_TRIANGLES (OFF_QUADS + PLANAR_STRIDE * NUM_QUADS)
#define OFF_PLANES (OFF_TRIANGLES + PLANAR_STRIDE * NUM_TRIANGLES)
#define OFF_LIGHTS (OFF_PLANES + PLANE_STRIDE * NUM_PLANES)
#define OFF_CAUSTICS (OFF_LIGHTS + LIGHT_STRIDE * NUM_LIGHTS)

inline real4 scene_rec(const Scene *sc, uint i) { return sc->rec[i]; }

// The scene a kernel reads: its records (the baked constants, or the buffer)
// and the section sizes (counts: materials, spheres, quads, triangles,
// planes, lights, caustic casters).
inline Scene scene_make(__global const real4 *records, uint8 counts, real eps_abs)
{
    Scene s;
#if CLPT_BAKED
    s.rec = clpt_scene;
#else
    s.rec = records;
#endif
    s.n_materials = counts.s0; s.n_spheres = counts.s1; s.n_quads = counts.s2; s.n_triangles = counts.s3;
    s.n_planes = counts.s4; s.n_lights = counts.s5; s.n_caustics = counts.s6;
    s.eps_abs = eps_abs;
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
    return (max_abs3(p) + err) * OFFSET_REL + sc->eps_abs;
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

// Quad (planar_tri = 0) or triangle (planar_tri = 1) at records i..i+3.
inline vreal intersect_planar(const Scene *sc, uint i, V3 o, V3 d, int planar_tri, real4 *n_out)
{
    real4 p = scene_rec(sc, i), n = scene_rec(sc, i + 1);
    real4 wu = scene_rec(sc, i + 2), wv = scene_rec(sc, i + 3);
    V3 op = v3_sub4(o, p);  // relative to the corner first: no cancellation far from the origin
    vreal t = -v3_dot4(op, n) / v3_dot4(d, n);
    V3 q = v3_fma(d, t, op);
    vreal a = v3_dot4(q, wu), b = v3_dot4(q, wv);
    vmask in = planar_tri ? (a >= R(0) && b >= R(0) && a + b <= R(1))
                          : (a >= R(0) && b >= R(0) && a <= R(1) && b <= R(1));
    *n_out = n;
    return VSEL((vreal)R(INFINITY), t, in && t > R(0));
}

inline vreal intersect_plane(const Scene *sc, uint i, V3 o, V3 d)
{
    real4 p = scene_rec(sc, i), n = scene_rec(sc, i + 1);
    vreal t = -v3_dot4(v3_sub4(o, p), n) / v3_dot4(d, n);
    return VSEL((vreal)R(INFINITY), t, t > R(0));
}

// Nearest root > 0 of |o + t d - c| = r for unit d. The discriminant uses the
// closest-approach vector (Haines et al., Ray Tracing Gems ch. 7), which stays
// accurate for small spheres far away; q avoids cancellation in the roots.
inline vreal intersect_sphere(real4 cr, V3 o, V3 d)
{
    V3 oc = v3_sub4(o, cr);
    vreal b = v3_dot(oc, d);
    V3 f = v3_fma(d, -b, oc);
    vreal r2 = cr.w * cr.w;
    vreal disc = r2 - v3_dot(f, f);
    vreal c = v3_dot(oc, oc) - r2;
    vreal q = -b - copysign(sqrt(fmax(disc, R(0))), b);
    vreal t0 = c / q, t1 = q;
    vreal tn = fmin(t0, t1), tf = fmax(t0, t1);
    vreal t = VSEL(tf, tn, tn > R(0));
    return VSEL((vreal)R(INFINITY), t, disc >= R(0) && t > R(0));
}

// --- closest hit ---------------------------------------------------------------
typedef struct {
    vreal t;    // +inf where the ray escaped
    V3 ng;      // unit geometric normal (sphere: outward; planar: winding)
    vreal mat;  // material id
    vreal light;  // light record index + 1 of an emissive primitive, 0 otherwise
    vreal err;  // magnitude the hit's rounding error follows: |o| + the primitive's position and size
} Hit;

// Closest hit among the quads (tri = 0) or triangles (tri = 1) at records
// off.., updating h where nearer.
inline void closest_planar(const Scene *sc, uint off, uint count, int tri, V3 o, V3 d, Hit *h)
{
    for (uint i = 0; i < count; i++) {
        uint r = off + PLANAR_STRIDE * i;
        real4 n;
        vreal t = intersect_planar(sc, r, o, d, tri, &n);
        vmask closer = t < h->t;
        h->t = VSEL(h->t, t, closer);
        h->ng = v3_sel4(h->ng, n, closer);
        h->mat = VSEL(h->mat, (vreal)scene_rec(sc, r).w, closer);
        h->light = VSEL(h->light, (vreal)n.w, closer);
        h->err = VSEL(h->err, (vreal)max_abs4(scene_rec(sc, r)), closer);  // |corner|: the test is relative to it
    }
}

inline Hit scene_intersect(const Scene *sc, V3 o, V3 d)
{
    Hit h;
    h.t = (vreal)R(INFINITY);
    h.ng = v3_zero();
    h.mat = (vreal)R(0);
    h.light = (vreal)R(0);
    h.err = (vreal)R(0);
#if CLPT_HAS_SPHERES
    for (uint i = 0; i < NUM_SPHERES; i++) {
        uint r = OFF_SPHERES + SPHERE_STRIDE * i;
        real4 cr = scene_rec(sc, r);
        vreal t = intersect_sphere(cr, o, d);
        vmask closer = t < h.t;
        h.t = VSEL(h.t, t, closer);
        // The normal is formed now, from the ray's origin relative to the centre.
        V3 n = v3_scale(v3_fma(d, t, v3_sub4(o, cr)), (vreal)(R(1) / cr.w));
        h.ng = v3_sel(h.ng, n, closer);
        real4 sm = scene_rec(sc, r + 1);
        h.mat = VSEL(h.mat, (vreal)sm.x, closer);
        h.light = VSEL(h.light, (vreal)sm.y, closer);
        h.err = VSEL(h.err, (vreal)(max_abs4(cr) + cr.w), closer);
    }
#endif
#if CLPT_HAS_QUADS
    closest_planar(sc, OFF_QUADS, NUM_QUADS, 0, o, d, &h);
#endif
#if CLPT_HAS_TRIANGLES
    closest_planar(sc, OFF_TRIANGLES, NUM_TRIANGLES, 1, o, d, &h);
#endif
#if CLPT_HAS_PLANES
    for (uint i = 0; i < NUM_PLANES; i++) {
        uint r = OFF_PLANES + PLANE_STRIDE * i;
        vreal t = intersect_plane(sc, r, o, d);
        vmask closer = t < h.t;
        h.t = VSEL(h.t, t, closer);
        h.ng = v3_sel4(h.ng, scene_rec(sc, r + 1), closer);
        h.mat = VSEL(h.mat, (vreal)scene_rec(sc, r).w, closer);
        h.light = VSEL(h.light, (vreal)R(0), closer);
        h.err = VSEL(h.err, (vreal)max_abs4(scene_rec(sc, r)), closer);
    }
#endif
    h.err = h.err + max_abs3(o);
    return h;
}

// --- shadow rays -----------------------------------------------------------------
// Mask of lanes (among `test`) whose segment o + t d, 0 < t < tmax, is blocked.
// Stops early once every tested lane is known to be blocked.
inline vmask scene_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask test)
{
    vmask occ = !test;  // untested lanes count as settled
#if CLPT_HAS_SPHERES
    for (uint i = 0; i < NUM_SPHERES; i++) {
        vreal t = intersect_sphere(scene_rec(sc, OFF_SPHERES + SPHERE_STRIDE * i), o, d);
        occ = occ || t < tmax;
    }
    if (VALL(occ)) return test;
#endif
#if CLPT_HAS_QUADS
    for (uint i = 0; i < NUM_QUADS; i++) {
        real4 n;
        occ = occ || intersect_planar(sc, OFF_QUADS + PLANAR_STRIDE * i, o, d, 0, &n) < tmax;
    }
    if (VALL(occ)) return test;
#endif
#if CLPT_HAS_TRIANGLES
    for (uint i = 0; i < NUM_TRIANGLES; i++) {
        real4 n;
        occ = occ || intersect_planar(sc, OFF_TRIANGLES + PLANAR_STRIDE * i, o, d, 1, &n) < tmax;
    }
#endif
#if CLPT_HAS_PLANES
    for (uint i = 0; i < NUM_PLANES; i++)
        occ = occ || intersect_plane(sc, OFF_PLANES + PLANE_STRIDE * i, o, d) < tmax;
#endif
    return occ && test;
}

// --- materials -------------------------------------------------------------------
typedef struct {
    V3 kd, ks, kr, kt, Le;
    vreal p_d, p_s, p_r, p_t;  // lobe probabilities (absorption takes the rest)
    vreal shininess, ior;
    vreal two_sided;           // emission on both sides (else the normal's side)
    vreal nondelta;            // 1 if kd or ks is nonzero (light sampling applies)
} Material;

// Per-lane material by selecting over the (few) materials: cheaper on a CPU
// than eight scattered loads per field.
inline Material material_fetch(const Scene *sc, vreal id)
{
    Material m;
    m.kd = m.ks = m.kr = m.kt = m.Le = v3_zero();
    m.p_d = m.p_s = m.p_r = m.p_t = m.shininess = m.two_sided = m.nondelta = (vreal)R(0);
    m.ior = (vreal)R(1);
    for (uint i = 0; i < NUM_MATERIALS; i++) {
        uint r = MAT_STRIDE * i;
        vmask is = id == (real)i;
        if (!VANY(is)) continue;
        real4 a = scene_rec(sc, r), f = scene_rec(sc, r + 4), g = scene_rec(sc, r + 5);
        m.kd = v3_sel4(m.kd, a, is); m.p_d = VSEL(m.p_d, (vreal)a.w, is);
#if CLPT_HAS_PHONG
        real4 b = scene_rec(sc, r + 1);
        m.ks = v3_sel4(m.ks, b, is); m.p_s = VSEL(m.p_s, (vreal)b.w, is);
        m.shininess = VSEL(m.shininess, (vreal)g.x, is);
#endif
#if CLPT_HAS_MIRROR
        real4 c = scene_rec(sc, r + 2);
        m.kr = v3_sel4(m.kr, c, is); m.p_r = VSEL(m.p_r, (vreal)c.w, is);
#endif
#if CLPT_HAS_GLASS
        real4 e = scene_rec(sc, r + 3);
        m.kt = v3_sel4(m.kt, e, is); m.p_t = VSEL(m.p_t, (vreal)e.w, is);
        m.ior = VSEL(m.ior, (vreal)g.y, is);
#endif
        m.Le = v3_sel4(m.Le, f, is); m.two_sided = VSEL(m.two_sided, (vreal)f.w, is);
        m.nondelta = VSEL(m.nondelta, (vreal)g.z, is);
    }
    return m;
}
