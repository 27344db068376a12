// filter.cl: the edge-aware cone filter, as five kernels.
//
// filter_load lays the host's images out as planes (below) and demodulates
// the colour (divides it by the first-hit albedo, so texture and colour edges
// are not blurred); filter_store multiplies the albedo back into the host's
// layout. The passes between work on the demodulated image, without the parts
// the host keeps out of it: emission seen directly and the photon map's
// caustics, which are added back sharp.
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
// Layout: planar images of `pitch` (the width rounded up to 16) columns, each
// plane `plane` floats long with `margin` floats before and after the pixels
// (zeros, so that lanes outside the image read finite values):
//   color: r, g, b, variance of the pixel mean, smoothed luminance and variance (filter_luma)
//   guides: normal x, y, z (0 if none), emitter flag (0/1), albedo r, g, b, depth
// The passes' three kernels (filter_firefly, filter_luma, filter_cone): one
// work-item per CLPT_FILTER_PIXELS (P: 8 or 16) pixels of a row, in vectors
// of P lanes (global size height * pitch / P); any local size. The host sets
// P by the device (clpt/program.py filter_pixels): 16 on CPUs, where Intel's
// and PoCL's compilers run one work-item's float16 faster than two
// work-items' float8 (the cone pass 1.3-1.8x), 8 elsewhere (GPUs: a float16
// per work-item would spill registers). The same operations either way: the
// same bits. The lanes past the width (the rows' padding) are zeros as
// filter_load, filter_firefly and filter_luma write them, and what the pass
// computes there in filter_cone; the taps that read them have weight 0. The
// margins are never written.

#ifndef CLPT_FILTER_PIXELS
#define CLPT_FILTER_PIXELS 8
#endif
#if CLPT_FILTER_PIXELS == 16
typedef float16 floatP;
typedef int16 intP;
#define LOADP vload16
#define STOREP vstore16
#define PIXEL_IDS ((int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#elif CLPT_FILTER_PIXELS == 8
typedef float8 floatP;
typedef int8 intP;
#define LOADP vload8
#define STOREP vstore8
#define PIXEL_IDS ((intP)(0, 1, 2, 3, 4, 5, 6, 7))
#else
#error "CLPT_FILTER_PIXELS: 8 or 16"
#endif

inline floatP lumaP(floatP r, floatP g, floatP b)
{
    return (float)CLPT_LUMA_R * r + (float)CLPT_LUMA_G * g + (float)CLPT_LUMA_B * b;
}

#define LDP(buf, k, off) LOADP(0, (buf) + (k) * plane + (off))

// filter_load: one work-item per pixel of the planes (pitch x height). The
// host's images are H x W, RGB interleaved: colour, the variance of each
// pixel mean's luminance, normal, albedo, depth and the share of samples that
// see an emitter (NULL: none do). Colour is divided by the albedo where it is
// above `floor` (1 elsewhere), the variance by the square of that albedo's
// luminance (at least `floor`); the guides take the albedo as it is, and the
// emitter flag where most samples see one.
__kernel void filter_load(__global const float *color, __global const float *var, __global const float *normal,
                          __global const float *albedo, __global const float *depth, __global const float *emitter,
                          uint width, uint height, uint pitch, uint plane, uint margin, float floor,
                          __global float *color_out, __global float *guides)
{
#pragma OPENCL FP_CONTRACT OFF
    // (no fused multiply-adds: the albedo's luminance as the host's dot product
    // gives it, so that the image is the same bits as when the host demodulated)
    uint x = get_global_id(0), y = get_global_id(1);
    if (x >= pitch || y >= height)
        return;
    uint o = margin + y * pitch + x;
    if (x >= width) {  // the row's padding
        for (int k = 0; k < 4; k++)
            color_out[k * plane + o] = 0.0f;
        for (int k = 0; k < 8; k++)
            guides[k * plane + o] = 0.0f;
        return;
    }
    uint i = y * width + x;
    float3 a = vload3(i, albedo);
    float3 alb = select((float3)(1.0f), a, a > floor);
    float la = fmax((float)CLPT_LUMA_R * alb.x + (float)CLPT_LUMA_G * alb.y + (float)CLPT_LUMA_B * alb.z, floor);
    float3 c = vload3(i, color) / alb;
    float3 n = vload3(i, normal);
    color_out[o] = c.x;
    color_out[plane + o] = c.y;
    color_out[2 * plane + o] = c.z;
    color_out[3 * plane + o] = var[i] / (la * la);
    guides[o] = n.x;
    guides[plane + o] = n.y;
    guides[2 * plane + o] = n.z;
    guides[3 * plane + o] = emitter && emitter[i] > 0.5f ? 1.0f : 0.0f;
    guides[4 * plane + o] = a.x;
    guides[5 * plane + o] = a.y;
    guides[6 * plane + o] = a.z;
    guides[7 * plane + o] = depth[i];
}

