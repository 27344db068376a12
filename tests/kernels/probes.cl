// probes.cl: thin kernels exposing kernels/*.h functions to the tests. Built
// only by tests/conftest.py, with the library files stitched in front.
// One work-item handles CLPT_LANES consecutive elements of each array.

// (LD, ST, LD3, ST3 and LDU: tests/kernels/lane_io.cl, stitched in before this file)

__kernel void probe_layout(__global int *out)
{
    out[0] = MAT_STRIDE; out[1] = SPHERE_STRIDE; out[2] = PLANAR_STRIDE; out[3] = PLANE_STRIDE;
    out[4] = LIGHT_STRIDE; out[5] = LIGHT_KIND_QUAD; out[6] = LIGHT_KIND_TRIANGLE; out[7] = LIGHT_KIND_SPHERE;
}

// sizeof and the offset of every field of each struct clpt/layout.py defines
// (the launch records), in its order (the host generates the list:
// PROBE_RECORD_FIELDS).
__kernel void probe_record_layout(__global uint *out)
{
    uint k = 0;
#define PROBE_SIZE(T) out[k++] = (uint)sizeof(T);
#define PROBE_FIELD(T, f) { T r_; out[k++] = (uint)((private char *)&r_.f - (private char *)&r_); }
    PROBE_RECORD_FIELDS
#undef PROBE_SIZE
#undef PROBE_FIELD
}

__kernel void probe_rng(uint seed, __global const uint *pixel, __global const uint *sample,
                        __global const uint *group, __global real *a, __global real *b, __global real *c,
                        __global real *d)
{
    size_t i = get_global_id(0);
    Rand4 r = rng_uniform4(seed, LDU(pixel, i), LDU(sample, i), LDU(group, i));
    ST(r.a, a, i); ST(r.b, b, i); ST(r.c, c, i); ST(r.d, d, i);
}

// Every named dimension of sampler.h for (seed, pixel, sample, depth), in
// the order test_sampler.py reads them: camera x, y; light pick, u1, u2;
// merge; bsdf lobe, u1, u2, fresnel; photon (index = pixel) emission pick,
// u1, u2, caster, aim u1, u2; photon bounce `bounce` lobe, fresnel. Work-item
// i writes out[(18 i + k) * CLPT_LANES + lane].
__kernel void probe_sampler(uint seed, uint bounce, __global const uint *pixel, __global const uint *sample,
                            __global const uint *depth, __global real *out)
{
    size_t i = get_global_id(0);
    SamplerKeys keys = sampler_keys_make(seed, LDU(pixel, i));
    Sampler s = sampler_make(seed, LDU(pixel, i), LDU(sample, i), &keys);
    vreal d = VREAL(LDU(depth, i));
    CameraU c = sample_camera(&s);
    LightU l = sample_light(&s, d);
    BsdfU b = sample_bsdf(&s, d);
    PhotonSampler ps = photon_sampler_make(seed, LDU(pixel, i));
    EmitU e = sample_photon_emission(&ps);
    BsdfU pb = sample_photon_bounce(&ps, bounce);
    vreal v[18] = {c.x, c.y, l.pick, l.u1, l.u2, sample_merge(&s, d), b.lobe, b.u1, b.u2, b.fresnel,
                   e.light.pick, e.light.u1, e.light.u2, e.caster, e.u1, e.u2, pb.lobe, pb.fresnel};
    for (int k = 0; k < 18; k++)
        ST(v[k], out, 18 * i + k);
}

__kernel void probe_cosine_hemisphere(__global const real *u1, __global const real *u2,
                                      __global real *x, __global real *y, __global real *z, __global real *pdf)
{
    size_t i = get_global_id(0);
    V3 w = sample_cosine_hemisphere(LD(u1, i), LD(u2, i));
    ST3(w, x, y, z, i);
    ST(cosine_hemisphere_pdf(w.z), pdf, i);
}

