// filter.cl: the edge-aware cone filter, as three kernels.
//
// Both work on the demodulated image (colour divided by the first-hit albedo,
// so texture and colour edges are not blurred; the host multiplies the albedo
// back) without the parts the host keeps out of it: emission seen directly and
// the photon map's caustics, which are added back sharp.
//
// filter_firefly: a pixel brighter than every one of its 8 neighbours by more
// than k standard errors (the noise: the median over the 3x3 of the variances
// of the pixel means) is scaled down to that bound, and its variance set to
// that median, unless its own samples confirm it: a pixel still above the
// bound by k_confirm of its own standard errors is left alone. A firefly (one
// sample's outlier among n) has a standard error about as large as its
// value and is always clamped; a highlight that most of the pixel's samples
// see is not. For noise of light tails the bound is almost never reached
// (8 neighbours and k = 3: under 0.2% of pixels for Gaussian noise); what it
// cuts is the energy of fireflies, a bias the host measures.
//
// filter_cone: one a-trous pass of a cone kernel w_s = 1 - r / (radius + 1)
// over the taps (dx, dy) * step, |dx|, |dy| <= radius, clipped to the image.
// Each tap's weight is cut where the guides disagree:
//   normals   max(0, n_p . n_q)^sigma_normal (both missing: 1; one: 0)
//   depth     exp(-|z_p - z_q| / (sigma_depth * z_p * r * step))
//   albedo    exp(-|a_p - a_q|^2 / sigma_albedo^2)
//   emitter   a pixel that sees a light and one that does not: 0
//   value     exp(-|L_p - L_q| / (sigma_lum * s_p + 1e-6)), L the luminance
//             smoothed over the 3x3 (1 2 1 weights, filter_luma) and s_p the
//             standard error of p's mean smoothed the same way (SVGF's
//             choice): differences beyond p's noise (edges of shadows) are
//             kept, and a firefly next to a calm pixel is not taken in by it.
//             The smoothed luminances compare with a third of the noise of
//             the pixels' own, so the test can be tighter for the same
//             acceptance of noise: shading edges are kept better.
// The guides' factor g (normals, depth, albedo) gets a floor: w = w_s (g +
// guide_floor) exp(-value term), so pixels on an edge, whose guides are a mix
// of both sides' and match neither, still average with their neighbours where
// the values agree (the value term and the emitter test have no floor).
// out = c_p + sum w (c_q - c_p) / sum w: a
// constant region stays exactly constant, and radius 0 is the identity. The
// variance of the output, sum w^2 v_q / (sum w)^2, feeds the next pass.
// With `fit` (the host's last pass), the taps' differences d_q = c_q - c_p
// are fitted by a plane a + b x + c y in the tap's position (x, y = dx, dy over
// radius, -1 to 1; weighted least squares with the same weights, the centre's
// 1 included, and a ridge of 1e-3 sum w on the slopes) and out = c_p + a: a
// gradient (a wall's falloff, a soft shadow) is not flattened, so that pass
// can average taps farther apart in value. A constant region still stays
// exactly constant; the variance written is the averaging's (nothing reads
// the last pass's).
//
// Layout: planar images of `pitch` (the width rounded up to 8) columns, each
// plane `plane` floats long with `margin` floats before and after the pixels
// (zeros, so that lanes outside the image read finite values):
//   color: r, g, b, variance of the pixel mean, smoothed luminance and variance (filter_luma)
//   guides: normal x, y, z (0 if none), emitter flag (0/1), albedo r, g, b, depth
// All three kernels: one work-item per 8 pixels of a row, in float8 lanes
// (global size height * pitch / 8); any local size. The lanes past the width
// (the rows' padding) write zeros in filter_firefly and filter_luma, as the
// host's upload would, and what the pass computes there in filter_cone; the
// taps that read them have weight 0. The margins are never written.

inline float8 luma8(float8 r, float8 g, float8 b)
{
    return (float)CLPT_LUMA_R * r + (float)CLPT_LUMA_G * g + (float)CLPT_LUMA_B * b;
}

#define LD8(buf, k, off) vload8(0, (buf) + (k) * plane + (off))