// filter_store: one work-item per pixel of the image (width x height): the
// colour planes times the albedo (as filter_load divided it), RGB interleaved.
__kernel void filter_store(__global const float *color_in, __global const float *guides, uint width, uint height,
                           uint pitch, uint plane, uint margin, float floor, __global float *out)
{
    uint x = get_global_id(0), y = get_global_id(1);
    if (x >= width || y >= height)
        return;
    uint o = margin + y * pitch + x, gid = y * width + x;
    float3 a = (float3)(guides[4 * plane + o], guides[5 * plane + o], guides[6 * plane + o]);
    float3 alb = select((float3)(1.0f), a, a > floor);
    vstore3((float3)(color_in[o], color_in[plane + o], color_in[2 * plane + o]) * alb, gid, out);
}

__kernel void filter_firefly(__global const float *color_in, uint width, uint height, uint pitch, uint plane,
                             uint margin, float k, float k_confirm, int any_nan, __global float *color_out)
{
    uint gid = get_global_id(0);
    uint per_row = pitch / (uint)CLPT_FILTER_PIXELS;
    if (gid >= per_row * height)
        return;
    int y = (int)(gid / per_row), x0 = (int)(gid % per_row) * CLPT_FILTER_PIXELS;
    int ym = (int)height - 1;
    intP xs = (intP)(x0) + PIXEL_IDS;
    intP inside = xs < (int)width;
    int o = (int)margin + y * (int)pitch + x0;
    // Pixels outside the image count as +inf variance, n as 0 luminance (rows
    // outside read a clamped row's address, columns the padding or the margin).
    floatP v[9];
    intP n = 0;
    floatP lmax = -INFINITY;
    for (int dy = -1; dy <= 1; dy++) {
        int qy = y + dy;
        int row_in = qy >= 0 && qy <= ym;
        int off = (int)margin + clamp(qy, 0, ym) * (int)pitch + x0;
        for (int dx = -1; dx <= 1; dx++) {
            intP qx = xs + dx;
            intP in = qx >= 0 && qx < (int)width && (intP)(row_in ? -1 : 0);
            v[(dy + 1) * 3 + dx + 1] = select((floatP)(INFINITY), LDP(color_in, 3, off + dx), in);
            n -= in;  // in: -1 where true
            if (dx != 0 || dy != 0)
                lmax = select(lmax, fmax(lmax, lumaP(LDP(color_in, 0, off + dx), LDP(color_in, 1, off + dx),
                                                     LDP(color_in, 2, off + dx))), in);
        }
    }
    // The median of the n variances in the image: the one of rank n / 2 (ties
    // ranked by position; n / 2 <= 4 and the outside's +inf rank last).
    floatP vmed = 0.0f;
    intP mid = n / 2;
    if (any_nan) {  // by the ranks (min and max would drop a NaN; the host says where the image has one)
        for (int a = 0; a < 9; a++) {
            intP rank = 0;
            for (int b = 0; b < 9; b++)
                rank -= v[b] < v[a] || (b < a ? (v[b] == v[a]) : (intP)(0));
            vmed = select(vmed, v[a], rank == mid);
        }
    } else {
        // the 5 smallest in order, by a selection network (Batcher's odd-even
        // merge sort of 16, pruned to 9 inputs and to the outputs 0-4: 23
        // compare-exchanges, checked on all 2^9 inputs of 0s and 1s)
#define CE(i, j) { floatP lo = fmin(v[i], v[j]); v[j] = fmax(v[i], v[j]); v[i] = lo; }
        CE(0, 1) CE(2, 3) CE(0, 2) CE(1, 3) CE(1, 2) CE(4, 5) CE(6, 7) CE(4, 6) CE(5, 7) CE(5, 6) CE(0, 4) CE(2, 6)
        CE(2, 4) CE(1, 5) CE(3, 7) CE(3, 5) CE(1, 2) CE(3, 4) CE(0, 8) CE(4, 8) CE(2, 4) CE(1, 2) CE(3, 4)
#undef CE
        vmed = v[0];
        for (int a = 1; a < 5; a++)
            vmed = select(vmed, v[a], mid == a);
    }
    floatP r = LDP(color_in, 0, o), g = LDP(color_in, 1, o), b = LDP(color_in, 2, o), var = LDP(color_in, 3, o);
    floatP bound = lmax + k * sqrt(vmed);
    floatP lp = lumaP(r, g, b);
    // Brightness the pixel's own samples confirm is kept: it is clamped only
    // where its excess over the bound is within k_confirm of its own standard errors
    // (a firefly's standard error is about its value; a highlight's, a lamp's
    // reflection's, a caustic's, seen by most of the pixel's samples, is not).
    intP clip = n > 1 && lp > bound && lp - k_confirm * sqrt(var) <= bound;
    floatP s = fmax(bound, 0.0f) / lp;
    r = select(r, r * s, clip); g = select(g, g * s, clip); b = select(b, b * s, clip);
    var = select(var, vmed, clip);
    STOREP(select((floatP)(0.0f), r, inside), 0, color_out + o);
    STOREP(select((floatP)(0.0f), g, inside), 0, color_out + plane + o);
    STOREP(select((floatP)(0.0f), b, inside), 0, color_out + 2 * plane + o);
    STOREP(select((floatP)(0.0f), var, inside), 0, color_out + 3 * plane + o);
}

