// sampling.h: warps from uniform numbers to directions and points, each
// sample_* beside the pdf it draws from. Local frames have +z along the axis.

// Orthonormal frame (t, b, n) around unit n, without branches
// (Duff et al., "Building an Orthonormal Basis, Revisited", JCGT 2017).
inline void frame_from_z(V3 n, V3 *t, V3 *b)
{
    vreal s = copysign((vreal)R(1), n.z);
    vreal a = R(-1) / (s + n.z);
    vreal c = n.x * n.y * a;
    *t = v3(R(1) + s * n.x * n.x * a, s * c, -s * n.x);
    *b = v3(c, s + n.y * n.y * a, -n.y);
}

// Local direction (x, y, z) in the frame around n, to world space.
inline V3 frame_to_world(V3 n, vreal x, vreal y, vreal z)
{
    V3 t, b;
    frame_from_z(n, &t, &b);
    return v3(x * t.x + y * b.x + z * n.x, x * t.y + y * b.y + z * n.y, x * t.z + y * b.z + z * n.z);
}

// sin x and (*c) cos x for x in [0, 2 pi] (the environment's and the microfacet
// samplers' angles; sampling that shipped scenes use keeps sincos): in float
// builds a quadrant and polynomials on [-pi/4, pi/4] (truncation below
// 2e-9; no general argument reduction, which the runtimes' sincos pays
// for every lane); in double builds sincos itself.
inline vreal poly_sincos(vreal x, vreal *c)
{
#if CLPT_DOUBLE
    return sincos(x, c);
#else
    vreal q = rint(x * R(M_2_PI));
    vreal r = (x - q * R(1.5707963705062866)) - q * R(-4.371139000186243e-8);  // x - q pi/2, two parts
    vreal r2 = r * r;
    vreal sr = r + r * r2 * (R(-1.0 / 6) + r2 * (R(1.0 / 120) + r2 * (R(-1.0 / 5040) + r2 * R(1.0 / 362880))));
    vreal cr = R(1) + r2 * (R(-0.5) + r2 * (R(1.0 / 24) + r2 * (R(-1.0 / 720) + r2 * (R(1.0 / 40320) +
                                                                                      r2 * R(-1.0 / 3628800)))));
    vreal k = q - R(4) * floor(q * R(0.25));  // the quadrant, 0..3
    vmask odd = k == R(1) || k == R(3);
    vreal sn = VSEL(sr, cr, odd), cs = VSEL(cr, sr, odd);
    *c = VSEL(cs, -cs, k == R(1) || k == R(2));
    return VSEL(sn, -sn, k >= R(2));
#endif
}

// atan2(y, x) and acos(x) for the environment's map coordinates and the
// Beckmann sampler in float builds: polynomials (fitted on [0, 1], about
// 1e-7 from the true angles, as close as the runtimes' own) at a third of
// PoCL's cost and under half of Intel's; in double builds the library's.
inline vreal poly_atan2(vreal y, vreal x)
{
#if CLPT_DOUBLE
    return atan2(y, x);
#else
    vreal ax = fabs(x), ay = fabs(y), mx = fmax(ax, ay);
    vreal a = VSEL(fmin(ax, ay) / mx, (vreal)R(0), mx == R(0));  // tan of the angle to the nearer axis
    vreal s = a * a;
    vreal p = R(-0.0014725287755042865) * s + R(0.009392663049680075);
    p = p * s + R(-0.028141420830489206);
    p = p * s + R(0.05464598857396245);
    p = p * s + R(-0.08188923705754897);
    p = p * s + R(0.10868251705609981);
    p = p * s + R(-0.14244970626866338);
    p = p * s + R(0.19996155278840844);
    p = p * s + R(-0.3333316437839989);
    p = p * s + R(0.9999999778933676);
    vreal r = a * p;
    r = VSEL(r, R(M_PI_2) - r, ay > ax);
    r = VSEL(r, R(M_PI) - r, signbit(x));
    return copysign(r, y);
#endif
}

inline vreal poly_acos(vreal x)
{
#if CLPT_DOUBLE
    return acos(x);
#else
    vreal ax = fabs(x);
    vreal p = R(0.0008004606159302055) * ax + R(-0.004413596679621504);
    p = p * ax + R(0.011701815427684864);
    p = p * ax + R(-0.02126384935019614);
    p = p * ax + R(0.032806845642495246);
    p = p * ax + R(-0.050649616459700446);
    p = p * ax + R(0.08903665585642324);
    p = p * ax + R(-0.21460144851942758);
    p = p * ax + R(1.5707963247236796);
    vreal r = sqrt(fmax(R(1) - ax, R(0))) * p;  // acos |x| = sqrt(1 - |x|) p(|x|)
    return VSEL(r, R(M_PI) - r, x < R(0));
#endif
}

// Direction around the z axis with cos(theta) = c and sin(theta) = s, at azimuth 2 pi u.
inline V3 spherical_local(vreal c, vreal s, vreal u)
{
    vreal cphi;
    vreal sphi = sincos(R(2 * M_PI) * u, &cphi);
    return v3(s * cphi, s * sphi, c);
}

