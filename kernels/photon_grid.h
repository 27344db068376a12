// photon_grid.h: the caustic photon map's hash grid and its cone-filter gather.
//
// Cells are cubes of two gather radii (inv_cell = 1 / (2 r), set by the
// host). A cell's bucket is a hash of its y and z plus its x, so the cells
// of an x-row sit in consecutive buckets. Photons are sorted by bucket and
// bucket_start[b] is the first photon of bucket b (bucket_start[table size]
// = photon count), so the two cells of a row are one contiguous range of
// photons. A gather ball of radius r around x lies within the 2 x 2 x 2
// cells nearest to x (its own cell and, per axis, the neighbour on the side
// of the half x is in: grid_lower_corner), so a gather reads 4 ranges. A bucket may also
// hold photons of other cells: a photon counts only when its own cell is in
// the row being visited, so none is counted twice. The sort is stable, so a
// gather adds the same photons in the same order every time.
//
// Dense caustics can pack most of the map into a few cells. To bound a
// gather's cost, a row range of more than `budget` photons is subsampled:
// with stride s = ceil(count / budget) and a random offset o in [0, s), the
// photons o, o + s, ... are visited and weighted by s. Each photon is taken
// with probability exactly 1/s, so the estimate stays that of the full
// radius in expectation; its extra noise averages out over samples.

#define GRID_ROW_HASH(y, z) (((y) * 73856093u) ^ ((z) * 19349663u))
// Cell coordinates far outside any scene are clamped, not overflowed.
#define GRID_COORD_LIMIT R(1.0e9)
// The occupancy bits (photon_maybe) are kept for cells OCC_SPLIT times finer
// than the grid's per axis (one radius across), set for every cell within
// OCC_PAD radii of a photon, plus the rounding of coordinates (OCC_REL_TOL
// of a coordinate, in cells; grid.cl photon_occupancy).
#define OCC_SPLIT 2
#define OCC_PAD 1.02
#define OCC_REL_TOL 1e-6

inline int grid_coord(real v, real inv_cell)
{
    return (int)floor(clamp(v * inv_cell, -GRID_COORD_LIMIT, GRID_COORD_LIMIT));
}

INLINE_VEC3 int3 grid_cell(real3 p, real inv_cell)
{
    return (int3)(grid_coord(p.x, inv_cell), grid_coord(p.y, inv_cell), grid_coord(p.z, inv_cell));
}

// The lowest of the 2 x 2 x 2 cells that hold every point within half a cell
// (one radius) of p.
INLINE_VEC3 int3 grid_lower_corner(real3 p, real inv_cell)
{
    real3 q = clamp(p * inv_cell, -GRID_COORD_LIMIT, GRID_COORD_LIMIT);
    real3 f = floor(q);
    int3 c = (int3)((int)f.x, (int)f.y, (int)f.z);
    return c - (int3)(q.x - f.x < R(0.5), q.y - f.y < R(0.5), q.z - f.z < R(0.5)) * (int3)(1);
}

INLINE_VEC3 uint grid_bucket(int3 c, uint mask)
{
    return (GRID_ROW_HASH(as_uint(c.y), as_uint(c.z)) + as_uint(c.x)) & mask;
}

typedef struct {
    __global const float4 *pos;   // xyz; w = 1 for a stored photon
    __global const float4 *dir;   // direction of travel (into the surface)
    __global const float4 *pow;   // flux, rgb
    __global const uint *bucket_start;  // table size + 1 entries
    uint mask;                    // table size - 1 (a power of two)
    uint max_photons;             // most photons a gather uses (the paper's cap)
    uint budget;                  // most photons visited per row of cells (subsampled above)
    real radius, inv_cell, cone_k;
    real mis_k;                   // pi r^2 N photons: the merge's pdf is pf cos mis_k (path.h)
    __global const uint *occ;     // occupancy bits (grid.cl photon_occupancy)
    uint occ_mask;                // bits in the table - 1
    uint moments;                 // merges also estimate path tracing's second moment (CLPT_AUX; below)
    real r2, inv_kr, norm;        // a gather's constants (photon_map_derive)
} PhotonMap;

// The constants every gather uses, from the radius and the cone filter:
// computed once, not per gather.
inline void photon_map_derive(PhotonMap *pm)
{
    pm->r2 = pm->radius * pm->radius;
    pm->inv_kr = R(1) / (pm->cone_k * pm->radius);
    pm->norm = (R(1) - R(2) / (R(3) * pm->cone_k)) * R(M_PI) * pm->r2;
}

