// simd.h: the lane abstraction every kernel is written in.
//
// One work-item traces CLPT_LANES independent paths at once, in explicit
// OpenCL vector types (float8 on an AVX2 CPU). PoCL does not vectorize a path
// tracer's loop body across work-items, but it compiles float8 arithmetic to
// AVX2 directly; CLPT_LANES = 1 gives plain scalar code for GPUs, where the
// hardware vectorizes across work-items.
//
// Conventions:
//   vreal  per-lane real (float, or double when CLPT_DOUBLE)
//   vmask  per-lane truth value from comparing vreals: combine masks with
//          && || ! only (they give -1/0 on vectors and 1/0 on scalars, and
//          VSEL/VANY accept both); never with & | ~.
//   vuint  per-lane 32-bit unsigned, used by the RNG and for indices.
// Per-lane integers that take part in masked updates (depth, primitive or
// material ids) are kept as vreal, so one select type serves all state.

#if CLPT_DOUBLE || CLPT_ACCUM_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#endif
#if CLPT_DOUBLE
typedef double real;
typedef double3 real3;
typedef double4 real4;
#define REAL3(v) convert_double3(v)
#define REAL_EPS 2.220446049250313e-16
#else
typedef float real;
typedef float3 real3;
typedef float4 real4;
#define REAL3(v) (v)
#define REAL_EPS 1.1920929e-07f
#endif
#define R(x) ((real)(x))

#define CLPT_CAT_(a, b) a##b
#define CLPT_CAT(a, b) CLPT_CAT_(a, b)

#if CLPT_LANES == 1
typedef real vreal;
typedef uint vuint;
typedef int vmask;
#if CLPT_ACCUM_DOUBLE
typedef double vdouble;
#endif
#define VSEL(a, b, m) ((m) ? (b) : (a))
#define VANY(m) ((m) != 0)
#define VALL(m) ((m) != 0)
#define VREAL(x) ((real)(x))
#define VUINT(x) ((uint)(x))
#define VINT(x) ((int)(x))
typedef int vint;
#define VDOUBLE(x) ((double)(x))
#define VMASK_D(m) (m)
#define VLANE_IDS ((uint)0)
typedef int mask_elem;
#define VLANE_R(v, l) (v)
#define VLANE_U(v, l) (v)
#define VLANE_M(v, l) (v)
#define VLANE_D(v, l) (v)
#else
#if CLPT_DOUBLE
typedef CLPT_CAT(double, CLPT_LANES) vreal;
typedef CLPT_CAT(long, CLPT_LANES) vmask;
typedef long mask_elem;
#define VREAL(x) CLPT_CAT(convert_double, CLPT_LANES)(x)
#define VMASK_D(m) (m)
#else
typedef CLPT_CAT(float, CLPT_LANES) vreal;
typedef CLPT_CAT(int, CLPT_LANES) vmask;
typedef int mask_elem;
#define VREAL(x) CLPT_CAT(convert_float, CLPT_LANES)(x)
#define VMASK_D(m) CLPT_CAT(convert_long, CLPT_LANES)(m)
#endif
typedef CLPT_CAT(uint, CLPT_LANES) vuint;
typedef CLPT_CAT(int, CLPT_LANES) vint;
#if CLPT_ACCUM_DOUBLE
typedef CLPT_CAT(double, CLPT_LANES) vdouble;
#endif
#define VSEL(a, b, m) select((a), (b), (m))
#define VANY(m) any(m)
#define VALL(m) all(m)
#define VUINT(x) CLPT_CAT(convert_uint, CLPT_LANES)(x)
#define VINT(x) CLPT_CAT(convert_int, CLPT_LANES)(x)
#define VDOUBLE(x) CLPT_CAT(convert_double, CLPT_LANES)(x)
// Lane l of a vector, through its private storage (l need not be constant).
#define VLANE_R(v, l) (((private real *)&(v))[l])
#define VLANE_U(v, l) (((private uint *)&(v))[l])
#define VLANE_M(v, l) (((private mask_elem *)&(v))[l])
#if CLPT_ACCUM_DOUBLE
#define VLANE_D(v, l) (((private double *)&(v))[l])
#endif
#if CLPT_LANES == 2
#define VLANE_IDS ((vuint)(0, 1))
#elif CLPT_LANES == 4
#define VLANE_IDS ((vuint)(0, 1, 2, 3))
#elif CLPT_LANES == 8
#define VLANE_IDS ((vuint)(0, 1, 2, 3, 4, 5, 6, 7))
#elif CLPT_LANES == 16
#define VLANE_IDS ((vuint)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15))
#else
#error "CLPT_LANES must be 1, 2, 4, 8 or 16"
#endif
#endif

// Number of lanes whose mask is set.
inline uint vpopcount(vmask m)
{
    uint n = 0;
    for (int l = 0; l < CLPT_LANES; l++)
        n += VLANE_M(m, l) != 0;
    return n;
}