// filter_luma: planes 4 and 5 of color, the luminance of planes 0-2 and the
// variance (plane 3) averaged over the pixel's 3x3 in the image with weights
// (1 2 1) x (1 2 1).
__kernel void filter_luma(__global float *color, uint width, uint height, uint pitch, uint plane, uint margin)
{
    uint gid = get_global_id(0);
    uint per_row = pitch / (uint)CLPT_FILTER_PIXELS;
    if (gid >= per_row * height)
        return;
    int y = (int)(gid / per_row), x0 = (int)(gid % per_row) * CLPT_FILTER_PIXELS;
    intP xs = (intP)(x0) + PIXEL_IDS;
    floatP s = 0.0f, sv = 0.0f, ws = 0.0f;
    for (int dy = -1; dy <= 1; dy++) {
        int qy = y + dy;
        if (qy < 0 || qy >= (int)height)
            continue;
        int off = (int)margin + qy * (int)pitch + x0;
        for (int dx = -1; dx <= 1; dx++) {
            intP qx = xs + dx;
            intP in = qx >= 0 && qx < (int)width;
            float w = (float)((2 - abs(dx)) * (2 - abs(dy)));
            floatP l = lumaP(LDP(color, 0, off + dx), LDP(color, 1, off + dx), LDP(color, 2, off + dx));
            s = select(s, s + w * l, in);
            sv = select(sv, sv + w * LDP(color, 3, off + dx), in);
            ws = select(ws, ws + w, in);
        }
    }
    int o = (int)margin + y * (int)pitch + x0;
    intP inside = xs < (int)width;
    STOREP(select((floatP)(0.0f), s / ws, inside), 0, color + 4 * plane + o);
    STOREP(select((floatP)(0.0f), sv / ws, inside), 0, color + 5 * plane + o);
}


