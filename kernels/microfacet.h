// microfacet.h: the microfacet lobes' distribution, as Mitsuba 3 defines
// its `roughconductor` (GGX or Beckmann, isotropic or anisotropic, Smith
// shadowing-masking with Mitsuba's rational approximation of Beckmann's G1,
// conductor Fresnel with a complex index per channel, sampling of the
// distribution of visible normals). Directions follow bsdf.h: d is the
// incoming ray direction (so -d points to the viewer), wi the scattered
// one, n the unit shading normal on the side of -d. Isotropic roughness
// makes D and G1 functions of cosines alone, so eval and pdf need no
// tangent frame and sampling draws the half vector in any frame around n;
// anisotropic roughness (alpha_u along the shading frame's tangent s, the
// surface's dp/du made normal to n, alpha_v along n x s) needs s: builds
// with CLPT_HAS_ANISOTROPY carry it in the material (scene.h
// material_tangent) and use the mf_*_w forms below.
//
//   f(d -> wi) = km F(-d.h) D(h) G1(-d, h) G1(wi, h) / (4 cos_o cos_i),  h = normalize(wi - d)
//   pdf(wi)    = D(h) G1(-d, h) / (4 cos_o)                  (visible normals, reflected)
//   f cos_i / pdf = km F(-d.h) G1(wi, h)
// where cos_o = -d.n and cos_i = wi.n.

// D(h) of a half vector with cos theta = c and t = (x / alpha_u)^2 + (y /
// alpha_v)^2 (its tangent-plane components over the roughness along them),
// a2 = alpha_u alpha_v; 0 where c <= 0 (Mitsuba: D cos > 1e-20).
inline vreal mf_D_core(vreal c, vreal t, vreal a2, vmask beckmann)
{
    // Each distribution only where a lane has it (vectors of one material are the rule).
    vreal c2 = c * c, r = (vreal)R(0);
    if (!VALL(beckmann))
        r = R(1) / (R(M_PI) * a2 * (t + c2) * (t + c2));
    if (VANY(beckmann))
        r = VSEL(r, exp(-t / c2) / (R(M_PI) * a2 * c2 * c2), beckmann);
    return VSEL((vreal)R(0), r, r * c > R(1e-20));
}

// Isotropic D of a half vector with cos theta = c and sin^2 theta = s2.
inline vreal mf_D(vreal c, vreal s2, vreal alpha, vmask beckmann)
{
    vreal a2 = alpha * alpha;
    return mf_D_core(c, s2 / a2, a2, beckmann);
}

// Smith's G1 for a direction with cos theta = cv and xy = (alpha_u x)^2 +
// (alpha_v y)^2 (its tangent-plane components times the roughness along
// them), whose cosine with the half vector is vh: 0 where v sees the
// microfacet from behind (vh cv <= 0), 1 at normal incidence.
inline vreal mf_G1_core(vreal cv, vreal xy, vreal vh, vmask beckmann)
{
    vreal tan2 = xy / (cv * cv), r = (vreal)R(0);
    if (!VALL(beckmann))
        r = R(2) / (R(1) + sqrt(R(1) + tan2));
    if (VANY(beckmann)) {
        vreal a = vrsqrt(tan2);
        vreal beck = (R(3.535) * a + R(2.181) * a * a) / (R(1) + R(2.276) * a + R(2.577) * a * a);
        r = VSEL(r, VSEL(beck, (vreal)R(1), a >= R(1.6)), beckmann);
    }
    r = VSEL(r, (vreal)R(1), xy == R(0));
    return VSEL(r, (vreal)R(0), vh * cv <= R(0));
}

// Isotropic G1 of a direction with cos theta = cv and sin^2 theta = s2.
inline vreal mf_G1(vreal cv, vreal s2, vreal vh, vreal alpha, vmask beckmann)
{
    return mf_G1_core(cv, alpha * alpha * s2, vh, beckmann);
}

// sin^2 of the angle between unit v and unit n, without the cancellation of 1 - (v.n)^2.
inline vreal mf_sin2(V3 v, V3 n)
{
    V3 c = v3_cross(v, n);
    return fmin(v3_dot(c, c), R(1));
}

// Unpolarized Fresnel reflectance of a conductor of complex index eta + i k
// at cos_i (Mitsuba 3's fresnel_conductor, after Moeller, "Optics").
inline vreal fresnel_conductor(vreal cos_i, vreal eta, vreal k)
{
    vreal c2 = cos_i * cos_i, s2 = R(1) - c2, s4 = s2 * s2;
    vreal t1 = eta * eta - k * k - s2;
    vreal a2pb2 = vsafe_sqrt(t1 * t1 + R(4) * k * k * eta * eta);
    vreal a = vsafe_sqrt(R(0.5) * (a2pb2 + t1));
    vreal term1 = a2pb2 + c2, term2 = R(2) * cos_i * a;
    vreal term3 = a2pb2 * c2 + s4, term4 = term2 * s2;
    // (rs + rp) / 2 with rs = (term1 - term2) / (term1 + term2), rp = rs (term3 - term4) /
    // (term3 + term4): rs term3 / (term3 + term4), one division.
    return (term1 - term2) * term3 / ((term1 + term2) * (term3 + term4));
}

