// film.h: what trace_paths reads and writes per pixel, and nothing else does.
//
//   LaneJobs        which pixel each lane works on, from which sample, how
//                   many samples and how deep (pixels of a row, or of an
//                   adaptive pass's list), and the next pixel a lane takes
//   Film            the pixel sums of the lanes' pixels: sums stay accurate
//                   over 10^6 samples and more (below)
//   VisibleSurface  the feature sums the denoisers read (CLPT_AUX): normal,
//                   albedo, depth, directly seen emission, caustic part
// Each is loaded from its buffers when a lane takes a pixel, added to per
// sample in sample order, and stored when the lane has finished the pixel
// (lane_next), one lane at a time.
//
// Sums: with fp64 (CLPT_ACCUM_DOUBLE) a pixel's sums are doubles. Devices
// without fp64 keep Kahan-compensated float sums (sum and compensation), whose
// error stays at a few float ulps of the total instead of growing with the
// sample count. Both take 32 + 8 bytes per pixel:
//   pix_sum  double4 (r, g, b, n)   or  float8 (r, g, b, n, and their compensations)
//   pix_sq   double (sum of squared luminance)   or  float2 (sum, compensation)

#define NO_PIXEL 0xFFFFFFFFu

// --- the lanes' pixels -------------------------------------------------------------
// A work-item takes L->wi_entries consecutive entries: pixels of the image
// (row-major, from group_offset runs on), all taking samples
// [sample_begin, sample_begin + n_samples); or, when n_list > 0 (adaptive
// sampling), entries of jobs, each (samples, max depth, first sample, pixel):
// the host continues each pixel's sample sequence where it stands. With
// lanes, each lane takes the next entry not yet taken as soon as it has
// finished its own (lane_next), up to LANE_PIXELS entries per lane on
// average (the host takes fewer where a launch would leave compute units
// idle: clpt/constants.py work_item_entries); a lane whose paths ran short
// then takes more pixels instead of idling until the slowest lane's last
// path ends. One lane takes all of a pixel's samples, in order, so its sums
// are the same bits however the entries fell to lanes and work-items.
//
// The image's pixels and a list's entries come in runs of wi_entries:
// work-item gid takes run gid, or, when L->pull_runs (CPU devices: clpt/
// engine/passes.py TracePass), the work-items pull runs one after another
// from a counter after the list (pix_jobs[n_list].x; at pix_jobs[0] for the
// image), in order (a list's heaviest first), until none is left. A
// work-item's lanes go on to its next run as soon as they have taken the
// last one's entries, and the device's threads end a launch together
// however unevenly the runtime handed them its work-groups: PoCL gives a
// thread a contiguous block of them, in chunks that shrink as they run out
// (of 11 work-groups, 6 to one thread and 5 to the other).
#define NO_RUN 0xFFFFFFFFu
typedef struct {
    vuint pixel;     // row-major index (NO_PIXEL: none)
    vuint s_begin;   // index of the pixel's first sample here
    vreal n;         // samples to take (0: none)
    vreal depth;     // most scattering events of a path
    uint run;        // the run of entries the work-item takes from (NO_RUN: none left)
    uint next;       // the run's first entry no lane has taken
} LaneJobs;

// No pixel in any lane yet, the work-item at entry `next` of run `run`:
// its own run's first, or, pulling, past the end (lane_take pulls one).
// (Scalars, not the launch record: a struct-returning function with a
// pointer parameter, inlined, leaves a noalias scope declaration Oclgrind
// cannot run; kernels/simd.h CLPT_INLINE.)
inline LaneJobs lane_jobs_none(uint run, uint next)
{
    LaneJobs j;
    j.pixel = (vuint)NO_PIXEL;
    j.s_begin = (vuint)0u;
    j.n = j.depth = (vreal)R(0);
    j.run = run;
    j.next = next;
    return j;
}

