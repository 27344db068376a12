// bsdf.h: evaluation of the materials' non-delta lobes.

// Phong lobes of this shininess or more are too narrow for light sampling
// (n = 1000: half the lobe's energy within ~2 degrees of the mirror
// direction, where light samples seldom land): their direct light comes from
// the lobe's own samples hitting an emitter, and next event estimation leaves
// them out. Each lobe's direct light has exactly one estimator either way.
#ifndef PHONG_NEE_MAX_N
#define PHONG_NEE_MAX_N R(1000)
#endif

// f(wo, wi) of the non-delta lobes that next event estimation covers, for
// incoming direction d and shading normal n on the side of -d.
inline V3 brdf_eval(const Material *m, V3 d, V3 n, V3 wi)
{
    V3 f = v3_scale(m->kd, (vreal)R(M_1_PI));
#if CLPT_HAS_PHONG
    vreal ca = v3_dot(v3_reflect(d, n), wi);
    vreal k = (m->shininess + R(2)) * R(0.5 * M_1_PI) * phong_cos_pow(ca, m->shininess);
    k = VSEL(k, (vreal)R(0), m->shininess >= PHONG_NEE_MAX_N);
    f = v3_fma(m->ks, k, f);
#endif
    return f;
}

// Dielectric interface: Fresnel reflectance F picks reflection (u < F) or
// refraction. n faces the incoming direction d; `front` says d arrives from
// outside, so the relative index eta = n_t / n_i is ior or 1 / ior.
inline V3 dielectric_sample(V3 d, V3 n, vmask front, vreal ior, vreal u, vmask *reflected, vreal *eta)
{
    vreal e = VSEL(R(1) / ior, ior, front);
    vreal cos_i = -v3_dot(d, n);
    vreal cos_t;
    vreal F = fresnel_dielectric(cos_i, e, &cos_t);
    vmask refl = u < F;
    *reflected = refl;
    *eta = e;
    return v3_sel(refract_dir(d, n, cos_i, cos_t, e), v3_reflect(d, n), refl);
}