inline V3 fresnel_conductor3(vreal cos_i, V3 eta, V3 k)
{
    return v3(fresnel_conductor(cos_i, eta.x, k.x), fresnel_conductor(cos_i, eta.y, k.y),
              fresnel_conductor(cos_i, eta.z, k.z));
}

// Inverse error function (Giles, "Approximating the erfinv function", GPU
// Computing Gems; single precision), its argument clamped to +-0.99999.
inline vreal mf_erfinv(vreal x)
{
    x = clamp(x, (vreal)R(-0.99999), (vreal)R(0.99999));
    vreal w = -log((R(1) - x) * (R(1) + x));
    vreal w1 = w - R(2.5);
    vreal p1 = (vreal)R(2.81022636e-08);
    p1 = mad(p1, w1, (vreal)R(3.43273939e-07));
    p1 = mad(p1, w1, (vreal)R(-3.5233877e-06));
    p1 = mad(p1, w1, (vreal)R(-4.39150654e-06));
    p1 = mad(p1, w1, (vreal)R(0.00021858087));
    p1 = mad(p1, w1, (vreal)R(-0.00125372503));
    p1 = mad(p1, w1, (vreal)R(-0.00417768164));
    p1 = mad(p1, w1, (vreal)R(0.246640727));
    p1 = mad(p1, w1, (vreal)R(1.50140941));
    // The tail's polynomial (|x| > ~0.9966) only where a lane needs it.
    vmask tail = w >= R(5);
    if (!VANY(tail))
        return p1 * x;
    vreal w2 = sqrt(w) - R(3);
    vreal p2 = (vreal)R(-0.000200214257);
    p2 = mad(p2, w2, (vreal)R(0.000100950558));
    p2 = mad(p2, w2, (vreal)R(0.00134934322));
    p2 = mad(p2, w2, (vreal)R(-0.00367342844));
    p2 = mad(p2, w2, (vreal)R(0.00573950773));
    p2 = mad(p2, w2, (vreal)R(-0.0076224613));
    p2 = mad(p2, w2, (vreal)R(0.00943887047));
    p2 = mad(p2, w2, (vreal)R(1.00167406));
    p2 = mad(p2, w2, (vreal)R(2.83297682));
    return VSEL(p2, p1, w < R(5)) * x;
}

// erf(x) for x >= 0 given e = exp(-x^2), in float builds (PoCL's erf costs
// about four times Intel's): x p(x^2) below 1, else 1 - e q(1 / x) (q fits
// erfc(x) exp(x^2) on [1, 4]; beyond, 1 in float); within a few ulps of erf.
inline vreal mf_erf(vreal x, vreal e)
{
#if CLPT_DOUBLE
    return erf(x);
#else
    vreal s = x * x;
    vreal p = R(7.933398701311101e-05) * s + R(-0.0008034821788238805);
    p = p * s + R(0.005191216019853895);
    p = p * s + R(-0.02685539847959624);
    p = p * s + R(0.11283625709235437);
    p = p * s + R(-0.3761262987717299);
    p = p * s + R(1.1283791665934326);
    vreal t = R(1) / x;
    vreal q = R(-0.018689448252039415) * t + R(0.12443236511659511);
    q = q * t + R(-0.3611206840699069);
    q = q * t + R(0.5825398471737456);
    q = q * t + R(-0.5096885778407367);
    q = q * t + R(0.052208753366818655);
    q = q * t + R(0.5575374971664107);
    q = q * t + R(0.0003638333464359373);
    return VSEL(R(1) - e * q, x * p, x < R(1));
#endif
}

