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

// --- gaussian: max(0, exp(-x^2 / (2 stddev^2)) - exp(-8)), radius r = 4 stddev -------------------
// In units of r the filter is one shape, g(s) = exp(-8 s^2) - exp(-8), and
// its half [0, 1] is sampled through a table of CLPT_GAUSSIAN_TABLE_BINS
// bins (clpt/constants.py), bin k holding the half's CDF from q_k = 1 - (1 -
// k / BINS)^2 to q_k+1: the bin by direct index from the CDF, then the point
// within it with the density linear between g at its ends (within 2.6e-5 of
// g's peak everywhere). Only the ends' loads are lane by lane.
__constant real filter_gaussian_s[CLPT_GAUSSIAN_TABLE_BINS + 1] = CLPT_GAUSSIAN_TABLE_S;

inline vreal filter_gaussian_eval(vreal s) { return exp(R(-8) * s * s) - R(0.00033546262790251185); }

// The CDF of g over [-1, 1] at s (exact: erf), for offsets cut at the film's edge.
inline vreal filter_gaussian_cdf(vreal s)
{
    return R(0.5) + (R(0.31332853432887503) * erf(R(2.8284271247461903) * s) - R(0.00033546262790251185) * s)
                    * (R(0.5) / R(CLPT_GAUSSIAN_HALF_MASS));
}

// The s in [-1, 1] where g's CDF (over [-1, 1]) is p.
inline vreal filter_gaussian_inverse(vreal p)
{
    vreal t = R(2) * p - R(1), q = fmin(fabs(t), R(1));  // q: the half's CDF
    vreal v = (R(1) - sqrt(R(1) - q)) * CLPT_GAUSSIAN_TABLE_BINS;
    vreal s0, s1, kr;
#if CLPT_LANES == 1
    int k = min((int)v, CLPT_GAUSSIAN_TABLE_BINS - 1);
    s0 = filter_gaussian_s[k]; s1 = filter_gaussian_s[k + 1]; kr = (real)k;
#else
    for (int l = 0; l < CLPT_LANES; l++) {
        int k = min((int)VLANE_R(v, l), CLPT_GAUSSIAN_TABLE_BINS - 1);
        VLANE_R(s0, l) = filter_gaussian_s[k];
        VLANE_R(s1, l) = filter_gaussian_s[k + 1];
        VLANE_R(kr, l) = (real)k;
    }
#endif
    vreal e0 = R(1) - kr * (R(1) / CLPT_GAUSSIAN_TABLE_BINS), e1 = e0 - R(1) / CLPT_GAUSSIAN_TABLE_BINS;
    vreal f = clamp((q - (R(1) - e0 * e0)) / (e0 * e0 - e1 * e1), R(0), R(1));  // the fraction of the bin's mass
    // Within the bin, density g0 + (g1 - g0) d / w over d in [0, w]: its CDF reaches the
    // fraction f at the root of (g1 - g0) / (2 w) d^2 + g0 d - f (g0 + g1) w / 2.
    vreal g0 = filter_gaussian_eval(s0), g1 = filter_gaussian_eval(s1), w = s1 - s0;
    vreal m = f * (g0 + g1) * w * R(0.5);
    vreal root = sqrt(fmax(g0 * g0 + R(2) * (g1 - g0) * m / w, R(0)));
    vreal d = R(2) * m / fmax(g0 + root, R(1e-30));
    return copysign(fmin(s0 + fmin(d, w), R(1)), t);
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
        // Lane by lane: a pixel by the film's edge takes its restricted range, the others exactly
        // [0, 1], whatever pixels the work-item's other lanes hold (they take pixels in turn).
        vreal a = (vreal)R(0), b = (vreal)R(1);
        vmask edge = lo > -r || hi < r;
        if (VANY(edge)) {
            a = VSEL(a, filter_gaussian_cdf(lo * (R(1) / r)), edge);
            b = VSEL(b, filter_gaussian_cdf(hi * (R(1) / r)), edge);
        }
        return clamp(filter_gaussian_inverse(mad(u, b - a, a)) * r, lo, hi);
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