// Entry k of run `run`: (samples, max depth, first sample, pixel); no
// samples past the image or the list.
inline uint4 lane_entry(const TraceLaunch *L, __global const uint4 *jobs, uint run, uint k)
{
    if (L->n_list == 0) {
        uint p = (L->group_offset + run) * L->wi_entries + k;
        return p < L->width * L->height ? (uint4)(L->n_samples, L->max_depth, L->sample_begin, p)
                                        : (uint4)(0u, 0u, 0u, NO_PIXEL);
    }
    uint e = run * L->wi_entries + k;
    return e < L->n_list ? jobs[e] : (uint4)(0u, 0u, 0u, NO_PIXEL);
}

// The next run pulled (NO_RUN: none left): of the list, or of the image's
// pixels in order.
inline uint lane_pull(const TraceLaunch *L, __global uint4 *jobs)
{
    uint r = atomic_inc((volatile __global uint *)(jobs + L->n_list));
    uint runs = L->n_list != 0u ? L->n_list / L->wi_entries
                                : (L->width * L->height + L->wi_entries - 1u) / L->wi_entries;
    return r < runs ? r : NO_RUN;
}

// Lane l takes the work-item's next entry with samples (none left: n = 0);
// returns its pixel, or NO_PIXEL.
inline uint lane_take(LaneJobs *j, int l, const TraceLaunch *L, __global uint4 *jobs)
{
    uint4 e = (uint4)(0u, 0u, 0u, NO_PIXEL);
    for (;;) {
        if (j->next >= L->wi_entries) {
            if (!L->pull_runs || j->run == NO_RUN)
                break;
            j->run = lane_pull(L, jobs);
            j->next = 0u;
            if (j->run == NO_RUN)
                break;
        }
        e = lane_entry(L, jobs, j->run, j->next++);
        if (e.x > 0u && e.w < L->width * L->height)
            break;
        e = (uint4)(0u, 0u, 0u, NO_PIXEL);
    }
    VLANE_U(j->pixel, l) = e.w;
    VLANE_U(j->s_begin, l) = e.z;
    VLANE_R(j->n, l) = (real)e.x;
    VLANE_R(j->depth, l) = (real)e.y;
    return e.w;
}

// --- pixel sums ----------------------------------------------------------------------
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

// Per lane: sums of r, g, b, samples and squared luminance (times lum_scale).
typedef struct { Acc r, g, b, n, sq; } Film;

inline void film_zero(Film *f)
{
#if CLPT_ACCUM_DOUBLE
    f->r.s = f->g.s = f->b.s = f->n.s = f->sq.s = 0.0;
#else
    f->r.s = f->g.s = f->b.s = f->n.s = f->sq.s = (vreal)0.0f;
    f->r.c = f->g.c = f->b.c = f->n.c = f->sq.c = (vreal)0.0f;
#endif
}

inline void film_load_lane(Film *f, int l, __global const pix_sum_t *ps, __global const pix_sq_t *pq, uint p)
{
    pix_sum_t s = ps[p];
    pix_sq_t q = pq[p];
#if CLPT_ACCUM_DOUBLE
    VLANE_D(f->r.s, l) = s.x; VLANE_D(f->g.s, l) = s.y; VLANE_D(f->b.s, l) = s.z; VLANE_D(f->n.s, l) = s.w;
    VLANE_D(f->sq.s, l) = q;
#else
    VLANE_R(f->r.s, l) = s.s0; VLANE_R(f->g.s, l) = s.s1; VLANE_R(f->b.s, l) = s.s2; VLANE_R(f->n.s, l) = s.s3;
    VLANE_R(f->r.c, l) = s.s4; VLANE_R(f->g.c, l) = s.s5; VLANE_R(f->b.c, l) = s.s6; VLANE_R(f->n.c, l) = s.s7;
    VLANE_R(f->sq.s, l) = q.x; VLANE_R(f->sq.c, l) = q.y;
#endif
}