// The photon map of a launch: its buffers and the launch record's settings.
// The offline pre-pass gathers only a few times per pixel: subsampling noise
// would not average out there, so the host gives it an unbounded budget.
// (Filled through a pointer: a struct returned by an inlined function whose
// storage lives on leaves a noalias scope declaration Oclgrind cannot run.)
inline void photon_map_init(PhotonMap *pm, const PhotonLookup *pl, __global const float4 *pos,
                            __global const float4 *dir, __global const float4 *pow, __global const uint *bucket_start,
                            __global const uint *occ)
{
    pm->pos = pos; pm->dir = dir; pm->pow = pow;
    pm->bucket_start = bucket_start;
    pm->mask = pl->mask; pm->max_photons = pl->max_photons; pm->budget = pl->budget;
    pm->radius = pl->radius; pm->inv_cell = pl->inv_cell; pm->cone_k = pl->cone_k;
    pm->mis_k = pl->mis_k;
    pm->occ = occ; pm->occ_mask = pl->occ_mask;
    pm->moments = pl->moments;
    photon_map_derive(pm);
}

#if CLPT_LANES == 1
#define VAS_UINT(x) as_uint(x)
#else
#define VAS_UINT(x) CLPT_CAT(as_uint, CLPT_LANES)(x)
#endif

// Lanes (among `active`) whose occupancy cell's bit is set: only they can
// have photons within the radius. Vector code, one load per lane.
inline vmask photon_maybe(const PhotonMap *pm, V3 x, vmask active)
{
    real inv_occ = pm->inv_cell * R(OCC_SPLIT);
    vint cx = VINT(floor(clamp(x.x * inv_occ, -GRID_COORD_LIMIT, GRID_COORD_LIMIT)));
    vint cy = VINT(floor(clamp(x.y * inv_occ, -GRID_COORD_LIMIT, GRID_COORD_LIMIT)));
    vint cz = VINT(floor(clamp(x.z * inv_occ, -GRID_COORD_LIMIT, GRID_COORD_LIMIT)));
    vuint b = (GRID_ROW_HASH(VAS_UINT(cy), VAS_UINT(cz)) + VAS_UINT(cx)) & pm->occ_mask;
    vuint word = (vuint)0u;
    for (int l = 0; l < CLPT_LANES; l++)
        VLANE_U(word, l) = pm->occ[VLANE_U(b, l) >> 5];
    vuint bit = (word >> (b & 31u)) & 1u;
    return active && VREAL(bit) > R(0);
}

// Radiance reflected towards -d at x (unit normal n facing -d) by the photons
// within the gather radius, for a surface with diffuse albedo kd and Phong
// lobe ks, shininess: sum of w f flux / ((1 - 2/(3k)) pi r^2), with Jensen's
// cone filter w = 1 - dist / (k r). Photons arriving from behind the surface
// are left out, and so are photons of more than max_bounces specular
// bounces (the path would be longer than the camera path may grow). With mis
// 1, each photon is weighted against path tracing by the power heuristic: the
// merge's pdf pf cos mis_k against the BSDF pdf (p_d cos / pi + p_s Phong pdf)
// of the direction the photon came from. With mis 2, only delta lights'
// photons (pf = inf) count, whole (path.h: an owned map past x). One query, in scalar code: each lane
// walks its own cells, so no lane waits for a denser neighbour.
//
// With pm->moments (builds with feature buffers: the pilot's trial,
// clpt/photons.py), *m2 gets the second moment path tracing alone would have
// for the paths this gather merges, estimated from the photons themselves:
// a photon's path x, merged with pdf p_m and contribution c = f / p_m, is a
// path path tracing makes with pdf p_pt, so f^2 / p_pt = c^2 p_m / p_pt is
// an unbiased sample of path tracing's second moment (its rare paths are
// what an equal-sample trial of path tracing misses). c is the luminance
// (weights lw) of the photon's contribution before the MIS weight; the cone
// filter's weights square to kappa = pi r^2 int K^2 times the uniform
// kernel's, and are divided out; with subsampling (stride s) each visited
// photon stands for s, so it adds c^2 / s.
#if CLPT_AUX
// One photon's sample of path tracing's second moment (below), before the
// gather's normalization: its contribution's luminance c (flux: its power
// times the cone weight w) squared, over the stride weight s and q = p_pt /
// p_m. (q = 0: a path path tracing cannot make; its error there is the
// path's whole contribution, counted as c^2.)
INLINE_VEC3 real photon_moment(real3 lw, real3 kd, real3 ks, real shininess, real lobe_s, real3 flux, real s, real q)
{
    real3 f = kd * R(M_1_PI);
#if CLPT_HAS_PHONG
    f += ks * ((shininess + R(2)) * R(0.5 * M_1_PI)) * lobe_s;
#endif
    real c = dot(lw, f * flux);
    return c * c / (s * (q > R(0) && isfinite(q) ? q : R(1)));
}