__kernel void probe_phong_lobe(__global const real *u1, __global const real *u2, real n,
                               __global real *x, __global real *y, __global real *z, __global real *pdf)
{
    size_t i = get_global_id(0);
    V3 w = sample_phong_lobe(LD(u1, i), LD(u2, i), (vreal)n);
    ST3(w, x, y, z, i);
    ST(phong_lobe_pdf(w.z, (vreal)n), pdf, i);
}

__kernel void probe_uniform_cone(__global const real *u1, __global const real *u2, real omc,
                                 __global real *x, __global real *y, __global real *z)
{
    size_t i = get_global_id(0);
    V3 w = sample_uniform_cone(LD(u1, i), LD(u2, i), (vreal)omc);
    ST3(w, x, y, z, i);
}

__kernel void probe_uniform_sphere(__global const real *u1, __global const real *u2,
                                   __global real *x, __global real *y, __global real *z)
{
    size_t i = get_global_id(0);
    V3 w = sample_uniform_sphere(LD(u1, i), LD(u2, i));
    ST3(w, x, y, z, i);
}

__kernel void probe_uniform_triangle(__global const real *u1, __global const real *u2,
                                     __global real *b1, __global real *b2)
{
    size_t i = get_global_id(0);
    vreal a, b;
    sample_uniform_triangle(LD(u1, i), LD(u2, i), &a, &b);
    ST(a, b1, i); ST(b, b2, i);
}

__kernel void probe_frame(__global const real *nx, __global const real *ny, __global const real *nz,
                          __global real *tx, __global real *ty, __global real *tz,
                          __global real *bx, __global real *by, __global real *bz)
{
    size_t i = get_global_id(0);
    V3 t, b;
    frame_from_z(LD3(nx, ny, nz, i), &t, &b);
    ST3(t, tx, ty, tz, i);
    ST3(b, bx, by, bz, i);
}

__kernel void probe_fresnel(__global const real *cos_i, __global const real *eta, __global real *f,
                            __global real *cos_t)
{
    size_t i = get_global_id(0);
    vreal ct;
    ST(fresnel_dielectric(LD(cos_i, i), LD(eta, i), &ct), f, i);
    ST(ct, cos_t, i);
}

__kernel void probe_refract(__global const real *dx, __global const real *dy, __global const real *dz,
                            __global const real *nx, __global const real *ny, __global const real *nz,
                            __global const real *eta, __global real *wx, __global real *wy, __global real *wz)
{
    size_t i = get_global_id(0);
    V3 d = LD3(dx, dy, dz, i), n = LD3(nx, ny, nz, i);
    vreal e = LD(eta, i);
    vreal cos_i = -v3_dot(d, n), cos_t;
    fresnel_dielectric(cos_i, e, &cos_t);
    ST3(refract_dir(d, n, cos_i, cos_t, e), wx, wy, wz, i);
}

inline Scene probe_scene(__global const real4 *rec, __constant SceneInfo *info)
{
    return scene_make(rec, *info);
}

__kernel void probe_intersect(__global const real4 *rec, __constant SceneInfo *info,
                              __global const real *ox, __global const real *oy, __global const real *oz,
                              __global const real *dx, __global const real *dy, __global const real *dz,
                              __global real *t, __global real *nx, __global real *ny, __global real *nz,
                              __global real *mat, __global real *occluded)
{
    size_t i = get_global_id(0);
    Scene s = probe_scene(rec, info);
    V3 o = LD3(ox, oy, oz, i), d = LD3(dx, dy, dz, i);
    Hit h = scene_intersect(&s, o, d);
    ST(h.t, t, i);
    ST3(h.ng, nx, ny, nz, i);
    ST(h.mat, mat, i);
    vmask all = h.t == h.t || h.t != h.t;
    vmask occ = scene_occluded(&s, o, d, (vreal)R(INFINITY), all);
    ST(VSEL((vreal)R(0), (vreal)R(1), occ), occluded, i);
}