// A slope (x, y) of the unit-roughness distribution's visible normals seen
// from cos theta = ci (> 0) in the stretched space, whose azimuth is 0
// (Heitz and d'Eon 2014; the Beckmann inversion as in Mitsuba and pbrt-v3:
// Newton steps on the CDF, kept inside a bisection interval).
inline void mf_sample_slopes(vreal ci, vreal u1, vreal u2, vmask beckmann, vreal *sx, vreal *sy)
{
    vreal si = vsafe_sqrt(R(1) - ci * ci);
    // --- GGX: a uniform disk point projected onto the visible half ------------------
    vreal r = sqrt(u1), cphi;
    vreal sphi = poly_sincos(R(2 * M_PI) * u2, &cphi);
    vreal px = r * cphi, py = r * sphi;
    vreal s = R(0.5) * (R(1) + ci);
    py = mad(vsafe_sqrt(R(1) - px * px), R(1) - s, py * s);
    vreal pz = vsafe_sqrt(R(1) - px * px - py * py);
    vreal inv = R(1) / mad(si, py, ci * pz);
    vreal gx = (ci * py - si * pz) * inv, gy = px * inv;
    *sx = gx;
    *sy = gy;
    if (!VANY(beckmann))
        return;
    // --- Beckmann --------------------------------------------------------------------
    vreal tan_i = si / ci, cot_i = ci / si;
    vreal e_cot = exp(-cot_i * cot_i);
    vreal a = (vreal)R(-1), c = mf_erf(cot_i, e_cot);
    vreal ux = fmax(u1, R(1e-6));
    vreal th = poly_acos(ci);
    vreal fit = R(1) + th * (R(-0.876) + th * (R(0.4265) - R(0.0594) * th));
    // (1 - ux)^fit as exp(fit log(1 - ux)): PoCL's vector pow is several times slower.
    vreal b = c - (R(1) + c) * exp(fit * log(R(1) - ux));
    const real sqrt_pi_inv = R(0.56418958354775628);
    vreal norm = R(1) / (R(1) + c + sqrt_pi_inv * tan_i * e_cot);
    // pbrt-v3's iteration: a lane stops where its CDF is within 1e-5 of ux
    // (its slope the erfinv just taken), the loop once every lane has, or
    // after 9 steps. Each lane's result is its own, whatever its neighbours do.
    // Lanes seen from below or at grazing (ci <= 0, or NaN: directions their
    // callers discard) start done too: their CDF is NaN, and they would
    // otherwise hold every lane of the vector through all 9 steps.
    vmask normal = ci > R(0.9999);
    vreal bx = (vreal)R(0);
    vmask done = !beckmann || normal || !(ci > R(0));
    for (int it = 0; it < 9; it++) {
        b = VSEL(R(0.5) * (a + c), b, b >= a && b <= c);
        vreal ie = mf_erfinv(b);
        vreal value = norm * (R(1) + b + sqrt_pi_inv * tan_i * exp(-ie * ie)) - ux;
        vreal deriv = norm * (R(1) - ie * tan_i);
        vmask conv = !done && fabs(value) < R(1e-5);
        bx = VSEL(bx, ie, conv);
        done = done || conv;
        if (VALL(done))
            break;
        vmask pos = value > R(0);
        c = VSEL(c, VSEL(c, b, pos), !done);
        a = VSEL(a, VSEL(b, a, pos), !done);
        b = VSEL(b, b - value / deriv, !done);
    }
    if (!VALL(done)) {
        b = VSEL(R(0.5) * (a + c), b, b >= a && b <= c);
        bx = VSEL(mf_erfinv(b), bx, done);
    }
    vreal by = mf_erfinv(R(2) * fmax(u2, R(1e-6)) - R(1));
    // Normal incidence: the distribution itself.
    vreal rr = sqrt(-log(fmax(R(1) - u1, R(1e-30))));
    bx = VSEL(bx, rr * cphi, normal);
    by = VSEL(by, rr * sphi, normal);
    *sx = VSEL(gx, bx, beckmann);
    *sy = VSEL(gy, by, beckmann);
}

// A half vector from the distribution of normals visible from wo (local,
// z along the normal, x along the roughness au, y along av, wo.z > 0):
// stretch wo, draw a slope, rotate it to wo's azimuth, unstretch
// (Mitsuba's sample_visible).
inline V3 mf_sample_visible(V3 wo, vreal au, vreal av, vmask beckmann, vreal u1, vreal u2)
{
    V3 ws = v3_normalize(v3(au * wo.x, av * wo.y, wo.z));
    vreal sxy = sqrt(ws.x * ws.x + ws.y * ws.y);
    vreal cphi = VSEL(ws.x / sxy, (vreal)R(1), sxy == R(0));
    vreal sphi = VSEL(ws.y / sxy, (vreal)R(0), sxy == R(0));
    vreal sx, sy;
    mf_sample_slopes(ws.z, u1, u2, beckmann, &sx, &sy);
    vreal mx = (cphi * sx - sphi * sy) * au;
    vreal my = (sphi * sx + cphi * sy) * av;
    return v3_normalize(v3(-mx, -my, (vreal)R(1)));
}

// D and G1 of world-space vectors about the shading normal n: anisotropic
// (roughness au along the unit tangent s, av along n x s) with
// CLPT_HAS_ANISOTROPY, else isotropic in au (s and av unused).
#if CLPT_HAS_ANISOTROPY
inline vreal mf_D_w(V3 h, V3 n, V3 s, vreal au, vreal av, vmask beckmann)
{
    vreal x = v3_dot(h, s) / au, y = v3_dot(h, v3_cross(n, s)) / av;
    return mf_D_core(v3_dot(h, n), x * x + y * y, au * av, beckmann);
}

inline vreal mf_G1_w(vreal cv, V3 v, V3 n, V3 s, vreal vh, vreal au, vreal av, vmask beckmann)
{
    vreal x = v3_dot(v, s) * au, y = v3_dot(v, v3_cross(n, s)) * av;
    return mf_G1_core(cv, x * x + y * y, vh, beckmann);
}
#else
inline vreal mf_D_w(V3 h, V3 n, V3 s, vreal au, vreal av, vmask beckmann)
{
    return mf_D(v3_dot(h, n), mf_sin2(h, n), au, beckmann);
}

inline vreal mf_G1_w(vreal cv, V3 v, V3 n, V3 s, vreal vh, vreal au, vreal av, vmask beckmann)
{
    return mf_G1(cv, mf_sin2(v, n), vh, au, beckmann);
}
#endif