// A function with a 3-component OpenCL vector (real3, int3, ...) as a
// parameter, behind a pointer parameter or as its result is declared
// INLINE_VEC3: always inlined, never called. Intel's CPU runtime
// (intel-opencl-rt 2026.2), which vectorizes a kernel across the work-items
// of a group, passes such a value to a function it leaves out of line with
// the wrong stride: in a group of 16, every work-item but the first gets
// components of its neighbours' values (a 2- or 4-component vector, or a
// struct such as V3, passes intact). `inline` alone is a hint Intel's
// compiler may decline in a large kernel: the generic build of a photon
// scene called bvh_walk1 out of line and walked shuffled rays.
#define INLINE_VEC3 inline __attribute__((always_inline))
// Always inlined for another reason: a function with a constant mode
// parameter that picks whole loops (scene_walk's and the BVH walk's closest
// or any hit, light_sample's shading point or emission, bsdf_sample's
// transport mode) becomes one plain function per mode only where it is
// inlined. Such a function returns no struct (it fills one through a
// pointer): inlining a struct-returning function leaves an
// llvm.experimental.noalias.scope.decl where the struct's storage stays in
// memory, which Oclgrind 21.10 cannot run. (The path events are plain
// `inline`, single call sites the compilers inline anyway.)
#define CLPT_INLINE inline __attribute__((always_inline))

// --- three-component vectors of lanes (structure of arrays) ----------------
typedef struct { vreal x, y, z; } V3;

inline V3 v3(vreal x, vreal y, vreal z) { V3 r; r.x = x; r.y = y; r.z = z; return r; }
inline V3 v3_splat(real4 a) { return v3((vreal)a.x, (vreal)a.y, (vreal)a.z); }
inline V3 v3_zero(void) { return v3((vreal)R(0), (vreal)R(0), (vreal)R(0)); }
inline V3 v3_add(V3 a, V3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
inline V3 v3_sub(V3 a, V3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
inline V3 v3_mul(V3 a, V3 b) { return v3(a.x * b.x, a.y * b.y, a.z * b.z); }
inline V3 v3_scale(V3 a, vreal s) { return v3(a.x * s, a.y * s, a.z * s); }
inline V3 v3_neg(V3 a) { return v3(-a.x, -a.y, -a.z); }
inline V3 v3_fma(V3 a, vreal s, V3 b) { return v3(mad(a.x, s, b.x), mad(a.y, s, b.y), mad(a.z, s, b.z)); }
inline vreal v3_dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline vreal v3_dot4(V3 a, real4 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline V3 v3_sub4(V3 a, real4 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
inline V3 v3_mul4(V3 a, real4 b) { return v3(a.x * b.x, a.y * b.y, a.z * b.z); }
inline V3 v3_cross(V3 a, V3 b)
{
    return v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
// 1 / sqrt rather than rsqrt: Intel's CPU runtime rounds rsqrt differently
// at different vector widths, which would break bit-identity across lanes.
inline vreal vrsqrt(vreal x) { return R(1) / sqrt(x); }
inline V3 v3_normalize(V3 a) { return v3_scale(a, vrsqrt(v3_dot(a, a))); }
inline V3 v3_sel(V3 a, V3 b, vmask m) { return v3(VSEL(a.x, b.x, m), VSEL(a.y, b.y, m), VSEL(a.z, b.z, m)); }
inline V3 v3_sel4(V3 a, real4 b, vmask m)
{
    return v3(VSEL(a.x, (vreal)b.x, m), VSEL(a.y, (vreal)b.y, m), VSEL(a.z, (vreal)b.z, m));
}
inline vreal v3_max_comp(V3 a) { return fmax(a.x, fmax(a.y, a.z)); }
inline vreal v3_luminance(V3 a) { return R(CLPT_LUMA_R) * a.x + R(CLPT_LUMA_G) * a.y + R(CLPT_LUMA_B) * a.z; }
// Reflect incoming direction d about normal n (both unit): d - 2 (d.n) n.
inline V3 v3_reflect(V3 d, V3 n) { return v3_fma(n, R(-2) * v3_dot(d, n), d); }

inline vreal vsafe_sqrt(vreal x) { return sqrt(fmax(x, R(0))); }

// The smallest lane of v, by halving the vector (no trip through memory).
#if CLPT_DOUBLE
#define SIMD_RN(n) CLPT_CAT(double, n)
#else
#define SIMD_RN(n) CLPT_CAT(float, n)
#endif
inline real vmin_lane(vreal v)
{
#if CLPT_LANES == 1
    return v;
#elif CLPT_LANES == 2
    return fmin(v.x, v.y);
#elif CLPT_LANES == 4
    SIMD_RN(2) a = fmin(v.lo, v.hi);
    return fmin(a.x, a.y);
#elif CLPT_LANES == 8
    SIMD_RN(4) a = fmin(v.lo, v.hi);
    SIMD_RN(2) b = fmin(a.lo, a.hi);
    return fmin(b.x, b.y);
#else
    SIMD_RN(8) a = fmin(v.lo, v.hi);
    SIMD_RN(4) b = fmin(a.lo, a.hi);
    SIMD_RN(2) c = fmin(b.lo, b.hi);
    return fmin(c.x, c.y);
#endif
}