// (f is not const: lanes are read through private storage, VLANE_*.)
inline void film_store_lane(Film *f, int l, __global pix_sum_t *ps, __global pix_sq_t *pq, uint p)
{
#if CLPT_ACCUM_DOUBLE
    ps[p] = (double4)(VLANE_D(f->r.s, l), VLANE_D(f->g.s, l), VLANE_D(f->b.s, l), VLANE_D(f->n.s, l));
    pq[p] = VLANE_D(f->sq.s, l);
#else
    ps[p] = (float8)(VLANE_R(f->r.s, l), VLANE_R(f->g.s, l), VLANE_R(f->b.s, l), VLANE_R(f->n.s, l),
                     VLANE_R(f->r.c, l), VLANE_R(f->g.c, l), VLANE_R(f->b.c, l), VLANE_R(f->n.c, l));
    pq[p] = (float2)(VLANE_R(f->sq.s, l), VLANE_R(f->sq.c, l));
#endif
}

// Adds finished samples (lanes in `done`) to the pixel sums. A sample that is
// not finite is counted and left out: it never reaches the sums. The squares
// are of luminance times lum_scale (a power of two that brings the scene's
// brightest emission near 1), so they stay in float's range at any units.
inline void film_add_sample(Film *f, vmask done, V3 L, real lum_scale, uint *nonfinite)
{
    vreal lum = v3_luminance(L) * lum_scale;
    vmask bad = done && !isfinite(L.x + L.y + L.z);
    *nonfinite += vpopcount(bad);
    vmask ok = done && !bad;
    acc_add(&f->r, L.x, ok);
    acc_add(&f->g, L.y, ok);
    acc_add(&f->b, L.z, ok);
    acc_add(&f->sq, lum * lum, ok);
    acc_add(&f->n, (vreal)R(1), done);
}

// --- features for the denoisers (CLPT_AUX) ------------------------------------------
// Per pixel, sums over samples of the feature vertex's shading normal (w:
// count), of its albedo seen through the specular chain (rgb) and distance
// from the camera (w), of the emission reached up to and at that vertex or
// through mirrors and glass alone (rgb; w: samples that see an emitter so,
// directly or through mirrors and glass), and of the
// photon map's contribution at the first vertex with a non-delta part (the
// gather there, or its merge; rgb; w: its squared luminance times
// lum_scale^2). The feature vertex is the first vertex with a non-delta part
// (aux_specular 0: mirrors and glass are seen through) or the first vertex
// (1: they are surfaces with albedo kr + kt), or the first that is not glass
// (2: mirrors are surfaces, glass is seen through). An emitter's albedo is its
// emission over its largest component, times the throughput; paths that meet
// no feature vertex get albedo 1 and no normal. The four sums are planes of
// one buffer, n_pix float4 each: normal, albedo, emission, caustic.
typedef struct {
    V3 normal;   vreal count;       // plane 0
    V3 albedo;   vreal depth;       // plane 1
    V3 emission; vreal lights;      // plane 2
    V3 caustic;  vreal caustic_sq;  // plane 3
    vmask found;     // this sample's feature vertex is recorded
    vmask chain;     // this sample's path has met only mirrors and glass so far
    vmask lit;       // this sample has reached an emitter directly or through mirrors and glass
    vreal path_len;  // distance this sample's path has travelled
} VisibleSurface;

#if CLPT_AUX
inline void v3_add_where(V3 *a, V3 b, vmask m) { *a = v3_sel(*a, v3_add(*a, b), m); }
inline void vreal_add_where(vreal *a, vreal b, vmask m) { *a = VSEL(*a, *a + b, m); }

inline void visible_zero(VisibleSurface *v)
{
    v->normal = v->albedo = v->emission = v->caustic = v3_zero();
    v->count = v->depth = v->lights = v->caustic_sq = v->path_len = (vreal)R(0);
    v->found = v->chain = v->lit = v->count != v->count;
}

