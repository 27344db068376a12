// bsdf.h: the materials' lobes as sample / eval / pdf.
//
// A material is the paper's mix of lobes, chosen per scattering event by
// Russian roulette: diffuse (kd), modified Phong (ks, shininess), mirror (kr)
// and refraction (kt); absorption takes the rest. Before rr_depth the
// absorption branch is left out (the lobe probabilities renormalized).
// Directions follow pbrt: d is the incoming ray direction, wi points away
// from the surface, n is the shading normal on the side of -d.

// Lobe probabilities of m at this depth (absorption allowed or not).
typedef struct { vreal d, s, r, t; } LobeProbs;

inline LobeProbs lobe_probs(const Material *m, vmask no_absorb)
{
    LobeProbs p;
    vreal sum = m->p_d + m->p_s + m->p_r + m->p_t;
    vreal k = VSEL((vreal)R(1), R(1) / sum, no_absorb && sum > R(0));
    p.d = m->p_d * k; p.s = m->p_s * k; p.r = m->p_r * k; p.t = m->p_t * k;
    return p;
}

// f(d -> wi) of the non-delta lobes.
inline V3 bsdf_eval(const Material *m, V3 d, V3 n, V3 wi)
{
    V3 f = v3_scale(m->kd, (vreal)R(M_1_PI));
#if CLPT_HAS_PHONG
    vreal ca = v3_dot(v3_reflect(d, n), wi);
    vreal k = (m->shininess + R(2)) * R(0.5 * M_1_PI) * phong_cos_pow(ca, m->shininess);
    f = v3_fma(m->ks, k, f);
#endif
    return f;
}

// Solid-angle pdf with which scatter() draws the non-delta direction wi:
// the mixture of the cosine and Phong lobes by their probabilities (directions
// below the surface have none). 0 where only delta lobes could be chosen.
inline vreal bsdf_pdf(const Material *m, LobeProbs p, V3 d, V3 n, V3 wi)
{
    vreal c = v3_dot(n, wi);
    vreal pdf = p.d * cosine_hemisphere_pdf(c);
#if CLPT_HAS_PHONG
    pdf += p.s * phong_lobe_pdf(v3_dot(v3_reflect(d, n), wi), m->shininess);
#endif
    return VSEL(pdf, (vreal)R(0), c <= R(0));
}

// Power heuristic (beta = 2) weight of a technique with pdf a against one with pdf b.
// Formed from b / a so that neither square can overflow.
inline vreal mis_power(vreal a, vreal b)
{
    vreal q = b / a;
    vreal w = R(1) / (R(1) + q * q);
    w = VSEL(w, (vreal)R(0), a <= R(0) || isnan(w));
    return VSEL(w, (vreal)R(1), !(b > R(0)));
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
