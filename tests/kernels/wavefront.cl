// wavefront.cl: the intersection stage of a wavefront path tracer, for
// tests/bench_wavefront.py. Rays come from buffers (structure of arrays) and
// hits go back to buffers, one ray a lane, CLPT_LANES rays a work-item; the
// queries are trace_paths' own (scene.h scene_intersect, scene_occluded), so
// the bench compares the same traversal inside and outside the megakernel.

// (LD, ST, LD3: tests/kernels/lane_io.cl, stitched in before this file, with the light
// sampler's query probe_light_sample)

// Closest hits: t (+inf: escaped), the geometric normal, the light + 1 of an emitter hit (0: none).
__kernel void wf_closest(__global const real4 *rec, __constant SceneInfo *info,
                         __global const real *ox, __global const real *oy, __global const real *oz,
                         __global const real *dx, __global const real *dy, __global const real *dz,
                         __global real *t, __global real *nx, __global real *ny, __global real *nz,
                         __global real *light)
{
    size_t i = get_global_id(0);
    Scene s = scene_make(rec, *info);
    Hit h = scene_intersect(&s, LD3(ox, oy, oz, i), LD3(dx, dy, dz, i));
    ST(h.t, t, i);
    ST(h.ng.x, nx, i); ST(h.ng.y, ny, i); ST(h.ng.z, nz, i);
    ST(h.light, light, i);
}

// Shadow rays: 1 where the segment o + s d, 0 < s < tmax, is blocked.
__kernel void wf_occluded(__global const real4 *rec, __constant SceneInfo *info,
                          __global const real *ox, __global const real *oy, __global const real *oz,
                          __global const real *dx, __global const real *dy, __global const real *dz,
                          __global const real *tmax, __global real *occluded)
{
    size_t i = get_global_id(0);
    Scene s = scene_make(rec, *info);
    vmask all = LD(tmax, i) == LD(tmax, i) || LD(tmax, i) != LD(tmax, i);
    vmask occ = scene_occluded(&s, LD3(ox, oy, oz, i), LD3(dx, dy, dz, i), LD(tmax, i), all);
    ST(VSEL((vreal)R(0), (vreal)R(1), occ), occluded, i);
}
