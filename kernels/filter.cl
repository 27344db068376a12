// filter.cl: cone_filter, one pass of the edge-aware cone filter.
//
// Filters the demodulated image (colour divided by the first-hit albedo, so
// texture and colour edges are not blurred; the host multiplies the albedo
// back) with a cone-shaped kernel w_s = 1 - r / (radius + 1) over the taps
// (dx, dy) * step, |dx|, |dy| <= radius; step > 1 gives the a-trous passes
// of a wide filter. Each tap's weight is cut where the guides disagree:
//   normals   max(0, n_p . n_q)^sigma_normal (both missing: 1; one: 0)
//   depth     exp(-|z_p - z_q| / (sigma_depth * z_p * r * step))
//   albedo    exp(-|a_p - a_q|^2 / sigma_albedo^2)
//   value     exp(-|l_p - l_q| / (sigma_lum * sqrt(v_p + v_q) + 1e-6)), v the
//             variance of each pixel's mean: differences beyond the noise
//             (edges of shadows and caustics) are kept.
// out = c_p + sum w (c_q - c_p) / sum w: a constant region stays exactly
// constant, and radius 0 is exactly the identity. The variance of the output
// (sum w^2 v_q / (sum w)^2) feeds the next pass.
//
// Launch: one work-item per pixel, global size width * height (any local size).
// Buffers: color_in, var_in, normal (xyz, 0 if none), albedo_depth (rgb, depth)
// in; color_out, var_out out.

__kernel void cone_filter(__global const float4 *color_in, __global const float *var_in,
                          __global const float4 *normal, __global const float4 *albedo_depth, uint width,
                          uint height, int radius, int step, float sigma_normal, float sigma_depth,
                          float sigma_albedo, float sigma_lum, __global float4 *color_out, __global float *var_out)
{
    uint i = get_global_id(0);
    if (i >= width * height)
        return;
    int x = (int)(i % width), y = (int)(i / width);
    float4 cp = color_in[i];
    float vp = var_in[i];
    float3 np = normal[i].xyz;
    float4 ap = albedo_depth[i];
    int has_n = dot(np, np) > 0.0f;
    float lp = (float)CLPT_LUMA_R * cp.x + (float)CLPT_LUMA_G * cp.y + (float)CLPT_LUMA_B * cp.z;
    float3 acc = (float3)(0.0f);
    float wsum = 1.0f, w2v = vp;  // the centre tap
    for (int dy = -radius; dy <= radius; dy++) {
        for (int dx = -radius; dx <= radius; dx++) {
            if (dx == 0 && dy == 0)
                continue;
            int qx = x + dx * step, qy = y + dy * step;
            if (qx < 0 || qy < 0 || qx >= (int)width || qy >= (int)height)
                continue;
            float r = sqrt((float)(dx * dx + dy * dy));
            float w = 1.0f - r / (float)(radius + 1);
            if (w <= 0.0f)
                continue;
            uint j = (uint)qy * width + (uint)qx;
            float3 nq = normal[j].xyz;
            int has_q = dot(nq, nq) > 0.0f;
            if (has_n != has_q)
                continue;
            if (has_n)
                w *= pown(fmax(dot(np, nq), 0.0f), (int)sigma_normal);
            float4 aq = albedo_depth[j];
            float3 da = ap.xyz - aq.xyz;
            w *= exp(-dot(da, da) / (sigma_albedo * sigma_albedo));
            w *= exp(-fabs(ap.w - aq.w) / (sigma_depth * fmax(ap.w, 1e-6f) * r * (float)step + 1e-12f));
            float4 cq = color_in[j];
            float lq = (float)CLPT_LUMA_R * cq.x + (float)CLPT_LUMA_G * cq.y + (float)CLPT_LUMA_B * cq.z;
            float vq = var_in[j];
            w *= exp(-fabs(lp - lq) / (sigma_lum * sqrt(vp + vq) + 1e-6f));
            if (!(w > 0.0f))
                continue;
            acc += w * (cq.xyz - cp.xyz);
            wsum += w;
            w2v += w * w * vq;
        }
    }
    color_out[i] = (float4)(cp.xyz + acc / wsum, 0.0f);
    var_out[i] = w2v / (wsum * wsum);
}