inline void visible_load_lane(VisibleSurface *v, int l, uint p, uint n_pix, __global const float4 *aux)
{
    float4 a = aux[p], b = aux[n_pix + p], c = aux[2 * n_pix + p], e = aux[3 * n_pix + p];
    VLANE_R(v->normal.x, l) = a.x; VLANE_R(v->normal.y, l) = a.y; VLANE_R(v->normal.z, l) = a.z;
    VLANE_R(v->count, l) = a.w;
    VLANE_R(v->albedo.x, l) = b.x; VLANE_R(v->albedo.y, l) = b.y; VLANE_R(v->albedo.z, l) = b.z;
    VLANE_R(v->depth, l) = b.w;
    VLANE_R(v->emission.x, l) = c.x; VLANE_R(v->emission.y, l) = c.y; VLANE_R(v->emission.z, l) = c.z;
    VLANE_R(v->lights, l) = c.w;
    VLANE_R(v->caustic.x, l) = e.x; VLANE_R(v->caustic.y, l) = e.y; VLANE_R(v->caustic.z, l) = e.z;
    VLANE_R(v->caustic_sq, l) = e.w;
}

inline void visible_store_lane(VisibleSurface *v, int l, uint p, uint n_pix, __global float4 *aux)
{
    aux[p] = (float4)(VLANE_R(v->normal.x, l), VLANE_R(v->normal.y, l), VLANE_R(v->normal.z, l),
                      VLANE_R(v->count, l));
    aux[n_pix + p] = (float4)(VLANE_R(v->albedo.x, l), VLANE_R(v->albedo.y, l), VLANE_R(v->albedo.z, l),
                              VLANE_R(v->depth, l));
    aux[2 * n_pix + p] = (float4)(VLANE_R(v->emission.x, l), VLANE_R(v->emission.y, l),
                                  VLANE_R(v->emission.z, l), VLANE_R(v->lights, l));
    aux[3 * n_pix + p] = (float4)(VLANE_R(v->caustic.x, l), VLANE_R(v->caustic.y, l), VLANE_R(v->caustic.z, l),
                                  VLANE_R(v->caustic_sq, l));
}

// A new sample in the lanes of `start`.
inline void visible_start(VisibleSurface *v, vmask start)
{
    v->found = v->found && !start;
    v->chain = v->chain || start;
    v->lit = v->lit && !start;
    v->path_len = VSEL(v->path_len, (vreal)R(0), start);
}

// Whether m emits towards a ray that meets its front (or back) face.
inline vmask emitter_facing(const Material *m, vmask front)
{
    return fmax(m->Le.x, fmax(m->Le.y, m->Le.z)) > R(0) && (front || m->two_sided != R(0));
}

// The lanes in `seen` met an emitter directly or through mirrors and glass:
// counted once a sample.
inline void visible_saw_emitter(VisibleSurface *v, vmask seen)
{
    seen = seen && !v->lit;
    vreal_add_where(&v->lights, (vreal)R(1), seen);
    v->lit = v->lit || seen;
}