// Closest hit (t, primitive, barycentrics, geometric normal) and shadow
// queries with a finite tmax, for comparing the BVH with the plain loops.
__kernel void probe_hit(__global const real4 *rec, __constant SceneInfo *info,
                        __global const real *ox, __global const real *oy, __global const real *oz,
                        __global const real *dx, __global const real *dy, __global const real *dz,
                        __global const real *tmax,
                        __global real *t, __global real *prim, __global real *bu, __global real *bv,
                        __global real *nx, __global real *ny, __global real *nz, __global real *light,
                        __global real *occluded)
{
    size_t i = get_global_id(0);
    Scene s = probe_scene(rec, info);
    V3 o = LD3(ox, oy, oz, i), d = LD3(dx, dy, dz, i);
    Hit h = scene_intersect(&s, o, d);
    ST(h.t, t, i); ST(h.prim, prim, i); ST(h.bu, bu, i); ST(h.bv, bv, i); ST(h.light, light, i);
    ST3(h.ng, nx, ny, nz, i);
    vmask all = h.t == h.t || h.t != h.t;
    vmask occ = scene_occluded(&s, o, d, LD(tmax, i), all);
    ST(VSEL((vreal)R(0), (vreal)R(1), occ), occluded, i);
}

// Shading normal at the closest hit, on the side facing the ray.
__kernel void probe_shading_normal(__global const real4 *rec, __constant SceneInfo *info,
                                   __global const real *ox, __global const real *oy, __global const real *oz,
                                   __global const real *dx, __global const real *dy, __global const real *dz,
                                   __global real *nx, __global real *ny, __global real *nz)
{
    size_t i = get_global_id(0);
    Scene s = probe_scene(rec, info);
    V3 o = LD3(ox, oy, oz, i), d = LD3(dx, dy, dz, i);
    Hit h = scene_intersect(&s, o, d);
    vmask front = v3_dot(h.ng, d) < R(0);
    V3 n = hit_shading_normal(&s, &h, v3_sel(v3_neg(h.ng), h.ng, front));
    ST3(n, nx, ny, nz, i);
}

// Adds x[lane] n times to fresh pixel sums, as the trace kernel adds samples.
__kernel void probe_accumulate(__global const real *x, uint n, __global pix_sum_t *ps, __global pix_sq_t *pq)
{
    size_t i = get_global_id(0);
    Film a;
    film_zero(&a);
    vreal v = LD(x, i);
    vmask all = v == v || v != v;
    for (uint k = 0; k < n; k++) {
        acc_add(&a.r, v, all);
        acc_add(&a.n, (vreal)R(1), all);
        acc_add(&a.sq, v * v, all);
    }
    for (int l = 0; l < CLPT_LANES; l++)
        film_store_lane(&a, l, ps, pq, i * CLPT_LANES + l);
}

// photon_gather_one for each query point (one per work-item, whatever the lanes).
__kernel void probe_gather(__global const float4 *ph_pos, __global const float4 *ph_dir,
                           __global const float4 *ph_pow, __global const uint *bucket_start, uint mask,
                           uint max_photons, uint budget, real radius, real inv_cell, real cone_k, real4 kd, real4 ks_n,
                           __global const real *q, __global real *out)
{
    size_t i = get_global_id(0);
    PhotonMap pm;
    pm.pos = ph_pos; pm.dir = ph_dir; pm.pow = ph_pow; pm.bucket_start = bucket_start;
    pm.mask = mask; pm.max_photons = max_photons; pm.budget = budget;
    pm.radius = radius; pm.inv_cell = inv_cell; pm.cone_k = cone_k; pm.mis_k = R(0);
    photon_map_derive(&pm);
    __global const real *a = q + 10 * i;
    real3 x = (real3)(a[0], a[1], a[2]), n = (real3)(a[3], a[4], a[5]), d = (real3)(a[6], a[7], a[8]);
    real m2 = R(0);  // (no second moment: lw = 0)
    real3 L = photon_gather_one(&pm, x, n, d, kd.xyz, ks_n.xyz, ks_n.w, a[9], R(1), R(0), 0, R(INFINITY),
                                (real3)(R(0)), &m2);
    out[3 * i] = L.x; out[3 * i + 1] = L.y; out[3 * i + 2] = L.z;
}

