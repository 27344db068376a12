// accum.h: per-pixel sums that stay accurate over 10^6 samples and more.
//
// With fp64 (CLPT_ACCUM_DOUBLE) a pixel's sums are doubles. Devices without
// fp64 keep Kahan-compensated float sums (sum and compensation), whose error
// stays at a few float ulps of the total instead of growing with the sample
// count. Both take 32 + 8 bytes per pixel:
//   pix_sum  double4 (r, g, b, n)   or  float8 (r, g, b, n, and their compensations)
//   pix_sq   double (sum of squared luminance)   or  float2 (sum, compensation)

#if CLPT_ACCUM_DOUBLE
typedef double4 pix_sum_t;
typedef double pix_sq_t;
typedef struct { vdouble s; } Acc;
inline void acc_add(Acc *a, vreal x, vmask m) { a->s = VSEL(a->s, a->s + VDOUBLE(x), VMASK_D(m)); }
#else
typedef float8 pix_sum_t;
typedef float2 pix_sq_t;
typedef struct { vreal s, c; } Acc;
// Kahan summation: c carries what the last addition rounded away.
inline void acc_add(Acc *a, vreal x, vmask m)
{
    vreal y = x - a->c;
    vreal t = a->s + y;
    vreal c = (t - a->s) - y;
    a->s = VSEL(a->s, t, m);
    a->c = VSEL(a->c, c, m);
}
#endif

typedef struct { Acc r, g, b, n, sq; } PixelAcc;

inline void pixel_acc_load(PixelAcc *a, int l, __global const pix_sum_t *ps, __global const pix_sq_t *pq, uint p)
{
    pix_sum_t s = ps[p];
    pix_sq_t q = pq[p];
#if CLPT_ACCUM_DOUBLE
    VLANE_D(a->r.s, l) = s.x; VLANE_D(a->g.s, l) = s.y; VLANE_D(a->b.s, l) = s.z; VLANE_D(a->n.s, l) = s.w;
    VLANE_D(a->sq.s, l) = q;
#else
    VLANE_R(a->r.s, l) = s.s0; VLANE_R(a->g.s, l) = s.s1; VLANE_R(a->b.s, l) = s.s2; VLANE_R(a->n.s, l) = s.s3;
    VLANE_R(a->r.c, l) = s.s4; VLANE_R(a->g.c, l) = s.s5; VLANE_R(a->b.c, l) = s.s6; VLANE_R(a->n.c, l) = s.s7;
    VLANE_R(a->sq.s, l) = q.x; VLANE_R(a->sq.c, l) = q.y;
#endif
}

inline void pixel_acc_store(PixelAcc *a, int l, __global pix_sum_t *ps, __global pix_sq_t *pq, uint p)
{
#if CLPT_ACCUM_DOUBLE
    ps[p] = (double4)(VLANE_D(a->r.s, l), VLANE_D(a->g.s, l), VLANE_D(a->b.s, l), VLANE_D(a->n.s, l));
    pq[p] = VLANE_D(a->sq.s, l);
#else
    ps[p] = (float8)(VLANE_R(a->r.s, l), VLANE_R(a->g.s, l), VLANE_R(a->b.s, l), VLANE_R(a->n.s, l),
                     VLANE_R(a->r.c, l), VLANE_R(a->g.c, l), VLANE_R(a->b.c, l), VLANE_R(a->n.c, l));
    pq[p] = (float2)(VLANE_R(a->sq.s, l), VLANE_R(a->sq.c, l));
#endif
}

inline void pixel_acc_zero(PixelAcc *a)
{
#if CLPT_ACCUM_DOUBLE
    a->r.s = a->g.s = a->b.s = a->n.s = a->sq.s = 0.0;
#else
    a->r.s = a->g.s = a->b.s = a->n.s = a->sq.s = (vreal)0.0f;
    a->r.c = a->g.c = a->b.c = a->n.c = a->sq.c = (vreal)0.0f;
#endif
}
