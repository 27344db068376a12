// bsdf.h: the materials' lobes as sample / eval / pdf.
//
// A material is the paper's mix of lobes, chosen per scattering event by
// Russian roulette: diffuse (kd), modified Phong (ks, shininess), the rough
// conductor's microfacet lobe (km, alpha, eta + i k; microfacet.h), mirror
// (kr) and refraction (kt), or Mitsuba's plastic (a dielectric coating over a
// diffuse base, smooth or rough; plastic_* below) or rough dielectric
// (microfacet reflection and transmission; rough_dielectric_* below), the
// material's only lobe then; absorption takes the rest. Before rr_depth the
// absorption branch is left out (the lobe probabilities renormalized).
// Directions follow pbrt: d is the incoming ray direction, wi points away
// from the surface, n is the shading normal on the side of -d.
// Camera paths and photon paths sample the same lobes with bsdf_sample; a
// new lobe is a case in bsdf_sample, bsdf_eval and bsdf_pdf (non-delta) or
// in bsdf_sample alone (delta), its parameters in clpt/layout.py's MATERIAL
// record and material_fetch (scene.h), and a CLPT_HAS_<lobe> flag.

// The microfacet lobes' shading-frame tangent and roughness along n x s
// (microfacet.h mf_D_w, mf_G1_w): the material's with CLPT_HAS_ANISOTROPY,
// else unused (isotropic: n and alpha_u stand in).
#if CLPT_HAS_ANISOTROPY
#define MF_S(m, n) ((m)->s)
#define MF_AV(m, au) ((m)->alpha_v)
#else
#define MF_S(m, n) (n)
#define MF_AV(m, au) (au)
#endif

// Lobe probabilities of m at this depth (absorption allowed or not).
typedef struct { vreal d, s, m, r, t, p, g; } LobeProbs;

inline LobeProbs lobe_probs(const Material *m, vmask no_absorb)
{
    LobeProbs p;
#if CLPT_HAS_MICROFACET
    vreal sum = m->p_d + m->p_s + m->p_m + m->p_r + m->p_t;
#else
    vreal sum = m->p_d + m->p_s + m->p_r + m->p_t;
#endif
#if CLPT_HAS_PLASTIC
    sum += m->p_p;
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    sum += m->p_g;
#endif
    vreal k = VSEL((vreal)R(1), R(1) / sum, no_absorb && sum > R(0));
    p.d = m->p_d * k; p.s = m->p_s * k; p.r = m->p_r * k; p.t = m->p_t * k;
    p.m = m->p_m * k;
#if CLPT_HAS_PLASTIC
    p.p = m->p_p * k;
#else
    p.p = (vreal)R(0);
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    p.g = m->p_g * k;
#else
    p.g = (vreal)R(0);
#endif
    return p;
}

#if CLPT_HAS_MICROFACET
// Solid-angle pdf of wi under the microfacet lobe's sampling (visible
// normals, reflected): D(h) G1(-d, h) / (4 cos_o); 0 unless both directions
// are above the surface and on the front of h.
inline vreal microfacet_pdf(const Material *m, V3 d, V3 n, V3 wi)
{
    vreal co = -v3_dot(d, n), ci = v3_dot(wi, n);
    V3 h = v3_normalize(v3_sub(wi, d));
    vreal oh = -v3_dot(d, h);
    vmask bk = m->beckmann != R(0);
    V3 s = MF_S(m, n);
    vreal av = MF_AV(m, m->alpha);
    vreal D = mf_D_w(h, n, s, m->alpha, av, bk);
    vreal pdf = D * mf_G1_w(co, d, n, s, oh, m->alpha, av, bk) / (R(4) * co);
    return VSEL((vreal)R(0), pdf, co > R(0) && ci > R(0) && oh > R(0) && v3_dot(wi, h) > R(0) && D > R(0));
}

// The rough conductor's f without Fresnel's colour (km F(-d.h) times *k, F
// returned) and microfacet_pdf of wi in *pdf: the half vector, D and G1(-d, h)
// shared.
inline V3 microfacet_eval_pdf(const Material *m, V3 d, V3 n, V3 wi, vreal *k, vreal *pdf)
{
    vreal co = -v3_dot(d, n), ci = v3_dot(wi, n);
    V3 h = v3_normalize(v3_sub(wi, d));
    vreal oh = -v3_dot(d, h), ih = v3_dot(wi, h);
    vmask bk = m->beckmann != R(0);
    V3 s = MF_S(m, n);
    vreal av = MF_AV(m, m->alpha);
    vreal D = mf_D_w(h, n, s, m->alpha, av, bk);
    vreal g1o = mf_G1_w(co, d, n, s, oh, m->alpha, av, bk);
    vreal G = g1o * mf_G1_w(ci, wi, n, s, ih, m->alpha, av, bk);
    vreal kk = D * G / (R(4) * co * ci);
    *k = VSEL((vreal)R(0), kk, co > R(0) && ci > R(0) && D > R(0));
    vreal pd = D * g1o / (R(4) * co);
    *pdf = VSEL((vreal)R(0), pd, co > R(0) && ci > R(0) && oh > R(0) && ih > R(0) && D > R(0));
    return v3_mul(m->km, fresnel_conductor3(oh, m->eta, m->k));
}
#endif