// For a light sample from each point: its pdf, and the pdf light_pdf_hit
// gives the point when a ray along the sample's direction hits it (what a
// BSDF-sampled hit of that light uses for its multiple-importance weight),
// 0 where the ray meets something else first.
__kernel void probe_light_pdf(__global const real4 *rec, __constant SceneInfo *info,
                              __global const real *px, __global const real *py, __global const real *pz,
                              __global const real *u0, __global const real *u1, __global const real *u2,
                              __global real *pdf_sample, __global real *pdf_hit)
{
    size_t i = get_global_id(0);
    Scene s = probe_scene(rec, info);
    V3 x = LD3(px, py, pz, i);
    LightU u;
    u.pick = LD(u0, i); u.u1 = LD(u1, i); u.u2 = LD(u2, i);
    LightSample ls;
    light_sample(&s, x, u, 1, u.pick == u.pick, &ls);
    Hit h = scene_intersect(&s, x, ls.wi);
    vreal p = light_pdf_hit(&s, h.light, x, v3_fma(ls.wi, h.t, x), h.ng, h.t);
    ST(VSEL((vreal)R(0), ls.pdf, ls.valid), pdf_sample, i);
    // Only where the ray's first hit is the sampled point (not another light in the way).
    ST(VSEL((vreal)R(0), p, fabs(h.t - ls.dist) < R(1e-4) * ls.dist), pdf_hit, i);
}

// What a ray leaving the scene along each unit direction d sees of the
// environment (lights.h env_emission, as path.h's escape event calls it):
// its radiance (r, g, b) and the pdf light_sample draws d with.
__kernel void probe_env_emission(__global const real4 *rec, __constant SceneInfo *info,
                                 __global const real *dx, __global const real *dy, __global const real *dz,
                                 __global real *r, __global real *g, __global real *b, __global real *pdf)
{
    size_t i = get_global_id(0);
    Scene s = probe_scene(rec, info);
    V3 d = LD3(dx, dy, dz, i);
    vreal p = (vreal)R(0);
    V3 Le = v3_zero();
#if CLPT_HAS_ENV_LIGHT
    Le = env_emission(&s, d, d.x == d.x, &p);
#endif
    ST(Le.x, r, i); ST(Le.y, g, i); ST(Le.z, b, i);
    ST(p, pdf, i);
}

// The pixel filter's offset (camera.h filter_sample_offset) for filter `kind`
// (0 box, 1 tent, 2 gaussian), for samples u of pixel centres c of an image n
// pixels wide.
__kernel void probe_pixel_filter(int kind, real radius, uint sample_border, real n,
                                 __global const real *u, __global const real *c, __global real *out)
{
    size_t i = get_global_id(0);
    FilterRec f;
    f.radius = radius; f.sample_border = sample_border;
    ST(filter_sample_offset(&f, kind, LD(u, i), LD(c, i), n), out, i);
}

// The lobe probes' outputs (probe_plastic, probe_rough_dielectric): sample bs
// (direction, weight, pdf, chosen, and the mask `flag` into flag_out), then
// f and pdf of w; the probe's names m, pr, d, n, i and buffers.
#define PROBE_STORE(flag, flag_out) do {                                         \
        ST3(bs.wi, sx, sy, sz, i);                                               \
        ST3(bs.weight, fr, fg, fb, i);                                           \
        ST(bs.pdf, spdf, i);                                                     \
        ST(VSEL((vreal)R(0), (vreal)R(1), bs.chosen), chosen, i);               \
        ST(VSEL((vreal)R(0), (vreal)R(1), flag), flag_out, i);                  \
        V3 w = LD3(wx, wy, wz, i);                                               \
        ST3(bsdf_eval(&m, d, n, w), er, eg, eb, i);                              \
        ST(bsdf_pdf(&m, pr, d, n, w), epdf, i);                                  \
    } while (0)