__kernel void filter_firefly(__global const float *color_in, uint width, uint height, uint pitch, uint plane,
                             uint margin, float k, float k_confirm, int any_nan, __global float *color_out)
{
    uint gid = get_global_id(0);
    uint per_row = pitch / 8u;
    if (gid >= per_row * height)
        return;
    int y = (int)(gid / per_row), x0 = (int)(gid % per_row) * 8;
    int ym = (int)height - 1;
    int8 xs = (int8)(x0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    int8 inside = xs < (int)width;
    int o = (int)margin + y * (int)pitch + x0;
    // Pixels outside the image count as +inf variance, n as 0 luminance (rows
    // outside read a clamped row's address, columns the padding or the margin).
    float8 v[9];
    int8 n = 0;
    float8 lmax = -INFINITY;
    for (int dy = -1; dy <= 1; dy++) {
        int qy = y + dy;
        int row_in = qy >= 0 && qy <= ym;
        int off = (int)margin + clamp(qy, 0, ym) * (int)pitch + x0;
        for (int dx = -1; dx <= 1; dx++) {
            int8 qx = xs + dx;
            int8 in = qx >= 0 && qx < (int)width && (int8)(row_in ? -1 : 0);
            v[(dy + 1) * 3 + dx + 1] = select((float8)(INFINITY), LD8(color_in, 3, off + dx), in);
            n -= in;  // in: -1 where true
            if (dx != 0 || dy != 0)
                lmax = select(lmax, fmax(lmax, luma8(LD8(color_in, 0, off + dx), LD8(color_in, 1, off + dx),
                                                     LD8(color_in, 2, off + dx))), in);
        }
    }
    // The median of the n variances in the image: the one of rank n / 2 (ties
    // ranked by position; n / 2 <= 4 and the outside's +inf rank last).
    float8 vmed = 0.0f;
    int8 mid = n / 2;
    if (any_nan) {  // by the ranks (min and max would drop a NaN; the host says where the image has one)
        for (int a = 0; a < 9; a++) {
            int8 rank = 0;
            for (int b = 0; b < 9; b++)
                rank -= v[b] < v[a] || (b < a ? (v[b] == v[a]) : (int8)(0));
            vmed = select(vmed, v[a], rank == mid);
        }
    } else {
        // the 5 smallest in order, by a selection network (Batcher's odd-even
        // merge sort of 16, pruned to 9 inputs and to the outputs 0-4: 23
        // compare-exchanges, checked on all 2^9 inputs of 0s and 1s)
#define CE(i, j) { float8 lo = fmin(v[i], v[j]); v[j] = fmax(v[i], v[j]); v[i] = lo; }
        CE(0, 1) CE(2, 3) CE(0, 2) CE(1, 3) CE(1, 2) CE(4, 5) CE(6, 7) CE(4, 6) CE(5, 7) CE(5, 6) CE(0, 4) CE(2, 6)
        CE(2, 4) CE(1, 5) CE(3, 7) CE(3, 5) CE(1, 2) CE(3, 4) CE(0, 8) CE(4, 8) CE(2, 4) CE(1, 2) CE(3, 4)
#undef CE
        vmed = v[0];
        for (int a = 1; a < 5; a++)
            vmed = select(vmed, v[a], mid == a);
    }
    float8 r = LD8(color_in, 0, o), g = LD8(color_in, 1, o), b = LD8(color_in, 2, o), var = LD8(color_in, 3, o);
    float8 bound = lmax + k * sqrt(vmed);
    float8 lp = luma8(r, g, b);
    // Brightness the pixel's own samples confirm is kept: it is clamped only
    // where its excess over the bound is within k_confirm of its own standard errors
    // (a firefly's standard error is about its value; a highlight's, a lamp's
    // reflection's, a caustic's, seen by most of the pixel's samples, is not).
    int8 clip = n > 1 && lp > bound && lp - k_confirm * sqrt(var) <= bound;
    float8 s = fmax(bound, 0.0f) / lp;
    r = select(r, r * s, clip); g = select(g, g * s, clip); b = select(b, b * s, clip);
    var = select(var, vmed, clip);
    vstore8(select((float8)(0.0f), r, inside), 0, color_out + o);
    vstore8(select((float8)(0.0f), g, inside), 0, color_out + plane + o);
    vstore8(select((float8)(0.0f), b, inside), 0, color_out + 2 * plane + o);
    vstore8(select((float8)(0.0f), var, inside), 0, color_out + 3 * plane + o);
}

// filter_luma: planes 4 and 5 of color, the luminance of planes 0-2 and the
// variance (plane 3) averaged over the pixel's 3x3 in the image with weights
// (1 2 1) x (1 2 1).
__kernel void filter_luma(__global float *color, uint width, uint height, uint pitch, uint plane, uint margin)
{
    uint gid = get_global_id(0);
    uint per_row = pitch / 8u;
    if (gid >= per_row * height)
        return;
    int y = (int)(gid / per_row), x0 = (int)(gid % per_row) * 8;
    int8 xs = (int8)(x0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    float8 s = 0.0f, sv = 0.0f, ws = 0.0f;
    for (int dy = -1; dy <= 1; dy++) {
        int qy = y + dy;
        if (qy < 0 || qy >= (int)height)
            continue;
        int off = (int)margin + qy * (int)pitch + x0;
        for (int dx = -1; dx <= 1; dx++) {
            int8 qx = xs + dx;
            int8 in = qx >= 0 && qx < (int)width;
            float w = (float)((2 - abs(dx)) * (2 - abs(dy)));
            float8 l = luma8(LD8(color, 0, off + dx), LD8(color, 1, off + dx), LD8(color, 2, off + dx));
            s = select(s, s + w * l, in);
            sv = select(sv, sv + w * LD8(color, 3, off + dx), in);
            ws = select(ws, ws + w, in);
        }
    }
    int o = (int)margin + y * (int)pitch + x0;
    int8 inside = xs < (int)width;
    vstore8(select((float8)(0.0f), s / ws, inside), 0, color + 4 * plane + o);
    vstore8(select((float8)(0.0f), sv / ws, inside), 0, color + 5 * plane + o);
}


// One work-item's 8 pixels; `fit` is a constant in each inlined copy (the
// averaging passes keep fewer values live), and so is `r1`, set where the
// radius is 1 (the default): the taps' loops then have constant trip counts
// and unroll (a loop of run-time length in a kernel body ran several times
// slower than the same work unrolled). The same operations in the same
// order either way: the same bits.
inline void cone8(__global const float *color_in, __global const float *guides, uint width, uint height,
                  uint pitch, uint plane, uint margin, int radius, int step, int n_pow, float sigma_depth,
                  float sigma_albedo, float sigma_lum, float guide_floor, const int fit, const int r1,
                  __global float *color_out)
{
    if (r1)
        radius = 1;
    uint gid = get_global_id(0);
    uint per_row = pitch / 8u;
    if (gid >= per_row * height)
        return;
    int y = (int)(gid / per_row), x0 = (int)(gid % per_row) * 8;
    int ym = (int)height - 1;
    int row0 = (int)margin + y * (int)pitch + x0;
    int8 xs = (int8)(x0) + (int8)(0, 1, 2, 3, 4, 5, 6, 7);
    float8 cr = LD8(color_in, 0, row0), cg = LD8(color_in, 1, row0), cb = LD8(color_in, 2, row0);
    float8 cv = LD8(color_in, 3, row0);
    float8 nx = LD8(guides, 0, row0), ny = LD8(guides, 1, row0), nz = LD8(guides, 2, row0);
    float8 fl = LD8(guides, 3, row0);
    float8 ar = LD8(guides, 4, row0), ag = LD8(guides, 5, row0), ab = LD8(guides, 6, row0);
    float8 dz = LD8(guides, 7, row0);
    int8 has_n = (nx * nx + ny * ny + nz * nz) > 0.0f;
    float8 lp = LD8(color_in, 4, row0);
    // p's noise: its variance smoothed over the 3x3 (filter_luma)
    float8 inv_sl = 1.0f / (sigma_lum * sqrt(LD8(color_in, 5, row0)) + 1e-6f);
    float inv_sa = 1.0f / (sigma_albedo * sigma_albedo);
    float8 inv_sd = 1.0f / (sigma_depth * fmax(dz, 1e-6f) * (float)step);
    float8 accr = 0.0f, accg = 0.0f, accb = 0.0f;
    float8 wsum = 1.0f, w2v = cv;  // the centre tap
    // fit: the sums of w x, w y, w x^2, w y^2, w x y and of w x d, w y d per channel
    float8 sx = 0.0f, sy = 0.0f, sxx = 0.0f, syy = 0.0f, sxy = 0.0f;
    float8 fxr = 0.0f, fxg = 0.0f, fxb = 0.0f, fyr = 0.0f, fyg = 0.0f, fyb = 0.0f;
    for (int dy = -radius; dy <= radius; dy++) {
        int qy = y + dy * step;
        if (qy < 0 || qy > ym)
            continue;
        for (int dx = -radius; dx <= radius; dx++) {
            if (dx == 0 && dy == 0)
                continue;
            float r = sqrt((float)(dx * dx + dy * dy));
            float ws = 1.0f - r / (float)(radius + 1);
            if (ws <= 0.0f)
                continue;
            int off = (int)margin + qy * (int)pitch + x0 + dx * step;
            int8 qx = xs + dx * step;
            float8 mx = LD8(guides, 0, off), my = LD8(guides, 1, off), mz = LD8(guides, 2, off);
            float8 fq = LD8(guides, 3, off);
            int8 use = qx >= 0 && qx < (int)width && has_n == ((mx * mx + my * my + mz * mz) > 0.0f) && fl == fq;
            float8 cn = fmax(nx * mx + ny * my + nz * mz, 0.0f), g = 1.0f;
            // cn^n_pow by squaring (1 <= n_pow < 128: seven bits; past the highest set
            // bit the squares go unused)
#pragma unroll
            for (int k = 0; k < 7; k++) {
                if ((n_pow >> k) & 1)
                    g *= cn;
                cn *= cn;
            }
            g = select((float8)(1.0f), g, has_n);
            float8 dar = ar - LD8(guides, 4, off), dag = ag - LD8(guides, 5, off), dab = ab - LD8(guides, 6, off);
            float8 dd = fabs(dz - LD8(guides, 7, off));
            g *= exp(-((dar * dar + dag * dag + dab * dab) * inv_sa + dd * inv_sd / r));
            float8 qr = LD8(color_in, 0, off), qg = LD8(color_in, 1, off), qb = LD8(color_in, 2, off);
            float8 qv = LD8(color_in, 3, off);
            float8 lq = LD8(color_in, 4, off);
            float8 w = ws * (g + guide_floor) * exp(-fabs(lp - lq) * inv_sl);
            w = select((float8)(0.0f), w, use && w > 0.0f);
            float8 dr = qr - cr, dg = qg - cg, db = qb - cb;
            accr += w * dr; accg += w * dg; accb += w * db;
            wsum += w;
            w2v += w * w * qv;
            if (fit) {
                float xt = (float)dx / (float)radius, yt = (float)dy / (float)radius;
                float8 wx = w * xt, wy = w * yt;
                sx += wx; sy += wy; sxx += wx * xt; syy += wy * yt; sxy += wx * yt;
                fxr += wx * dr; fxg += wx * dg; fxb += wx * db;
                fyr += wy * dr; fyg += wy * dg; fyb += wy * db;
            }
        }
    }
    if (fit) {
        // a: the first row of the normal matrix's cofactors against the sums, over its determinant
        float8 lam = 1e-3f * wsum;
        float8 axx = sxx + lam, ayy = syy + lam;
        float8 m0 = axx * ayy - sxy * sxy, m1 = sxy * sy - sx * ayy, m2 = sx * sxy - axx * sy;
        float8 inv = 1.0f / (wsum * m0 + sx * m1 + sy * m2);
        vstore8(cr + (m0 * accr + m1 * fxr + m2 * fyr) * inv, 0, color_out + row0);
        vstore8(cg + (m0 * accg + m1 * fxg + m2 * fyg) * inv, 0, color_out + plane + row0);
        vstore8(cb + (m0 * accb + m1 * fxb + m2 * fyb) * inv, 0, color_out + 2 * plane + row0);
    } else {
        vstore8(cr + accr / wsum, 0, color_out + row0);
        vstore8(cg + accg / wsum, 0, color_out + plane + row0);
        vstore8(cb + accb / wsum, 0, color_out + 2 * plane + row0);
    }
    vstore8(w2v / (wsum * wsum), 0, color_out + 3 * plane + row0);
}

__kernel void filter_cone(__global const float *color_in, __global const float *guides, uint width, uint height,
                          uint pitch, uint plane, uint margin, int radius, int step, int n_pow, float sigma_depth,
                          float sigma_albedo, float sigma_lum, float guide_floor, int fit,
                          __global float *color_out)
{
#define CONE8(FIT, R1) cone8(color_in, guides, width, height, pitch, plane, margin, radius, step, n_pow, \
                             sigma_depth, sigma_albedo, sigma_lum, guide_floor, FIT, R1, color_out)
    if (radius == 1) {
        if (fit)
            CONE8(1, 1);
        else
            CONE8(0, 1);
    } else if (fit) {
        CONE8(1, 0);
    } else {
        CONE8(0, 0);
    }
#undef CONE8
}
