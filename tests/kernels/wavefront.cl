// wavefront.cl: the intersection stage of a wavefront path tracer, for
// tests/bench_wavefront.py. Rays come from buffers (structure of arrays) and
// hits go back to buffers, one ray a lane, CLPT_LANES rays a work-item; the
// queries are trace_paths' own (scene.h scene_intersect, scene_occluded), so
// the bench compares the same traversal inside and outside the megakernel.

#if CLPT_LANES == 1
#define WF_LD(p, i) ((p)[i])
#define WF_ST(v, p, i) ((p)[i] = (v))
#else
#define WF_LD(p, i) CLPT_CAT(vload, CLPT_LANES)(i, p)
#define WF_ST(v, p, i) CLPT_CAT(vstore, CLPT_LANES)(v, i, p)
#endif
#define WF_LD3(px, py, pz, i) v3(WF_LD(px, i), WF_LD(py, i), WF_LD(pz, i))

// Closest hits: t (+inf: escaped), the geometric normal, the light + 1 of an emitter hit (0: none).
__kernel void wf_closest(__global const real4 *rec, __constant SceneInfo *info,
                         __global const real *ox, __global const real *oy, __global const real *oz,
                         __global const real *dx, __global const real *dy, __global const real *dz,
                         __global real *t, __global real *nx, __global real *ny, __global real *nz,
                         __global real *light)
{
    size_t i = get_global_id(0);
    Scene s = scene_make(rec, *info);
    Hit h = scene_intersect(&s, WF_LD3(ox, oy, oz, i), WF_LD3(dx, dy, dz, i));
    WF_ST(h.t, t, i);
    WF_ST(h.ng.x, nx, i); WF_ST(h.ng.y, ny, i); WF_ST(h.ng.z, nz, i);
    WF_ST(h.light, light, i);
}

// Shadow rays: 1 where the segment o + s d, 0 < s < tmax, is blocked.
__kernel void wf_occluded(__global const real4 *rec, __constant SceneInfo *info,
                          __global const real *ox, __global const real *oy, __global const real *oz,
                          __global const real *dx, __global const real *dy, __global const real *dz,
                          __global const real *tmax, __global real *occluded)
{
    size_t i = get_global_id(0);
    Scene s = scene_make(rec, *info);
    vmask all = WF_LD(tmax, i) == WF_LD(tmax, i) || WF_LD(tmax, i) != WF_LD(tmax, i);
    vmask occ = scene_occluded(&s, WF_LD3(ox, oy, oz, i), WF_LD3(dx, dy, dz, i), WF_LD(tmax, i), all);
    WF_ST(VSEL((vreal)R(0), (vreal)R(1), occ), occluded, i);
}

// A point on the lights for each origin p (light.h's sampler: u0 picks the light, u1, u2 the point):
// the direction, the distance, whether the sample is valid.
__kernel void wf_light(__global const real4 *rec, __constant SceneInfo *info,
                       __global const real *px, __global const real *py, __global const real *pz,
                       __global const real *u0, __global const real *u1, __global const real *u2,
                       __global real *wx, __global real *wy, __global real *wz, __global real *dist,
                       __global real *valid)
{
    size_t i = get_global_id(0);
    Scene s = scene_make(rec, *info);
    LightU u;
    u.pick = WF_LD(u0, i); u.u1 = WF_LD(u1, i); u.u2 = WF_LD(u2, i);
    LightSample ls;
    light_sample(&s, WF_LD3(px, py, pz, i), u, 1, u.pick == u.pick, &ls);
    WF_ST(ls.wi.x, wx, i); WF_ST(ls.wi.y, wy, i); WF_ST(ls.wi.z, wz, i);
    WF_ST(ls.dist, dist, i);
    WF_ST(VSEL((vreal)R(0), (vreal)R(1), ls.valid), valid, i);
}
