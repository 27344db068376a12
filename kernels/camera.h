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

#define FILTER_NEWTON_STEPS 6

// The x in [lo, hi] whose integral is t (filter_gaussian_integral(lo) <= t
// <= ...(hi)): Newton's method from a logistic fit of the normal
// distribution, each step kept inside the bracket, which shrinks around the
// root (a step that would leave it bisects instead). Converged to the
// precision of real in FILTER_NEWTON_STEPS (tests/test_camera.py).
inline vreal filter_gaussian_inverse(vreal t, vreal lo, vreal hi, real stddev, real bias, real r)
{
    real mass = stddev * R(1.2533141373155003) * erf(r * (R(0.7071067811865476) / stddev)) - bias * r;
    vreal p = clamp(R(0.5) + t * (R(0.5) / mass), R(1e-6), R(1) - R(1e-6));  // the whole filter's CDF
    vreal x = clamp(stddev * (R(1) / R(1.702)) * log(p / (R(1) - p)), lo, hi);
    for (int i = 0; i < FILTER_NEWTON_STEPS; i++) {
        vreal g = filter_gaussian_integral(x, stddev, bias) - t;
        lo = VSEL(lo, x, g <= R(0));
        hi = VSEL(hi, x, g >= R(0));
        vreal f = filter_gaussian_eval(x, stddev, bias);
        vreal xn = x - g / f;
        x = VSEL(R(0.5) * (lo + hi), xn, f > R(0) && xn >= lo && xn <= hi);
    }
    return x;
}

// The offset from the pixel centre c (in pixels, along one axis of an image
// n pixels long) for u in [0, 1): drawn from the filter, restricted to the
// film unless f->sample_border.
inline vreal filter_sample_offset(const FilterRec *f, vreal u, vreal c, real n)
{
    real r = f->radius;
    vreal lo = (vreal)(-r), hi = (vreal)r;
    if (!f->sample_border) {
        lo = fmax(lo, -c);
        hi = fmin(hi, n - c);
    }
#if CLPT_PIXEL_FILTER == 1
    vreal a = filter_tent_integral(lo, r), b = filter_tent_integral(hi, r);
    return clamp(filter_tent_inverse(mad(u, b - a, a), r), lo, hi);
#elif CLPT_PIXEL_FILTER == 2
    vreal a = filter_gaussian_integral(lo, f->stddev, f->bias), b = filter_gaussian_integral(hi, f->stddev, f->bias);
    return filter_gaussian_inverse(mad(u, b - a, a), lo, hi, f->stddev, f->bias, r);
#else
    return u - R(0.5);  // the box
#endif
}

// The camera sample of pixel (px, py) as a position within the pixel (the
// image position is px + .x, py + .y): the pixel centre plus the filter's offset.
inline CameraU camera_filter_sample(const FilterRec *f, CameraU u, vreal px, vreal py, uint width, uint height)
{
    CameraU o;
    o.x = R(0.5) + filter_sample_offset(f, u.x, px + R(0.5), (real)width);
    o.y = R(0.5) + filter_sample_offset(f, u.y, py + R(0.5), (real)height);
    return o;
}