#if CLPT_HAS_PLASTIC
// --- plastic ---------------------------------------------------------------------
// Mitsuba 3's `roughplastic` (c_alpha > 0) and `plastic` (c_alpha 0): a
// dielectric coating of index c_eta (a microfacet one of roughness c_alpha,
// or smooth) over a diffuse base kp, light scattered inside reflected back
// with the internal reflectance c_fdr. With t(mu) the coating's
// transmittance from outside at cos mu (rough: the material's table, from
// clpt/coating.py; smooth: 1 - F(mu)) and cos_o = -d.n, cos_i = wi.n:
//   f = kps D F(-d.h) G / (4 cos_o cos_i)                           (rough only)
//     + kp / (1 - c_fdr [kp if nonlinear]) t(cos_o) t(cos_i) / (pi c_eta^2)
// and, smooth, a delta reflection of weight kps F(cos_o). Sampling picks the
// specular part with Mitsuba's probability q = (1 - t_o) w / ((1 - t_o) w +
// t_o (1 - w)), w its specular sampling weight (mean kps over mean kp +
// mean kps); the diffuse part cosine-weighted.
#define COAT_TABLE_RES (4 * COAT_TABLE_ROWS)

// t(mu) of the rough coating, interpolated in its table as Mitsuba's lerp_gather.
inline vreal plastic_table(const Material *m, vreal mu)
{
    vreal x = clamp(mu, (vreal)R(0), (vreal)R(1)) * R(COAT_TABLE_RES - 1);
    vreal r = (vreal)R(0);
    vreal tab = m->c_tab;
    for (int l = 0; l < CLPT_LANES; l++) {
        real xl = VLANE_R(x, l);
        uint i = min((uint)xl, (uint)(COAT_TABLE_RES - 2));
        __global const real *t = (__global const real *)(m->rec + (uint)VLANE_R(tab, l));
        VLANE_R(r, l) = t[i] + (t[i + 1] - t[i]) * (xl - (real)i);
    }
    return r;
}

// The coating's transmittance from outside at cos mu > 0 (both kinds).
inline vreal plastic_transmittance(const Material *m, vreal mu)
{
    vreal ct;
    vreal smooth = R(1) - fresnel_dielectric(mu, m->c_eta, &ct);
    vmask rough = m->c_alpha > R(0);
    if (!VANY(rough))
        return smooth;
    return VSEL(smooth, plastic_table(m, mu), rough);
}

// Probability of the specular part when sampling from cos_o (Mitsuba's).
inline vreal plastic_spec_prob(const Material *m, vreal t_o)
{
    vreal ps = (R(1) - t_o) * m->spec_w, pd = t_o * (R(1) - m->spec_w);
    return VSEL(ps / (ps + pd), (vreal)R(0), !(ps + pd > R(0)));
}

// f of the plastic's diffuse base through its coating, for cosines co and
// ci; *t_o: the coating's transmittance at co.
inline V3 plastic_diffuse(const Material *m, vreal co, vreal ci, vreal *t_o)
{
    *t_o = plastic_transmittance(m, co);
    vreal k = *t_o * plastic_transmittance(m, ci) * R(M_1_PI) / (m->c_eta * m->c_eta);
    vmask nl = m->c_nonlinear != R(0);
    vreal fl = R(1) - m->c_fdr;
    V3 f = v3(m->kp.x / VSEL(fl, R(1) - m->kp.x * m->c_fdr, nl), m->kp.y / VSEL(fl, R(1) - m->kp.y * m->c_fdr, nl),
              m->kp.z / VSEL(fl, R(1) - m->kp.z * m->c_fdr, nl));
    return v3_scale(f, k);
}

// f of the plastic's non-delta parts (rough specular and diffuse).
inline V3 plastic_eval(const Material *m, V3 d, V3 n, V3 wi)
{
    vreal co = -v3_dot(d, n), ci = v3_dot(wi, n);
    vmask ok = co > R(0) && ci > R(0);
    vreal t_o;
    V3 f = plastic_diffuse(m, co, ci, &t_o);
    vmask rough = m->c_alpha > R(0);
    if (VANY(rough)) {
        vmask bk = m->c_beckmann != R(0);
        vreal a = VSEL((vreal)R(1), m->c_alpha, rough);
        V3 h = v3_normalize(v3_sub(wi, d));
        vreal hn = v3_dot(h, n), oh = -v3_dot(d, h), ct;
        vreal D = mf_D(hn, mf_sin2(h, n), a, bk);
        vreal G = mf_G1(co, mf_sin2(d, n), oh, a, bk) * mf_G1(ci, mf_sin2(wi, n), v3_dot(wi, h), a, bk);
        vreal F = fresnel_dielectric(oh, m->c_eta, &ct);
        vreal s = D * F * G / (R(4) * co * ci);
        f = v3_sel(f, v3_fma(m->kps, s, f), rough && D > R(0));
    }
    return v3_sel(v3_zero(), f, ok && m->p_p > R(0));
}

