// camera.h: pinhole camera, and the pixel filter's sampling of where in the
// image a camera sample goes. The host computes the image-plane frame:
//   corner  direction to the top-left corner of the image (plane at distance 1)
//   dx, dy  steps of one pixel to the right and down
//
// Pixel filters (CLPT_PIXEL_FILTER: 0 box, 1 tent, 2 gaussian; Mitsuba 3's
// rfilters, clpt/scene.py PixelFilter). With the box a sample's ray passes
// through a uniformly random point of its pixel, so a pixel is the
// box-filtered mean of its samples. The other filters are importance
// sampled (pbrt-v4's filter importance sampling): the sample's offset from
// the pixel centre is drawn from the normalized, separable filter, so every
// sample has weight 1, each pixel stays an independent mean of its own
// samples, and its expectation is Mitsuba's weighted splatting, sum w L /
// sum w. Mitsuba samples positions inside the film only (its sample_border
// off, the default): a pixel near the edge then sees its filter cut at the
// film's edge, which is sampling the filter restricted to the film
// (FilterRec.sample_border == 0); with sample_border the whole filter.

inline V3 camera_ray(real4 corner, real4 dx, real4 dy, vreal px, vreal py)
{
    V3 d = v3(corner.x + px * dx.x + py * dy.x,
              corner.y + px * dx.y + py * dy.y,
              corner.z + px * dx.z + py * dy.z);
    return v3_normalize(d);
}

// --- tent: max(0, 1 - |x| / r) ----------------------------------------------------------------
// Its integral from 0 to x (odd in x), and the inverse of that on [-r/2, r/2].
inline vreal filter_tent_integral(vreal x, real r) { return x - x * fabs(x) / (R(2) * r); }

inline vreal filter_tent_inverse(vreal t, real r)
{
    return copysign(r * (R(1) - vsafe_sqrt(R(1) - R(2) * fabs(t) / r)), t);
}

// --- gaussian: max(0, exp(-x^2 / (2 stddev^2)) - bias), bias = its value at r = 4 stddev --------
inline vreal filter_gaussian_eval(vreal x, real stddev, real bias)
{
    return fmax(exp(x * x * (R(-0.5) / (stddev * stddev))) - bias, (vreal)R(0));
}

// Its integral from 0 to x (odd in x), for |x| <= r.
inline vreal filter_gaussian_integral(vreal x, real stddev, real bias)
{
    return stddev * R(1.2533141373155003) * erf(x * (R(0.7071067811865476) / stddev)) - bias * x;
}

// The x in [lo, hi] whose integral is t (filter_gaussian_integral(lo) <= t
// <= ...(hi)), by Newton's method from the better (the shorter Newton step)
// of two guesses: the normal distribution's quantile (Abramowitz and Stegun
// 26.2.23, within 4.5e-4 stddev of the unwindowed root) and, for the far
// tails where the window dominates, the root of the filter's integral
// linearized at the radius, bias r / (2 stddev^2) (r - |x|)^2. Every
// evaluation shrinks a bracket around the root, and a step that would leave
// it bisects instead. Converged to the precision of real in
// FILTER_NEWTON_STEPS (tests/test_camera.py).
#if CLPT_DOUBLE
#define FILTER_NEWTON_STEPS 5
#else
#define FILTER_NEWTON_STEPS 4
#endif

inline vreal filter_gaussian_inverse(vreal t, vreal lo, vreal hi, real stddev, real bias, real r)
{
    real mass = stddev * R(1.2533141373155003) * erf(r * (R(0.7071067811865476) / stddev)) - bias * r;
    vreal p = R(0.5) + t * (R(0.5) / mass);  // the whole filter's CDF at the root
    vreal q = clamp(fmin(p, R(1) - p), R(1e-30), R(0.5)), side = copysign((vreal)R(1), p - R(0.5));
    vreal s = sqrt(R(-2) * log(q));
    vreal z = s - (R(2.515517) + s * (R(0.802853) + s * R(0.010328)))
                  / (R(1) + s * (R(1.432788) + s * (R(0.189269) + s * R(0.001308))));
    vreal xa = clamp(side * z * stddev, lo, hi);
    vreal xb = clamp(side * (r - sqrt(R(4) * stddev * stddev * mass * q / (bias * r))), lo, hi);
    vreal ga = filter_gaussian_integral(xa, stddev, bias) - t, gb = filter_gaussian_integral(xb, stddev, bias) - t;
    vreal fa = filter_gaussian_eval(xa, stddev, bias), fb = filter_gaussian_eval(xb, stddev, bias);
    lo = fmax(lo, fmax(VSEL(lo, xa, ga <= R(0)), VSEL(lo, xb, gb <= R(0))));
    hi = fmin(hi, fmin(VSEL(hi, xa, ga >= R(0)), VSEL(hi, xb, gb >= R(0))));
    vmask pick_b = fabs(gb) * fa < fabs(ga) * fb;  // |gb / fb| < |ga / fa|, 0 / 0 never picked
    vreal x = VSEL(xa, xb, pick_b), g = VSEL(ga, gb, pick_b), f = VSEL(fa, fb, pick_b);
    for (int i = 0; i < FILTER_NEWTON_STEPS; i++) {
        vreal xn = x - g / f;
        x = VSEL(R(0.5) * (lo + hi), xn, f > R(0) && xn >= lo && xn <= hi);
        g = filter_gaussian_integral(x, stddev, bias) - t;
        f = filter_gaussian_eval(x, stddev, bias);
        lo = VSEL(lo, x, g <= R(0));
        hi = VSEL(hi, x, g >= R(0));
    }
    return x;
}

// The offset from the pixel centre c (in pixels, along one axis of an image
// n pixels long) for u in [0, 1): drawn from filter `kind` (CLPT_PIXEL_FILTER's
// numbering; a constant where the build knows it), restricted to the film
// unless f->sample_border.
CLPT_INLINE vreal filter_sample_offset(const FilterRec *f, int kind, vreal u, vreal c, real n)
{
    real r = f->radius;
    vreal lo = (vreal)(-r), hi = (vreal)r;
    if (!f->sample_border) {
        lo = fmax(lo, -c);
        hi = fmin(hi, n - c);
    }
    if (kind == 1) {
        vreal a = filter_tent_integral(lo, r), b = filter_tent_integral(hi, r);
        return clamp(filter_tent_inverse(mad(u, b - a, a), r), lo, hi);
    }
    if (kind == 2) {
        vreal a = filter_gaussian_integral(lo, f->stddev, f->bias), b = filter_gaussian_integral(hi, f->stddev, f->bias);
        return filter_gaussian_inverse(mad(u, b - a, a), lo, hi, f->stddev, f->bias, r);
    }
    return u - R(0.5);  // the box (radius 0.5: never restricted)
}

// The camera sample of pixel (px, py) as a position within the pixel (the
// image position is px + .x, py + .y): the pixel centre plus the filter's offset.
inline CameraU camera_filter_sample(const FilterRec *f, CameraU u, vreal px, vreal py, uint width, uint height)
{
    CameraU o;
    o.x = R(0.5) + filter_sample_offset(f, CLPT_PIXEL_FILTER, u.x, px + R(0.5), (real)width);
    o.y = R(0.5) + filter_sample_offset(f, CLPT_PIXEL_FILTER, u.y, py + R(0.5), (real)height);
    return o;
}