// pi r^2 int K^2 over the disk for the cone filter K = (1 - d / (k r)) / ((1 - 2 / (3k)) pi r^2):
// how much more the squares of its weights sum to than the uniform kernel's.
inline real cone_kappa(real k)
{
    real a = R(1) - R(2) / (R(3) * k);
    return R(2) * (R(0.5) - R(2) / (R(3) * k) + R(0.25) / (k * k)) / (a * a);
}
#endif

// The photons of the row of two cells starting at cell: [*s0, *e0) and
// [*s1, *e1) (buckets b, b+1 hold the row; the last may wrap to bucket 0,
// and then the second range holds its part). Returns how many of the two
// buckets lie before the wrap.
INLINE_VEC3 uint grid_row_range(const PhotonMap *pm, int3 cell, uint *s0, uint *e0, uint *s1, uint *e1)
{
    uint b = grid_bucket(cell, pm->mask);
    uint n_first = min(2u, pm->mask + 1u - b);
    *s0 = pm->bucket_start[b];
    *e0 = pm->bucket_start[b + n_first];
    *s1 = *e1 = 0u;
    if (n_first < 2u) {
        *s1 = pm->bucket_start[0];
        *e1 = pm->bucket_start[2u - n_first];
    }
    return n_first;
}

INLINE_VEC3 real3 photon_gather_one(const PhotonMap *pm, real3 x, real3 n, real3 d, real3 kd, real3 ks, real shininess,
                                    real u, real p_d, real p_s, int mis, real max_bounces, real3 lw, real *m2)
{
    real r2 = pm->r2, inv_kr = pm->inv_kr;
    int3 base = grid_lower_corner(x, pm->inv_cell);
    real3 sum_d = (real3)(R(0)), sum_s = (real3)(R(0));
#if CLPT_HAS_PHONG
    real3 refl = d - R(2) * dot(d, n) * n;
    int phong = ks.x > R(0) || ks.y > R(0) || ks.z > R(0);
#endif
    uint found = 0;
    // The four rows' ranges first: their loads overlap.
    uint rs0[4], re0[4], rs1[4], re1[4], rn[4];
    uint rows = 0u;  // the rows with photons, as bits
    for (int k = 0; k < 4; k++) {
        rn[k] = grid_row_range(pm, base + (int3)(0, k & 1, k >> 1), &rs0[k], &re0[k], &rs1[k], &re1[k]);
        rows |= (re0[k] - rs0[k] + re1[k] - rs1[k] != 0u ? 1u : 0u) << k;
    }
    while (rows != 0u) {
        int k = 31 - (int)clz(rows & (0u - rows));
        rows &= rows - 1u;
        int3 cell = base + (int3)(0, k & 1, k >> 1);  // first cell of the row
        uint s0 = rs0[k], e0 = re0[k], s1 = rs1[k], e1 = re1[k], n_first = rn[k];
        uint count = (e0 - s0) + (e1 - s1);
        uint stride = 1u, offset = 0u;
        if (count > pm->budget) {
            stride = (count + pm->budget - 1u) / pm->budget;
            offset = min((uint)(u * (real)stride), stride - 1u);
        }
        real weight = (real)stride;
        for (int part = 0; part < 2; part++) {
            uint end = part == 0 ? e0 : e1;
            // The stride runs on across the wrap: row index j is visited when j % stride == offset.
            uint first = part == 0 ? s0 + offset : s1 + (offset + stride - (e0 - s0) % stride) % stride;
            for (uint i = first; i < end; i += stride) {
                float4 p = pm->pos[i];
                real3 to = REAL3(p.xyz) - x;
                real d2 = dot(to, to);
                if (d2 >= r2)
                    continue;
                if (p.w > max_bounces)
                    continue;
                int3 pc = grid_cell(REAL3(p.xyz), pm->inv_cell);
                if (pc.y != cell.y || pc.z != cell.z || pc.x < cell.x || pc.x > cell.x + 1)
                    continue;  // another cell's photon in these buckets
                float4 dir = pm->dir[i];
#if CLPT_HAS_DELTA_LIGHTS
                if (mis == 2 && !isinf(dir.w))
                    continue;  // (delta lights' photons only)
#endif
                real3 w_in = REAL3(dir.xyz);
                real cos_n = -dot(w_in, n);
                if (cos_n <= R(0))
                    continue;  // arrives from behind the surface
                real w = weight * (R(1) - sqrt(d2) * inv_kr);
                real lobe_s = R(0);
#if CLPT_HAS_PHONG
                if (phong) {
                    real ca = -dot(refl, w_in);
                    lobe_s = ca > R(0) ? exp(shininess * log(fmax(ca, R(1e-30)))) : R(0);
                }
#endif
                real p_pt = p_d * cos_n * R(M_1_PI) + p_s * (shininess + R(1)) * R(0.5 * M_1_PI) * lobe_s;
                real q = p_pt / ((real)dir.w * cos_n * pm->mis_k);
#if CLPT_AUX
                if (pm->moments)
                    *m2 += photon_moment(lw, kd, ks, shininess, lobe_s, REAL3(pm->pow[i].xyz) * w, weight, q);
#endif
                if (mis == 1) {
                    real wm = R(1) / (R(1) + q * q);
                    w *= isnan(wm) ? R(0) : wm;
                }
                real3 flux = REAL3(pm->pow[i].xyz) * w;
                sum_d += flux;
#if CLPT_HAS_PHONG
                sum_s += flux * lobe_s;
#endif
                if (++found >= pm->max_photons)
                    goto done;
            }
            if (n_first == 2u)
                break;
        }
    }
done:;
    if (found == 0u)
        return (real3)(R(0));  // nothing in reach (also keeps 0 / 0 out when r^2 underflows)
    real3 f_sum = kd * R(M_1_PI) * sum_d;
#if CLPT_HAS_PHONG
    f_sum += ks * ((shininess + R(2)) * R(0.5 * M_1_PI)) * sum_s;
#endif
    real norm = pm->norm;
#if CLPT_AUX
    if (pm->moments)
        *m2 /= norm * norm * cone_kappa(pm->cone_k);
#endif
    return f_sum / norm;
}