// A material built by hand: no lobe but a non-delta one to come (tables at tab).
inline Material probe_material_blank(__global const real4 *tab)
{
    Material m = material_blank(tab);
    m.nondelta = (vreal)R(1);
#if CLPT_HAS_ANISOTROPY
    m.s = v3((vreal)R(1), (vreal)R(0), (vreal)R(0));  // the shading frame: x, y, the normal z
#endif
    return m;
}

// The rough conductor's lobe (bsdf.h, microfacet.h) at a vertex with normal
// +z, alone in its material: for each incoming direction d, a sample from
// (u1, u2) (its direction, weight f cos / pdf, mixture pdf and whether a lobe
// was chosen) and f and pdf of the given direction w.
// par: alpha (alpha_u, along x), 1 for Beckmann, alpha_v (along y; 0: alpha);
// eta, k: the conductor's index; km: reflectance.
__kernel void probe_microfacet(real4 par, real4 eta, real4 k, real4 km,
                               __global const real *dx, __global const real *dy, __global const real *dz,
                               __global const real *u1, __global const real *u2,
                               __global const real *wx, __global const real *wy, __global const real *wz,
                               __global real *sx, __global real *sy, __global real *sz,
                               __global real *fr, __global real *fg, __global real *fb,
                               __global real *spdf, __global real *chosen,
                               __global real *er, __global real *eg, __global real *eb, __global real *epdf)
{
    size_t i = get_global_id(0);
    Material m = probe_material_blank(0);
    m.km = v3_splat(km); m.eta = v3_splat(eta); m.k = v3_splat(k);
    m.p_m = (vreal)R(1); m.alpha = (vreal)par.x; m.beckmann = (vreal)par.y;
#if CLPT_HAS_ANISOTROPY
    m.alpha_v = (vreal)(par.z > R(0) ? par.z : par.x);
#endif
    LobeProbs pr = lobe_probs(&m, (vmask)0);
    V3 n = v3((vreal)R(0), (vreal)R(0), (vreal)R(1));
    V3 d = LD3(dx, dy, dz, i);
    BsdfU u;
    u.lobe = (vreal)R(0.5); u.u1 = LD(u1, i); u.u2 = LD(u2, i); u.fresnel = (vreal)R(0.5);
    vmask all = (vmask)(-1);
    BsdfSample bs;
    bsdf_sample(&m, pr, d, n, all, all, u, TRANSPORT_RADIANCE, 1, &bs);
    ST3(bs.wi, sx, sy, sz, i);
    ST3(bs.weight, fr, fg, fb, i);
    ST(bs.pdf, spdf, i);
    ST(VSEL((vreal)R(0), (vreal)R(1), bs.chosen), chosen, i);
    V3 w = LD3(wx, wy, wz, i);
    V3 f = bsdf_eval(&m, d, n, w);
    ST3(f, er, eg, eb, i);
    ST(bsdf_pdf(&m, pr, d, n, w), epdf, i);
}