// One work-item's P pixels; `fit` is a constant in each inlined copy (the
// averaging passes keep fewer values live), and so is `r1`, set where the
// radius is 1 (the default): the taps' loops then have constant trip counts
// and unroll (a loop of run-time length in a kernel body ran several times
// slower than the same work unrolled). The same operations in the same
// order either way: the same bits.
inline void coneP(__global const float *color_in, __global const float *guides, uint width, uint height,
                  uint pitch, uint plane, uint margin, int radius, int step, int n_pow, float sigma_depth,
                  float sigma_albedo, float sigma_lum, float guide_floor, const int fit, const int r1,
                  __global float *color_out)
{
    if (r1)
        radius = 1;
    uint gid = get_global_id(0);
    uint per_row = pitch / (uint)CLPT_FILTER_PIXELS;
    if (gid >= per_row * height)
        return;
    int y = (int)(gid / per_row), x0 = (int)(gid % per_row) * CLPT_FILTER_PIXELS;
    int ym = (int)height - 1;
    int row0 = (int)margin + y * (int)pitch + x0;
    intP xs = (intP)(x0) + PIXEL_IDS;
    floatP cr = LDP(color_in, 0, row0), cg = LDP(color_in, 1, row0), cb = LDP(color_in, 2, row0);
    floatP cv = LDP(color_in, 3, row0);
    floatP nx = LDP(guides, 0, row0), ny = LDP(guides, 1, row0), nz = LDP(guides, 2, row0);
    floatP fl = LDP(guides, 3, row0);
    floatP ar = LDP(guides, 4, row0), ag = LDP(guides, 5, row0), ab = LDP(guides, 6, row0);
    floatP dz = LDP(guides, 7, row0);
    intP has_n = (nx * nx + ny * ny + nz * nz) > 0.0f;
    floatP lp = LDP(color_in, 4, row0);
    // p's noise: its variance smoothed over the 3x3 (filter_luma)
    floatP inv_sl = 1.0f / (sigma_lum * sqrt(LDP(color_in, 5, row0)) + 1e-6f);
    float inv_sa = 1.0f / (sigma_albedo * sigma_albedo);
    floatP inv_sd = 1.0f / (sigma_depth * fmax(dz, 1e-6f) * (float)step);
    floatP accr = 0.0f, accg = 0.0f, accb = 0.0f;
    floatP wsum = 1.0f, w2v = cv;  // the centre tap
    // fit: the sums of w x, w y, w x^2, w y^2, w x y and of w x d, w y d per channel
    floatP sx = 0.0f, sy = 0.0f, sxx = 0.0f, syy = 0.0f, sxy = 0.0f;
    floatP fxr = 0.0f, fxg = 0.0f, fxb = 0.0f, fyr = 0.0f, fyg = 0.0f, fyb = 0.0f;
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
            intP qx = xs + dx * step;
            floatP mx = LDP(guides, 0, off), my = LDP(guides, 1, off), mz = LDP(guides, 2, off);
            floatP fq = LDP(guides, 3, off);
            intP use = qx >= 0 && qx < (int)width && has_n == ((mx * mx + my * my + mz * mz) > 0.0f) && fl == fq;
            floatP cn = fmax(nx * mx + ny * my + nz * mz, 0.0f), g = 1.0f;
            // cn^n_pow by squaring (1 <= n_pow < 128: seven bits; past the highest set
            // bit the squares go unused)
#pragma unroll
            for (int k = 0; k < 7; k++) {
                if ((n_pow >> k) & 1)
                    g *= cn;
                cn *= cn;
            }
            g = select((floatP)(1.0f), g, has_n);
            floatP dar = ar - LDP(guides, 4, off), dag = ag - LDP(guides, 5, off), dab = ab - LDP(guides, 6, off);
            floatP dd = fabs(dz - LDP(guides, 7, off));
            g *= exp(-((dar * dar + dag * dag + dab * dab) * inv_sa + dd * inv_sd / r));
            floatP qr = LDP(color_in, 0, off), qg = LDP(color_in, 1, off), qb = LDP(color_in, 2, off);
            floatP qv = LDP(color_in, 3, off);
            floatP lq = LDP(color_in, 4, off);
            floatP w = ws * (g + guide_floor) * exp(-fabs(lp - lq) * inv_sl);
            w = select((floatP)(0.0f), w, use && w > 0.0f);
            floatP dr = qr - cr, dg = qg - cg, db = qb - cb;
            accr += w * dr; accg += w * dg; accb += w * db;
            wsum += w;
            w2v += w * w * qv;
            if (fit) {
                float xt = (float)dx / (float)radius, yt = (float)dy / (float)radius;
                floatP wx = w * xt, wy = w * yt;
                sx += wx; sy += wy; sxx += wx * xt; syy += wy * yt; sxy += wx * yt;
                fxr += wx * dr; fxg += wx * dg; fxb += wx * db;
                fyr += wy * dr; fyg += wy * dg; fyb += wy * db;
            }
        }
    }
    if (fit) {
        // a: the first row of the normal matrix's cofactors against the sums, over its determinant
        floatP lam = 1e-3f * wsum;
        floatP axx = sxx + lam, ayy = syy + lam;
        floatP m0 = axx * ayy - sxy * sxy, m1 = sxy * sy - sx * ayy, m2 = sx * sxy - axx * sy;
        floatP inv = 1.0f / (wsum * m0 + sx * m1 + sy * m2);
        STOREP(cr + (m0 * accr + m1 * fxr + m2 * fyr) * inv, 0, color_out + row0);
        STOREP(cg + (m0 * accg + m1 * fxg + m2 * fyg) * inv, 0, color_out + plane + row0);
        STOREP(cb + (m0 * accb + m1 * fxb + m2 * fyb) * inv, 0, color_out + 2 * plane + row0);
    } else {
        STOREP(cr + accr / wsum, 0, color_out + row0);
        STOREP(cg + accg / wsum, 0, color_out + plane + row0);
        STOREP(cb + accb / wsum, 0, color_out + 2 * plane + row0);
    }
    STOREP(w2v / (wsum * wsum), 0, color_out + 3 * plane + row0);
}

__kernel void filter_cone(__global const float *color_in, __global const float *guides, uint width, uint height,
                          uint pitch, uint plane, uint margin, int radius, int step, int n_pow, float sigma_depth,
                          float sigma_albedo, float sigma_lum, float guide_floor, int fit,
                          __global float *color_out)
{
#define CONEP(FIT, R1) coneP(color_in, guides, width, height, pitch, plane, margin, radius, step, n_pow, \
                             sigma_depth, sigma_albedo, sigma_lum, guide_floor, FIT, R1, color_out)
    if (radius == 1) {
        if (fit)
            CONEP(1, 1);
        else
            CONEP(0, 1);
    } else if (fit) {
        CONEP(1, 0);
    } else {
        CONEP(0, 0);
    }
#undef CONEP
}