// The gather for the lanes in `active`, one lane at a time (u: per-lane
// random numbers for the subsampling offsets).
inline V3 photon_gather(const PhotonMap *pm, const Material *m, LobeProbs pr, V3 x, V3 n, V3 d, vreal u,
                        vmask active, int mis, vreal max_bounces, V3 lw, vreal *m2)
{
    active = photon_maybe(pm, x, active);
    V3 out = v3_zero();
#if CLPT_AUX
    *m2 = (vreal)R(0);
#endif
    // The active lanes as bits, visited lowest first (no branch per lane).
    uint lanes = 0u;
    for (int l = 0; l < CLPT_LANES; l++)
        lanes |= (VLANE_M(active, l) != 0 ? 1u : 0u) << l;
    while (lanes != 0u) {
        int l = 31 - (int)clz(lanes & (0u - lanes));
        lanes &= lanes - 1u;
        real3 xl = (real3)(VLANE_R(x.x, l), VLANE_R(x.y, l), VLANE_R(x.z, l));
        real3 nl = (real3)(VLANE_R(n.x, l), VLANE_R(n.y, l), VLANE_R(n.z, l));
        real3 dl = (real3)(VLANE_R(d.x, l), VLANE_R(d.y, l), VLANE_R(d.z, l));
        real3 kd = (real3)(VLANE_R(m->kd.x, l), VLANE_R(m->kd.y, l), VLANE_R(m->kd.z, l));
        real3 ks = (real3)(VLANE_R(m->ks.x, l), VLANE_R(m->ks.y, l), VLANE_R(m->ks.z, l));
        real m2l = R(0);
#if CLPT_AUX
        real3 lwl = (real3)(VLANE_R(lw.x, l), VLANE_R(lw.y, l), VLANE_R(lw.z, l));
#else
        real3 lwl = (real3)(R(0));  // (no moments without feature buffers)
#endif
        real3 L = photon_gather_one(pm, xl, nl, dl, kd, ks, VLANE_R(m->shininess, l), VLANE_R(u, l),
                                    VLANE_R(pr.d, l), VLANE_R(pr.s, l), mis, VLANE_R(max_bounces, l), lwl, &m2l);
#if CLPT_AUX
        VLANE_R(*m2, l) = m2l;
#endif
        VLANE_R(out.x, l) = L.x;
        VLANE_R(out.y, l) = L.y;
        VLANE_R(out.z, l) = L.z;
    }
    return out;
}