// Solid-angle pdf of wi under the plastic's sampling (its non-delta parts).
inline vreal plastic_pdf(const Material *m, V3 d, V3 n, V3 wi)
{
    vreal co = -v3_dot(d, n), ci = v3_dot(wi, n);
    vreal q = plastic_spec_prob(m, plastic_transmittance(m, co));
    vreal pdf = (R(1) - q) * ci * R(M_1_PI);
    vmask rough = m->c_alpha > R(0);
    if (VANY(rough)) {
        vmask bk = m->c_beckmann != R(0);
        vreal a = VSEL((vreal)R(1), m->c_alpha, rough);
        V3 h = v3_normalize(v3_sub(wi, d));
        vreal oh = -v3_dot(d, h);
        vreal D = mf_D(v3_dot(h, n), mf_sin2(h, n), a, bk);
        vreal ps = D * mf_G1(co, mf_sin2(d, n), oh, a, bk) / (R(4) * co);
        pdf = VSEL(pdf, pdf + q * ps, rough && D > R(0));
    }
    return VSEL((vreal)R(0), pdf, co > R(0) && ci > R(0) && m->p_p > R(0));
}

// plastic_eval and, in *pdf_out, plastic_pdf of wi: the coating's
// transmittance at cos_o, the half vector, D and G1(-d, h) shared.
inline V3 plastic_eval_pdf(const Material *m, V3 d, V3 n, V3 wi, vreal *pdf_out)
{
    vreal co = -v3_dot(d, n), ci = v3_dot(wi, n);
    vmask ok = co > R(0) && ci > R(0);
    vreal t_o;
    V3 f = plastic_diffuse(m, co, ci, &t_o);
    vreal q = plastic_spec_prob(m, t_o);
    vreal pdf = (R(1) - q) * ci * R(M_1_PI);
    vmask rough = m->c_alpha > R(0);
    if (VANY(rough)) {
        vmask bk = m->c_beckmann != R(0);
        vreal a = VSEL((vreal)R(1), m->c_alpha, rough);
        V3 h = v3_normalize(v3_sub(wi, d));
        vreal hn = v3_dot(h, n), oh = -v3_dot(d, h), ct;
        vreal D = mf_D(hn, mf_sin2(h, n), a, bk);
        vreal g1o = mf_G1(co, mf_sin2(d, n), oh, a, bk);
        vreal G = g1o * mf_G1(ci, mf_sin2(wi, n), v3_dot(wi, h), a, bk);
        vreal F = fresnel_dielectric(oh, m->c_eta, &ct);
        vreal s = D * F * G / (R(4) * co * ci);
        f = v3_sel(f, v3_fma(m->kps, s, f), rough && D > R(0));
        vreal ps = D * g1o / (R(4) * co);
        pdf = VSEL(pdf, pdf + q * ps, rough && D > R(0));
    }
    *pdf_out = VSEL((vreal)R(0), pdf, ok && m->p_p > R(0));
    return v3_sel(v3_zero(), f, ok && m->p_p > R(0));
}
#endif

#if CLPT_HAS_ROUGH_DIELECTRIC
// --- rough dielectric ------------------------------------------------------------
// Mitsuba 3's `roughdielectric`: one microfacet interface (GGX or Beckmann of
// roughness g_alpha, microfacet.h) that reflects and refracts through the same
// normal h (Walter et al. 2007). n faces the viewer (-d), e = g_eta is the
// index beyond the surface over the viewer's side (material_face), cos_o =
// -d.n, cos_i = wi.n, F = F(-d.h) for relative index e, G = G1(-d, h) G1(wi, h):
//   reflection (cos_i > 0),   h = normalize(wi - d):
//     f = gr F D G / (4 cos_o cos_i)
//   transmission (cos_i < 0), h = normalize(-d + e wi) turned to n's side:
//     f = gt (1 - F) D G |(-d.h)(wi.h)| / (cos_o |cos_i| (-d.h + e wi.h)^2)
// That is radiance transport: Mitsuba's factor 1/e^2 for the solid-angle
// compression cancels the e^2 of the Jacobian below (as the smooth
// dielectric's weight is kt / e^2). Sampling draws h from the normals visible
// from -d (or, g_visible 0, from D(h) cos h with Walter's widened roughness
// (1.2 - 0.2 sqrt(cos_o)) alpha, as Mitsuba does), then reflection with
// probability F, else refraction:
//   pdf = p_h(h) (F or 1 - F) |dh/dwi|,  dh/dwi = 1 / (4 wi.h) or e^2 |wi.h| / (-d.h + e wi.h)^2
// and visible normals give the weight f |cos_i| / pdf = gr G1(wi, h) or gt G1(wi, h) / e^2.