// The surface the lanes in `hit` reached, t further along the path: recorded
// where it is this sample's feature vertex. Returns the lanes whose emission
// here the denoisers keep out of the filtering (seen directly): the vertex
// is the feature vertex or comes before it, or every vertex before it is a
// mirror or glass (a lamp's reflection or refraction, in either mode).
inline vmask visible_add_vertex(VisibleSurface *v, vmask hit, vreal t, const Material *m, V3 n, V3 beta,
                                vmask front, uint aux_specular)
{
    v->path_len = VSEL(v->path_len, v->path_len + t, hit);
    vmask before_x = !v->found || v->chain;
    // An emitter seen here is counted (once a sample) in both modes.
    vreal le_max = fmax(m->Le.x, fmax(m->Le.y, m->Le.z));
    vmask facing = emitter_facing(m, front);
    visible_saw_emitter(v, hit && before_x && facing);
    v->chain = v->chain && !(hit && m->nondelta != R(0));
    // aux_specular 1: mirrors and glass are surfaces; 2: mirrors are, glass is seen through
    vmask clear = fmax(m->kt.x, fmax(m->kt.y, m->kt.z)) > R(0);
    vmask rec = hit && !v->found && (m->nondelta != R(0) || aux_specular == 1u || (aux_specular == 2u && !clear));
    if (VANY(rec)) {
        V3 surf = v3_add(m->kd, m->ks);
#if CLPT_HAS_MICROFACET
        surf = v3_add(surf, m->km);
#endif
#if CLPT_HAS_PLASTIC
        surf = v3_add(surf, m->kp);
#endif
#if CLPT_HAS_ROUGH_DIELECTRIC
        surf = v3_add(surf, m->gt);  // a rough dielectric: its transmittance
#endif
        if (aux_specular != 0u) {  // a mirror or glass vertex is a surface of albedo kr + kt (at most 1)
            V3 spec = v3_add(m->kr, m->kt);
            surf = v3_sel(surf, v3(fmin(spec.x, R(1)), fmin(spec.y, R(1)), fmin(spec.z, R(1))),
                          m->nondelta == R(0));
        }
        // An emitter it sees is described by its own colour.
        surf = v3_sel(surf, v3_scale(m->Le, R(1) / fmax(le_max, R(1e-30))), rec && facing);
        v3_add_where(&v->normal, n, rec);
        v3_add_where(&v->albedo, v3_mul(beta, surf), rec);
        vreal_add_where(&v->depth, v->path_len, rec);
        vreal_add_where(&v->count, (vreal)R(1), rec);
        v->found = v->found || rec;
    }
    return before_x;
}

// Emission Le that the lanes in `sees` reached through the reflection of
// the camera's first vertex on glass (path_glass_split): seen through
// glass, so kept out of the filtering; the lanes in `lit` met an emitter.
inline void visible_add_split(VisibleSurface *v, V3 Le, vmask sees, vmask lit)
{
    v3_add_where(&v->emission, Le, sees);
    visible_saw_emitter(v, lit);
}

// The photon map's part c of this sample (lanes in m, if finite): rgb and
// its squared luminance times lum_scale^2.
inline void visible_add_caustic(VisibleSurface *v, V3 c, vmask m, real lum_scale)
{
    vreal l = v3_luminance(c) * lum_scale;
    vmask add = m && isfinite(c.x + c.y + c.z);
    v3_add_where(&v->caustic, c, add);
    v->caustic_sq = VSEL(v->caustic_sq, v->caustic_sq + l * l, add);  // one expression: l * l may fuse into the sum
}

// Finished samples (lanes in done) that met no feature vertex (an emitter
// seen directly or through glass, or the void): no normal, albedo 1, the
// distance travelled.
inline void visible_end_sample(VisibleSurface *v, vmask done)
{
    vmask none = done && !v->found;
    v3_add_where(&v->albedo, v3((vreal)R(1), (vreal)R(1), (vreal)R(1)), none);
    vreal_add_where(&v->depth, v->path_len, none);
    vreal_add_where(&v->count, (vreal)R(1), none);
}
#endif

// The lanes in `want` have finished their pixels: their sums go back to the
// buffers (the features' unless aux_out is 0), and each takes the next entry
// with samples and loads its pixel's sums. Returns the lanes that got one.
inline vmask lane_next(LaneJobs *j, Film *f, VisibleSurface *vis, vmask want, const TraceLaunch *L,
                       __global uint4 *jobs, __global pix_sum_t *ps, __global pix_sq_t *pq,
                       __global float4 *aux, int aux_out)
{
    uint n_pix = L->width * L->height;
    for (int l = 0; l < CLPT_LANES; l++) {
        if (VLANE_M(want, l) == 0)
            continue;
        uint p = VLANE_U(j->pixel, l);
        if (p < n_pix) {
            film_store_lane(f, l, ps, pq, p);
#if CLPT_AUX
            if (aux_out)
                visible_store_lane(vis, l, p, n_pix, aux);
#endif
        }
        p = lane_take(j, l, L, jobs);
        if (p < n_pix) {
            film_load_lane(f, l, ps, pq, p);
#if CLPT_AUX
            visible_load_lane(vis, l, p, n_pix, aux);
#endif
        }
    }
    return want && j->n > R(0);
}