// --- cosine-weighted hemisphere: theta = acos(sqrt(u1)), phi = 2 pi u2 ---
inline V3 sample_cosine_hemisphere(vreal u1, vreal u2)
{
    return spherical_local(sqrt(u1), vsafe_sqrt(R(1) - u1), u2);
}
inline vreal cosine_hemisphere_pdf(vreal cos_theta) { return fmax(cos_theta, R(0)) * R(M_1_PI); }

// --- Phong lobe: alpha = acos(u1^(1/(n+1))) around the lobe axis ----------
// pdf_sa = (n + 1) / (2 pi) cos^n(alpha). 1 - cos(alpha) is formed with expm1
// so that the lobe stays accurate (and distinct from a mirror) for n ~ 1e6.
inline V3 sample_phong_lobe(vreal u1, vreal u2, vreal n)
{
    vreal lg = log(fmax(u1, R(1e-30))) / (n + R(1));
    vreal one_minus_c = -expm1(lg);
    vreal c = R(1) - one_minus_c;
    vreal s = vsafe_sqrt(one_minus_c * (R(2) - one_minus_c));
    return spherical_local(c, s, u2);
}
// cos^n for cos in [0, 1], as exp(n log cos): PoCL's vector pow is ~6x slower.
inline vreal phong_cos_pow(vreal cos_alpha, vreal n)
{
    vreal c = fmax(cos_alpha, R(0));
    vreal p = exp(n * log(fmax(c, R(1e-30))));
    return VSEL(p, (vreal)R(0), c <= R(0));
}
inline vreal phong_lobe_pdf(vreal cos_alpha, vreal n)
{
    return (n + R(1)) * R(0.5 * M_1_PI) * phong_cos_pow(cos_alpha, n);
}

// --- cone of directions around z with 1 - cos(theta_max) = omc -------------
// pdf_sa = 1 / (2 pi omc). Taking 1 - cos(theta_max) as the input keeps tiny
// cones (a far or tiny sphere light) exact instead of rounding to zero.
inline V3 sample_uniform_cone(vreal u1, vreal u2, vreal omc)
{
    vreal k = u1 * omc;  // 1 - cos(theta)
    return spherical_local(R(1) - k, vsafe_sqrt(k * (R(2) - k)), u2);
}
inline vreal uniform_cone_pdf(vreal omc) { return R(0.5 * M_1_PI) / omc; }
// 1 - cos(theta_max) of the cone a sphere of squared radius r2 subtends from
// squared distance d2 to its centre, without cancellation for small cones
// (1 at and inside the sphere).
inline vreal sphere_cone_omc(real r2, vreal d2)
{
    vreal sin2 = fmin(r2 / d2, R(1));
    return sin2 / (R(1) + vsafe_sqrt(R(1) - sin2));
}

// --- uniform point on a triangle, as barycentrics (b1, b2) of edges e1, e2 --
inline void sample_uniform_triangle(vreal u1, vreal u2, vreal *b1, vreal *b2)
{
    vreal su = sqrt(u1);
    *b1 = R(1) - su;
    *b2 = u2 * su;
}

// --- uniform direction on the unit sphere (pdf_sa = 1 / 4 pi) ---------------
inline V3 sample_uniform_sphere(vreal u1, vreal u2)
{
    vreal c = R(1) - R(2) * u1;
    return spherical_local(c, vsafe_sqrt(R(1) - c * c), u2);
}

// --- dielectric interface --------------------------------------------------
// Unpolarized Fresnel reflectance for light meeting the interface at
// cos_i >= 0 from the side of index 1 with relative index eta = n_t / n_i.
// Total internal reflection gives 1. cos_t is returned for the refraction.
inline vreal fresnel_dielectric(vreal cos_i, vreal eta, vreal *cos_t)
{
    vreal sin2_t = (R(1) - cos_i * cos_i) / (eta * eta);
    vmask tir = sin2_t >= R(1);
    vreal ct = vsafe_sqrt(R(1) - sin2_t);
    vreal r_par = (eta * cos_i - ct) / (eta * cos_i + ct);
    vreal r_perp = (cos_i - eta * ct) / (cos_i + eta * ct);
    vreal f = R(0.5) * (r_par * r_par + r_perp * r_perp);
    *cos_t = ct;
    // eta = 1 is no interface at all; 0/0 at cos_i = 0 there is caught here too.
    f = VSEL(f, (vreal)R(0), eta == R(1));
    return VSEL(f, (vreal)R(1), tir);
}

// Refracted direction for incoming unit d, unit normal n on the incident side
// (dot(d, n) = -cos_i) and relative index eta = n_t / n_i (no TIR assumed).
inline V3 refract_dir(V3 d, V3 n, vreal cos_i, vreal cos_t, vreal eta)
{
    vreal inv = R(1) / eta;
    return v3_fma(n, cos_i * inv - cos_t, v3_scale(d, inv));
}