// The roughness h is drawn with: alpha, or Walter's widened one without visible normals.
inline vreal rough_dielectric_sample_alpha(const Material *m, vreal co)
{
    return VSEL(m->g_alpha * (R(1.2) - R(0.2) * vsafe_sqrt(co)), m->g_alpha, m->g_visible != R(0));
}

// f(d -> wi) of the rough dielectric, and in *pdf the solid-angle pdf of its sampling.
inline V3 rough_dielectric_eval_pdf(const Material *m, V3 d, V3 n, V3 wi, vreal *pdf)
{
    vreal co = -v3_dot(d, n), ci = v3_dot(wi, n), e = m->g_eta;
    vmask refl = ci > R(0);
    V3 h = v3_normalize(v3_fma(wi, VSEL(e, (vreal)R(1), refl), v3_neg(d)));
    h = v3_sel(h, v3_neg(h), v3_dot(h, n) < R(0));
    vreal hn = v3_dot(h, n), oh = -v3_dot(d, h), ih = v3_dot(wi, h), ct;
    vmask bk = m->g_beckmann != R(0);
    V3 s = MF_S(m, n);
    vreal av = MF_AV(m, m->g_alpha);
    vreal D = mf_D_w(h, n, s, m->g_alpha, av, bk);
    vreal g1o = mf_G1_w(co, d, n, s, oh, m->g_alpha, av, bk);
    vreal G = g1o * mf_G1_w(ci, wi, n, s, ih, m->g_alpha, av, bk);
    vreal F = fresnel_dielectric(oh, e, &ct);
    vreal den = oh + e * ih;
    vreal fr = F * D * G / (R(4) * co * ci);
    vreal ft = (R(1) - F) * D * G * fabs(oh * ih) / (co * fabs(ci) * den * den);
    vmask ok = co > R(0) && ci != R(0) && oh > R(0) && ih * ci > R(0) && D > R(0);
    vmask vis = m->g_visible != R(0);
    vreal ph = D * g1o * oh / co;
    if (!VALL(vis))  // D cos h with the widened roughness only where a lane samples it
        ph = VSEL(mf_D(hn, mf_sin2(h, n), rough_dielectric_sample_alpha(m, co), bk) * hn, ph, vis);
    vreal jac = VSEL(e * e * fabs(ih) / (den * den), R(1) / (R(4) * ih), refl);
    *pdf = VSEL((vreal)R(0), ph * VSEL(R(1) - F, F, refl) * jac, ok);
    return v3_sel(v3_zero(), v3_sel(v3_scale(m->gt, ft), v3_scale(m->gr, fr), refl), ok);
}
#endif

// f(d -> wi) of the non-delta lobes.
inline V3 bsdf_eval(const Material *m, V3 d, V3 n, V3 wi)
{
    V3 f = v3_scale(m->kd, (vreal)R(M_1_PI));
#if CLPT_HAS_PHONG
    vreal ca = v3_dot(v3_reflect(d, n), wi);
    vreal k = (m->shininess + R(2)) * R(0.5 * M_1_PI) * phong_cos_pow(ca, m->shininess);
    f = v3_fma(m->ks, k, f);
#endif
#if CLPT_HAS_MICROFACET
    vmask mf = m->p_m > R(0);
    if (VANY(mf)) {
        vreal co = -v3_dot(d, n), ci = v3_dot(wi, n);
        V3 h = v3_normalize(v3_sub(wi, d));
        vreal oh = -v3_dot(d, h);
        vmask bk = m->beckmann != R(0);
        V3 s = MF_S(m, n);
        vreal av = MF_AV(m, m->alpha);
        vreal D = mf_D_w(h, n, s, m->alpha, av, bk);
        vreal G = mf_G1_w(co, d, n, s, oh, m->alpha, av, bk) * mf_G1_w(ci, wi, n, s, v3_dot(wi, h), m->alpha, av, bk);
        vreal k = D * G / (R(4) * co * ci);
        k = VSEL((vreal)R(0), k, mf && co > R(0) && ci > R(0) && D > R(0));
        V3 F = fresnel_conductor3(oh, m->eta, m->k);
        f = v3_sel(f, v3_fma(v3_mul(m->km, F), k, f), mf);
    }
#endif
#if CLPT_HAS_PLASTIC
    if (VANY(m->p_p > R(0)))
        f = v3_add(f, plastic_eval(m, d, n, wi));
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    vmask g = m->p_g > R(0);
    if (VANY(g)) {
        vreal pdf;
        f = v3_sel(f, v3_add(f, rough_dielectric_eval_pdf(m, d, n, wi, &pdf)), g);
    }
#endif
    return f;
}

