// lane_io.cl: what tests/kernels/probes.cl (the tests' probes) and
// tests/kernels/wavefront.cl (tests/bench_wavefront.py) share: one
// work-item handles CLPT_LANES consecutive elements of each array (structure
// of arrays), and the light sampler's query.

#if CLPT_LANES == 1
#define LD(p, i) ((p)[i])
#define ST(v, p, i) ((p)[i] = (v))
#define LDU(p, i) ((p)[i])
#else
#define LD(p, i) CLPT_CAT(vload, CLPT_LANES)(i, p)
#define ST(v, p, i) CLPT_CAT(vstore, CLPT_LANES)(v, i, p)
#define LDU(p, i) CLPT_CAT(vload, CLPT_LANES)(i, p)
#endif
#define ST3(v, px, py, pz, i) do { ST((v).x, px, i); ST((v).y, py, i); ST((v).z, pz, i); } while (0)
#define LD3(px, py, pz, i) v3(LD(px, i), LD(py, i), LD(pz, i))

// A point on the lights for each origin p (lights.h light_sample: u0 picks the light, u1, u2 the
// point): the direction, the distance, the radiance's first channel, the pdf, whether it is valid.
__kernel void probe_light_sample(__global const real4 *rec, __constant SceneInfo *info,
                                 __global const real *px, __global const real *py, __global const real *pz,
                                 __global const real *u0, __global const real *u1, __global const real *u2,
                                 __global real *wx, __global real *wy, __global real *wz, __global real *dist,
                                 __global real *le, __global real *pdf, __global real *valid)
{
    size_t i = get_global_id(0);
    Scene s = scene_make(rec, *info);
    LightU u;
    u.pick = LD(u0, i); u.u1 = LD(u1, i); u.u2 = LD(u2, i);
    LightSample ls;
    light_sample(&s, LD3(px, py, pz, i), u, 1, u.pick == u.pick, &ls);
    ST3(ls.wi, wx, wy, wz, i);
    ST(ls.dist, dist, i);
    ST(ls.Le.x, le, i);
    ST(ls.pdf, pdf, i);
    ST(VSEL((vreal)R(0), (vreal)R(1), ls.valid), valid, i);
}