#if CLPT_HAS_PLASTIC
// The plastic's lobe (bsdf.h) at a vertex with normal +z, alone in its
// material, as probe_microfacet: a sample per incoming direction d from
// (u1, u2, uf: the specular/diffuse choice), and f and pdf of w.
// tab: the transmittance table (COAT_TABLE_ROWS rows); par: the record's
// coat row (eta, internal reflectance, alpha (0: smooth), 1 for Beckmann); kp: diffuse
// reflectance, nonlinear; kps: specular reflectance, specular sampling weight.
__kernel void probe_plastic(__global const real4 *tab, real4 par, real4 kp, real4 kps,
                            __global const real *dx, __global const real *dy, __global const real *dz,
                            __global const real *u1, __global const real *u2, __global const real *uf,
                            __global const real *wx, __global const real *wy, __global const real *wz,
                            __global real *sx, __global real *sy, __global real *sz,
                            __global real *fr, __global real *fg, __global real *fb,
                            __global real *spdf, __global real *chosen, __global real *delta,
                            __global real *er, __global real *eg, __global real *eb, __global real *epdf)
{
    size_t i = get_global_id(0);
    Material m = probe_material_blank(tab);
    m.kp = v3_splat(kp); m.kps = v3_splat(kps);
    m.p_p = (vreal)R(1); m.spec_w = (vreal)kps.w;
    m.c_eta = (vreal)par.x; m.c_fdr = (vreal)par.y; m.c_alpha = (vreal)par.z; m.c_beckmann = (vreal)par.w;
    m.c_tab = (vreal)R(0); m.c_nonlinear = (vreal)kp.w;
    LobeProbs pr = lobe_probs(&m, (vmask)0);
    V3 n = v3((vreal)R(0), (vreal)R(0), (vreal)R(1));
    V3 d = LD3(dx, dy, dz, i);
    BsdfU u;
    u.lobe = (vreal)R(0.5); u.u1 = LD(u1, i); u.u2 = LD(u2, i); u.fresnel = LD(uf, i);
    vmask all = (vmask)(-1);
    BsdfSample bs;
    bsdf_sample(&m, pr, d, n, all, all, u, TRANSPORT_RADIANCE, 1, &bs);
    PROBE_STORE(bs.delta, delta);
}
#endif

#if CLPT_HAS_ROUGH_DIELECTRIC
// The rough dielectric's lobe (bsdf.h) at a vertex with normal +z, alone in
// its material, as probe_microfacet: incoming directions d from above (front)
// or below (the normal turned to face them, the index inverted, as
// vertex_make does), a sample per d from (u1, u2, uf: reflection or
// refraction), and f and pdf of w. par: alpha, 1 for Beckmann, eta (inside
// over outside), sample_visible; kr, kt: specular reflectance and
// transmittance, kr.w: alpha_v (along y; 0: alpha), kt.w: 1 for importance
// transport (photons) instead of radiance.
__kernel void probe_rough_dielectric(real4 par, real4 kr, real4 kt,
                                     __global const real *dx, __global const real *dy, __global const real *dz,
                                     __global const real *u1, __global const real *u2, __global const real *uf,
                                     __global const real *wx, __global const real *wy, __global const real *wz,
                                     __global real *sx, __global real *sy, __global real *sz,
                                     __global real *fr, __global real *fg, __global real *fb,
                                     __global real *spdf, __global real *chosen, __global real *up,
                                     __global real *er, __global real *eg, __global real *eb, __global real *epdf)
{
    size_t i = get_global_id(0);
    Material m = probe_material_blank(0);
    m.gr = v3_splat(kr); m.gt = v3_splat(kt);
    m.p_g = (vreal)R(1); m.g_alpha = (vreal)par.x; m.g_beckmann = (vreal)par.y; m.g_eta = (vreal)par.z;
    m.g_visible = (vreal)par.w;
#if CLPT_HAS_ANISOTROPY
    m.alpha_v = (vreal)(kr.w > R(0) ? kr.w : par.x);
#endif
    V3 d = LD3(dx, dy, dz, i);
    vmask front = d.z < R(0);
    material_face(&m, front);
    LobeProbs pr = lobe_probs(&m, (vmask)0);
    V3 n = v3((vreal)R(0), (vreal)R(0), VSEL((vreal)R(-1), (vreal)R(1), front));
    BsdfU u;
    u.lobe = (vreal)R(0.5); u.u1 = LD(u1, i); u.u2 = LD(u2, i); u.fresnel = LD(uf, i);
    vmask all = (vmask)(-1);
    BsdfSample bs;
    bsdf_sample(&m, pr, d, n, front, all, u, kt.w > 0 ? TRANSPORT_IMPORTANCE : TRANSPORT_RADIANCE, 1, &bs);
    PROBE_STORE(bs.up, up);
}
#endif