// Solid-angle pdf with which scatter() draws the non-delta direction wi:
// the mixture of the non-delta lobes by their probabilities (directions
// below the surface have none but the rough dielectric's). 0 where only
// delta lobes could be chosen.
inline vreal bsdf_pdf(const Material *m, LobeProbs p, V3 d, V3 n, V3 wi)
{
    vreal c = v3_dot(n, wi);
    vreal pdf = p.d * cosine_hemisphere_pdf(c);
#if CLPT_HAS_PHONG
    pdf += p.s * phong_lobe_pdf(v3_dot(v3_reflect(d, n), wi), m->shininess);
#endif
#if CLPT_HAS_MICROFACET
    vmask mf = p.m > R(0);
    if (VANY(mf)) {
        pdf = VSEL(pdf, pdf + p.m * microfacet_pdf(m, d, n, wi), mf);
    }
#endif
#if CLPT_HAS_PLASTIC
    vmask pp = p.p > R(0);
    if (VANY(pp))
        pdf = VSEL(pdf, pdf + p.p * plastic_pdf(m, d, n, wi), pp);
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    pdf = VSEL(pdf, (vreal)R(0), c <= R(0));
    vmask g = p.g > R(0);
    if (VANY(g)) {
        vreal pg;
        rough_dielectric_eval_pdf(m, d, n, wi, &pg);
        pdf = VSEL(pdf, pdf + p.g * pg, g);
    }
    return pdf;
#else
    return VSEL(pdf, (vreal)R(0), c <= R(0));
#endif
}

// bsdf_eval and, in *pdf, bsdf_pdf of wi (the same values), each lobe's
// shared terms computed once for both: Phong's cos^n, the microfacet lobes'
// half vector, D and G1(-d, h), the coating's transmittance at cos_o.
inline V3 bsdf_eval_pdf(const Material *m, LobeProbs p, V3 d, V3 n, V3 wi, vreal *pdf)
{
    vreal c = v3_dot(n, wi);
    V3 f = v3_scale(m->kd, (vreal)R(M_1_PI));
    vreal pd = p.d * cosine_hemisphere_pdf(c);
#if CLPT_HAS_PHONG
    vreal ca = v3_dot(v3_reflect(d, n), wi);
    vreal cp = phong_cos_pow(ca, m->shininess);
    vreal k = (m->shininess + R(2)) * R(0.5 * M_1_PI) * cp;
    f = v3_fma(m->ks, k, f);
    pd += p.s * ((m->shininess + R(1)) * R(0.5 * M_1_PI) * cp);
#endif
#if CLPT_HAS_MICROFACET
    vmask mf = m->p_m > R(0), pm = p.m > R(0);
    if (VANY(mf || pm)) {
        vreal km, pdf_m;
        V3 kf = microfacet_eval_pdf(m, d, n, wi, &km, &pdf_m);
        f = v3_sel(f, v3_fma(kf, km, f), mf);
        pd = VSEL(pd, pd + p.m * pdf_m, pm);
    }
#endif
#if CLPT_HAS_PLASTIC
    if (VANY(m->p_p > R(0) || p.p > R(0))) {
        vreal pdf_p;
        f = v3_add(f, plastic_eval_pdf(m, d, n, wi, &pdf_p));
        pd = VSEL(pd, pd + p.p * pdf_p, p.p > R(0));
    }
#endif
    pd = VSEL(pd, (vreal)R(0), c <= R(0));
#if CLPT_HAS_ROUGH_DIELECTRIC
    vmask g = m->p_g > R(0);
    if (VANY(g)) {
        vreal pg;
        f = v3_sel(f, v3_add(f, rough_dielectric_eval_pdf(m, d, n, wi, &pg)), g);
        pd = VSEL(pd, pd + p.g * pg, p.g > R(0));
    }
#endif
    *pdf = pd;
    return f;
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

// --- sampling a lobe --------------------------------------------------------------
// Camera paths carry radiance, photons carry flux (pbrt's TransportMode):
// radiance is scaled by 1/eta^2 across a refraction (pbrt, sec. 9.5.2),
// flux is not.
#define TRANSPORT_RADIANCE 0
#define TRANSPORT_IMPORTANCE 1

typedef struct {
    V3 wi;          // unit direction of the scattered ray
    V3 weight;      // f cos / pdf of the chosen lobe, over the lobe's probability
    vreal pdf;      // solid-angle pdf of wi under the whole non-delta mixture; 0 after a delta lobe
    vmask chosen;   // a lobe was chosen (not absorbed; a Phong or microfacet direction above the surface)
    vmask delta;    // ... and it is the mirror or refraction
    vmask up;       // wi leaves on the side of n (not refracted through)
} BsdfSample;

#if CLPT_HAS_MICROFACET || CLPT_HAS_PLASTIC || CLPT_HAS_ROUGH_DIELECTRIC
// A half vector (world space) from the distribution of normals visible
// from -d about the shading normal n (microfacet.h mf_sample_visible), of
// roughness au along the tangent s and av along n x s (CLPT_HAS_ANISOTROPY;
// else isotropic au in any frame, s and av unused).
inline V3 sample_half_vector(V3 d, V3 n, V3 s, vreal au, vreal av, vmask beckmann, vreal u1, vreal u2)
{
    V3 t, b;
#if CLPT_HAS_ANISOTROPY
    t = s;
    b = v3_cross(n, s);
#else
    frame_from_z(n, &t, &b);
#endif
    V3 o = v3_neg(d);
    V3 hl = mf_sample_visible(v3(v3_dot(o, t), v3_dot(o, b), v3_dot(o, n)), au, av, beckmann, u1, u2);
    return v3_normalize(v3(hl.x * t.x + hl.y * b.x + hl.z * n.x, hl.x * t.y + hl.y * b.y + hl.z * n.y,
                           hl.x * t.z + hl.y * b.z + hl.z * n.z));
}
#endif

#if CLPT_HAS_PHONG
// --- Phong lobe around the mirror direction --------------------------------------
// f = ks (n+2)/(2 pi) cos^n(alpha), pdf = (n+1)/(2 pi) cos^n(alpha):
// f cos_i / pdf = ks (n+2)/(n+1) cos_i; directions below the surface are lost.
inline void sample_phong(const Material *m, LobeProbs pr, V3 d, V3 n, BsdfU u, V3 *wi, V3 *w, vmask *is_s)
{
    V3 rdir = v3_reflect(d, n);
    V3 ll = sample_phong_lobe(u.u1, u.u2, m->shininess);
    V3 ws = frame_to_world(rdir, ll.x, ll.y, ll.z);
    vreal cos_i = v3_dot(ws, n);
    vreal k = (m->shininess + R(2)) / (m->shininess + R(1)) * fmax(cos_i, R(0)) / pr.s;
    *wi = v3_sel(*wi, ws, *is_s);
    *w = v3_sel(*w, v3_scale(m->ks, k), *is_s);
    *is_s = *is_s && cos_i > R(0);
}
#endif

#if CLPT_HAS_MICROFACET
// --- rough conductor: a visible normal h, reflected about ------------------------
// f cos_i / pdf = km F(-d.h) G1(wi, h) (microfacet.h); lost (*is_m cleared)
// where -d is below the shading normal or wi leaves below it.
inline void sample_rough_conductor(const Material *m, LobeProbs pr, V3 d, V3 n, BsdfU u, V3 *wi, V3 *w, vmask *is_m)
{
    vreal oz = -v3_dot(d, n);
    vmask bk = m->beckmann != R(0);
    V3 s = MF_S(m, n);
    vreal av = MF_AV(m, m->alpha);
    V3 h = sample_half_vector(d, n, s, m->alpha, av, bk && *is_m, u.u1, u.u2);
    vreal oh = -v3_dot(d, h);
    V3 wm = v3_reflect(d, h);
    vreal cos_i = v3_dot(wm, n);
    vreal g1 = mf_G1_w(cos_i, wm, n, s, v3_dot(wm, h), m->alpha, av, bk);
    V3 F = fresnel_conductor3(oh, m->eta, m->k);
    *wi = v3_sel(*wi, wm, *is_m);
    *w = v3_sel(*w, v3_scale(v3_mul(m->km, F), g1 / pr.m), *is_m);
    *is_m = *is_m && oz > R(0) && oh > R(0) && cos_i > R(0) && g1 > R(0);
}
#endif

#if CLPT_HAS_PLASTIC
// --- plastic: the coating's specular part with Mitsuba's probability q, else
// the diffuse base (cosine-weighted: lc, local); weight f cos / (pdf p_p), the
// smooth coating's reflection kps F / (q p_p), a delta lobe (*p_delta) ---------
inline void sample_plastic(const Material *m, LobeProbs pr, V3 d, V3 n, BsdfU u, V3 lc, V3 *wi, V3 *w,
                           vmask *is_p, vmask *p_delta)
{
    vreal co = -v3_dot(d, n), ct;
    vreal q = plastic_spec_prob(m, plastic_transmittance(m, co));
    vmask spec = u.fresnel < q;
    vmask rough = m->c_alpha > R(0);
    V3 wp = frame_to_world(n, lc.x, lc.y, lc.z);
    vmask rs = spec && rough;
    if (VANY(rs && *is_p)) {
        vreal a = VSEL((vreal)R(1), m->c_alpha, rough);
        V3 h = sample_half_vector(d, n, MF_S(m, n), a, a, m->c_beckmann != R(0) && rs && *is_p, u.u1, u.u2);
        wp = v3_sel(wp, v3_reflect(d, h), rs);
    }
    vmask sd = spec && !rough;  // smooth: the mirror direction, a delta lobe
    wp = v3_sel(wp, v3_reflect(d, n), sd);
    V3 wpn = v3_normalize(wp);
    vreal pdf;
    V3 fp = plastic_eval_pdf(m, d, n, wpn, &pdf);
    V3 wnd = v3_scale(fp, v3_dot(wpn, n) / (pdf * pr.p));
    V3 wd = v3_scale(m->kps, fresnel_dielectric(co, m->c_eta, &ct) / (q * pr.p));
    *wi = v3_sel(*wi, wpn, *is_p);
    *w = v3_sel(*w, v3_sel(wnd, wd, sd), *is_p);
    *p_delta = *is_p && sd && co > R(0);
    *is_p = *is_p && co > R(0) && (sd || (pdf > R(0) && v3_dot(wpn, n) > R(0)));
}
#endif

#if CLPT_HAS_ROUGH_DIELECTRIC
// --- rough dielectric: a microfacet normal h (visible normals of -d, or D cos
// with the widened roughness), then reflection about h with probability F, else
// refraction through it; *up cleared where refracted. Weight f cos / (pdf p_g)
// (radiance: the transmitted one over e^2); lost (*is_g cleared) where -d is
// below n or the direction leaves on the wrong side of n ---------------------
inline void sample_rough_dielectric(const Material *m, LobeProbs pr, V3 d, V3 n, BsdfU u, int mode, V3 *wi,
                                    V3 *w, vreal *pdf_g, vmask *is_g, vmask *up)
{
    vreal co = -v3_dot(d, n), e = m->g_eta;
    vmask bk = m->g_beckmann != R(0), vis = m->g_visible != R(0);
    V3 s = MF_S(m, n);
    vreal av = MF_AV(m, m->g_alpha);
    V3 h = sample_half_vector(d, n, s, m->g_alpha, av, bk && *is_g, u.u1, u.u2);
    if (VANY(!vis && *is_g)) {
        // D(h) cos h: tan^2 theta = a^2 u1 / (1 - u1) (GGX) or -a^2 log(1 - u1) (Beckmann).
        vreal a = rough_dielectric_sample_alpha(m, co);
        vreal t2 = a * a * VSEL(u.u1 / (R(1) - u.u1), -log(R(1) - u.u1), bk);
        vreal c = vrsqrt(R(1) + t2), s = vsafe_sqrt(R(1) - c * c), cp;
        vreal sp = poly_sincos(R(2 * M_PI) * u.u2, &cp);
        h = v3_sel(h, frame_to_world(n, s * cp, s * sp, c), !vis);
    }
    vreal oh = -v3_dot(d, h), ct;
    vreal F = fresnel_dielectric(oh, e, &ct);
    vmask refl = u.fresnel <= F;
    V3 wg = v3_normalize(v3_sel(refract_dir(d, h, oh, ct, e), v3_reflect(d, h), refl));
    vreal cg = v3_dot(wg, n);
    vreal g1 = mf_G1_w(cg, wg, n, s, v3_dot(wg, h), m->g_alpha, av, bk);
    // Importance (flux) crosses without the radiance's 1 / e^2.
    vreal kt = mode == TRANSPORT_RADIANCE ? R(1) / (e * e) : (vreal)R(1);
    V3 wv = v3_sel(v3_scale(m->gt, kt), m->gr, refl);
    vreal k = g1 / pr.g;
    vmask ok = co > R(0) && oh > R(0) && VSEL(cg < R(0), cg > R(0), refl) && g1 > R(0);
    // The lobe's pdf of wg (rough_dielectric_eval_pdf's): visible normals' density of h, the lobe's
    // choice, the Jacobian of the half-vector map.
    vreal ih = v3_dot(wg, h), den = oh + e * ih;
    vreal ph = mf_D_w(h, n, s, m->g_alpha, av, bk) * mf_G1_w(co, d, n, s, oh, m->g_alpha, av, bk) * oh / co;
    vreal pdf = ph * VSEL(R(1) - F, F, refl) * VSEL(e * e * fabs(ih) / (den * den), R(1) / (R(4) * ih), refl);
    if (VANY(!vis && *is_g)) {
        vreal pn;
        V3 f = rough_dielectric_eval_pdf(m, d, n, wg, &pn);
        V3 wn = v3_scale(f, fabs(cg) / (pn * pr.g));
        wv = v3_sel(wv, v3_scale(wn, VSEL(e * e * kt, (vreal)R(1), refl)), !vis);
        k = VSEL(k, (vreal)R(1), !vis);
        ok = ok && (vis || pn > R(0));
        pdf = VSEL(pdf, pn, !vis);
    }
    *pdf_g = VSEL(*pdf_g, pdf, *is_g);
    *wi = v3_sel(*wi, wg, *is_g);
    *w = v3_sel(*w, v3_scale(wv, k), *is_g);
    *up = *up && !(*is_g && !refl);
    *is_g = *is_g && ok;
}
#endif

// A lobe of m chosen by Russian roulette over pr (u.lobe), and a direction
// in it, at a vertex with shading normal n facing -d (front: d arrives from
// outside), into *out. `alive` masks the lanes sampled. With nondelta 0 (a
// constant where this is inlined: photons, which stop at the first
// non-delta vertex) only the mirror and refraction are compiled.
CLPT_INLINE void bsdf_sample(const Material *m, LobeProbs pr, V3 d, V3 n, vmask front, vmask alive, BsdfU u,
                             int mode, int nondelta, BsdfSample *out)
{
    BsdfSample bs;
    // --- Russian roulette over the lobes --------------------------------------
    vreal c = u.lobe;
    vmask is_d = c < pr.d;
    vmask is_s = !is_d && c < pr.d + pr.s;
#if CLPT_HAS_MICROFACET
    vreal c_m = pr.d + pr.s + pr.m;
    vmask is_m = !is_d && !is_s && c < c_m;
#else
    vreal c_m = pr.d + pr.s;
    vmask is_m = is_d && !is_d;
#endif
#if CLPT_HAS_PLASTIC
    vmask is_p = !is_d && !is_s && !is_m && c < c_m + pr.p;
    c_m += pr.p;
#else
    vmask is_p = is_d && !is_d;
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
    vmask is_g = !is_d && !is_s && !is_m && !is_p && c < c_m + pr.g;
    c_m += pr.g;
#else
    vmask is_g = is_d && !is_d;
#endif
    vmask is_r = !is_d && !is_s && !is_m && !is_p && !is_g && c < c_m + pr.r;
    vmask is_t = !is_d && !is_s && !is_m && !is_p && !is_g && !is_r && c < c_m + pr.r + pr.t;
    vmask p_delta = is_p && !is_p;  // the smooth plastic's specular reflection
#if CLPT_HAS_ROUGH_DIELECTRIC
    vreal pdf_g = (vreal)R(0);  // the rough dielectric's pdf of the direction it drew
#endif
    V3 wi = v3_reflect(d, n);
    V3 w = v3_scale(m->kr, R(1) / pr.r);
    bs.up = alive;
    if (nondelta) {
        // --- diffuse: cosine-weighted; f cos / pdf = kd ---------------------------
        V3 lc = sample_cosine_hemisphere(u.u1, u.u2);
        wi = frame_to_world(n, lc.x, lc.y, lc.z);
        w = v3_scale(m->kd, R(1) / pr.d);
#if CLPT_HAS_PHONG
        if (VANY(is_s))
            sample_phong(m, pr, d, n, u, &wi, &w, &is_s);
#endif
#if CLPT_HAS_MICROFACET
        if (VANY(is_m))
            sample_rough_conductor(m, pr, d, n, u, &wi, &w, &is_m);
#endif
#if CLPT_HAS_PLASTIC
        if (VANY(is_p))
            sample_plastic(m, pr, d, n, u, lc, &wi, &w, &is_p, &p_delta);
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
        if (VANY(is_g))
            sample_rough_dielectric(m, pr, d, n, u, mode, &wi, &w, &pdf_g, &is_g, &bs.up);
#endif
    } else {
        is_m = is_m && !is_m;
        is_p = is_p && !is_p;
        is_g = is_g && !is_g;
    }
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
        V3 wt = dielectric_sample(d, n, front, m->ior, u.fresnel, &refl, &eta);
        wi = v3_sel(wi, wt, is_t);
        vreal k = mode == TRANSPORT_RADIANCE ? VSEL(R(1) / (eta * eta), (vreal)R(1), refl) / pr.t : R(1) / pr.t;
        w = v3_sel(w, v3_scale(m->kt, k), is_t);
        bs.up = bs.up && !(is_t && !refl);
    }
#endif
    bs.chosen = is_d || is_s || is_m || is_p || is_g || is_r || is_t;
    bs.delta = is_r || is_t || p_delta;
    bs.wi = v3_normalize(wi);
    bs.weight = w;
    // The pdf of the direction under the whole non-delta mixture (what light
    // sampling's weight is measured against), not only the chosen lobe's.
#if CLPT_HAS_ROUGH_DIELECTRIC
    // A rough dielectric is its material's only lobe: its lanes' pdf is the one it drew with.
    LobeProbs po = pr;
    po.g = (vreal)R(0);
    bs.pdf = nondelta ? VSEL(VSEL((vreal)R(0), bsdf_pdf(m, po, d, n, bs.wi), is_d || is_s || is_m || (is_p && !p_delta)),
                             pr.g * pdf_g, is_g)
                      : (vreal)R(0);
#else
    bs.pdf = nondelta ? VSEL((vreal)R(0), bsdf_pdf(m, pr, d, n, bs.wi), is_d || is_s || is_m || (is_p && !p_delta))
                      : (vreal)R(0);
#endif
    *out = bs;
}
