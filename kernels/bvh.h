// bvh.h: closest-hit and shadow queries through the scene's BVH.
//
// Layout (clpt/layout.py BvhNode and BvhLeaf, built by clpt/bvh.py, packed
// by clpt/pack.py): a wide node holds its 8 children's boxes as rows of 8
// reals (lo.x, hi.x, lo.y, hi.y, lo.z, hi.z), then their pointers and
// counts: count > 0 is a leaf block of that many items at the pointer, 0 a
// node at the pointer, -1 an empty slot. A leaf block holds up to 4 items
// (triangles, quads, spheres) in rows of 4 reals (structure of arrays):
// their PlanarRec fields, geometry and the hit's attributes (material,
// light, primitive id, kind), 256 bytes. The root is the node at OFF_BVH,
// on a 64-byte boundary, so no node or leaf straddles more cache lines
// than it fills.
//
// Two walks, and the hybrid of them is the default (CLPT_BVH_PACKETS = 1;
// 0, every ray alone, is kept for `clpt bench-bvh --walks` to compare;
// README "Meshes and the BVH" has the measurements):
//   packet      all CLPT_LANES rays of the work-item walk the tree together
//               where they are coherent (all active, one origin: camera
//               rays), each child's box tested against every lane at once,
//               a child entered if any lane enters it, the nearest first.
//   per lane    each lane's ray walks alone with its own stack: a node's
//               8 boxes are tested against the one ray in one vector
//               operation, and a leaf's 4 items likewise (Embree's way);
//               the nearest child is entered first, the others pushed with
//               their entry distance and skipped when popped beyond the
//               nearest hit found by then.
// The stack bound (clpt/bvh.py MAX_STACK) is checked by the host.

#define BVH_STACK 96
#define BVH_LEAF_BIT 0x80000000u

#if CLPT_DOUBLE
typedef double8 breal8;
typedef long8 bmask8;
#else
typedef float8 breal8;
typedef int8 bmask8;
#endif
#if BVHL_WIDTH == 4
typedef real4 lreal;
#if CLPT_DOUBLE
typedef long4 lmask;
#else
typedef int4 lmask;
#endif
#define LEAF_MIN(v) bvh_min4(v)
#else
#error "leaf blocks of 4 items"
#endif
#define BVH_EL(v, k) (((private real *)&(v))[k])
// Sort keys of 8 non-negative reals: their bits as unsigned integers.
#if CLPT_DOUBLE
typedef ulong8 bkey8;
typedef ulong bkeyel;
#define BVH_AS_KEY8(v) as_ulong8(v)
#define BVH_KEY_INF 0x7ff0000000000000ul
#define BVH_KEY_MASK 0x7ffffffffffffff8ul
#define BVH_IOTA8 ((ulong8)(0, 1, 2, 3, 4, 5, 6, 7))
#else
typedef uint8 bkey8;
typedef uint bkeyel;
#define BVH_AS_KEY8(v) as_uint8(v)
#define BVH_KEY_INF 0x7f800000u
#define BVH_KEY_MASK 0x7ffffff8u
#define BVH_IOTA8 ((uint8)(0, 1, 2, 3, 4, 5, 6, 7))
#endif
// An 8-lane comparison's mask as int8 (-1: true).
#if CLPT_DOUBLE
#define BVH_I8(m) convert_int8(m)
#else
#define BVH_I8(m) (m)
#endif

// Field `field` (BVH_*: a row of 8 reals) of the node at record node.
inline breal8 bvh_row(const Scene *sc, uint node, uint field)
{
#if CLPT_DOUBLE
    return vload8(0, (__global const double *)(sc->rec + node + field));
#else
    return vload8(0, (__global const float *)(sc->rec + node + field));
#endif
}

// Field `field` (BVHL_*: a row of BVHL_WIDTH reals, one per item) of a leaf block.
inline lreal bvh_lrow(const Scene *sc, uint blk, uint field)
{
    return scene_rec(sc, blk + field);
}

inline real bvh_min4(real4 v)
{
    __typeof__(v.lo) a = min(v.lo, v.hi);
    return min(a.x, a.y);
}

// Smallest of 8 (no NaNs).
inline real bvh_min8(breal8 v)
{
    __typeof__(v.lo) a = min(v.lo, v.hi);
    __typeof__(a.lo) b = min(a.lo, a.hi);
    return min(b.x, b.y);
}

// Entry distance into the box lo..hi for lanes that enter it before tmax
// (+inf for the others). The exit distance is widened by a few ulps so that
// boxes the host rounded outwards are never missed by rounding here.
inline vreal bvh_enter(real4 lo, real4 hi, V3 o, V3 inv, vreal tmax)
{
    vreal x0 = (lo.x - o.x) * inv.x, x1 = (hi.x - o.x) * inv.x;
    vreal y0 = (lo.y - o.y) * inv.y, y1 = (hi.y - o.y) * inv.y;
    vreal z0 = (lo.z - o.z) * inv.z, z1 = (hi.z - o.z) * inv.z;
    vreal tn = fmax(fmax(fmin(x0, x1), fmin(y0, y1)), fmax(fmin(z0, z1), (vreal)R(0)));
    vreal tf = fmin(fmin(fmax(x0, x1), fmax(y0, y1)), fmax(z0, z1)) * R(1 + 4 * REAL_EPS);
    return VSEL((vreal)R(INFINITY), tn, tn <= fmin(tf, tmax));
}


// Item k of the leaf block at blk as the PLANAR rows p, n, wu, wv.
inline void bvh_leaf_item(const Scene *sc, uint blk, int k, real4 *p, real4 *n, real4 *wu, real4 *wv)
{
    // Whole rows loaded, then item k taken from each (a scalar load per field was slower on PoCL).
    real4 px = bvh_lrow(sc, blk, BVHL_PX), py = bvh_lrow(sc, blk, BVHL_PY), pz = bvh_lrow(sc, blk, BVHL_PZ);
    real4 nx = bvh_lrow(sc, blk, BVHL_NX), ny = bvh_lrow(sc, blk, BVHL_NY), nz = bvh_lrow(sc, blk, BVHL_NZ);
    real4 ux = bvh_lrow(sc, blk, BVHL_UX), uy = bvh_lrow(sc, blk, BVHL_UY), uz = bvh_lrow(sc, blk, BVHL_UZ);
    real4 vx = bvh_lrow(sc, blk, BVHL_VX), vy = bvh_lrow(sc, blk, BVHL_VY), vz = bvh_lrow(sc, blk, BVHL_VZ);
    real4 kind = bvh_lrow(sc, blk, BVHL_KIND), mat = bvh_lrow(sc, blk, BVHL_MAT);
    real4 light = bvh_lrow(sc, blk, BVHL_LIGHT), prim = bvh_lrow(sc, blk, BVHL_PRIM);
    *p = (real4)(BVH_EL(px, k), BVH_EL(py, k), BVH_EL(pz, k), BVH_EL(mat, k));
    *n = (real4)(BVH_EL(nx, k), BVH_EL(ny, k), BVH_EL(nz, k), BVH_EL(light, k));
    *wu = (real4)(BVH_EL(ux, k), BVH_EL(uy, k), BVH_EL(uz, k), BVH_EL(prim, k));
    *wv = (real4)(BVH_EL(vx, k), BVH_EL(vy, k), BVH_EL(vz, k), BVH_EL(kind, k));
}

// Item k of a leaf against every lane: its records and the hit distances
// (a, b: the planar hit's coordinates; a sphere's records are p.xyz = centre, n.x = radius).
inline vreal bvh_leaf_item_t(const Scene *sc, uint blk, int k, V3 o, V3 d, real4 *p, real4 *n, real4 *wu,
                             real4 *wv, vreal *a, vreal *b)
{
    bvh_leaf_item(sc, blk, k, p, n, wu, wv);
    if ((*wv).w == (real)ITEM_SPHERE)
        return intersect_sphere((real4)((*p).x, (*p).y, (*p).z, (*n).x), o, d);
    return intersect_planar_recs(*p, *n, *wu, *wv, o, d, (*wv).w != (real)ITEM_QUAD, a, b);
}

// A leaf's items against every lane (each item against all lanes at once):
// the closest hits into *h (any = 0), or the lanes they block before tmax
// or'ed into *occ (any = 1; a constant where this is inlined).
CLPT_INLINE void bvh_leaf_lanes(const Scene *sc, uint blk, V3 o, V3 d, int any, Hit *h, vreal tmax, vmask *occ)
{
    real4 kind = bvh_lrow(sc, blk, BVHL_KIND);
    for (int k = 0; k < BVHL_WIDTH; k++) {
        if (BVH_EL(kind, k) == (real)ITEM_EMPTY)
            break;
        real4 p, n, wu, wv;
        vreal a, b;
        vreal t = bvh_leaf_item_t(sc, blk, k, o, d, &p, &n, &wu, &wv, &a, &b);
        if (any)
            *occ = *occ || t < tmax;
        else if (wv.w == (real)ITEM_SPHERE)
            hit_sphere(h, t, t < h->t, (real4)(p.x, p.y, p.z, n.x), o, d, p.w, n.w, wu.w);
        else
            hit_planar(h, t, t < h->t, p, n, wu, wv, a, b);
    }
}

// --- one ray against a wide node and a leaf block, in vectors of 8 ---------
// The box and item tests mirror bvh_enter and the plain loops' tests
// operation for operation, so every walk finds the same hits.

// Entry distances of the ray into the node's 8 boxes (+inf: missed or
// empty). Each axis is entered by the lo plane for a positive direction
// and the hi plane for a negative one (neg): with no zero directions (bvh_safe_inv) the slab ends need no min/max to order them.
INLINE_VEC3 breal8 bvh_node_enter1(const Scene *sc, uint node, real3 o, real3 inv, int3 neg, real tmax)
{
    breal8 lx = bvh_row(sc, node, BVH_LO_X), hx = bvh_row(sc, node, BVH_HI_X);
    breal8 ly = bvh_row(sc, node, BVH_LO_Y), hy = bvh_row(sc, node, BVH_HI_Y);
    breal8 lz = bvh_row(sc, node, BVH_LO_Z), hz = bvh_row(sc, node, BVH_HI_Z);
    // Vector blends on the ray's (fixed) signs, not branches.
    bmask8 mx = (bmask8)(-neg.x), my = (bmask8)(-neg.y), mz = (bmask8)(-neg.z);
    breal8 nx = (select(lx, hx, mx) - o.x) * inv.x, fx = (select(hx, lx, mx) - o.x) * inv.x;
    breal8 ny = (select(ly, hy, my) - o.y) * inv.y, fy = (select(hy, ly, my) - o.y) * inv.y;
    breal8 nz = (select(lz, hz, mz) - o.z) * inv.z, fz = (select(hz, lz, mz) - o.z) * inv.z;
    breal8 tn = max(max(nx, ny), max(nz, (breal8)R(0)));
    breal8 tf = min(min(fx, fy), fz) * R(1 + 4 * REAL_EPS);
    bmask8 hit = tn <= min(tf, (breal8)tmax) && bvh_row(sc, node, BVH_COUNT) >= R(0);
    return select((breal8)R(INFINITY), tn, hit);
}

// 1 / d with zero and tiny components replaced by +-BVH_TINY first, so that
// (box plane - origin) * inverse is never 0 * inf (NaN): a ray in a box's
// face plane counts as inside that slab's side it moves towards.
#define BVH_TINY R(1e-18)
inline real bvh_safe_inv(real x)
{
    return R(1) / (fabs(x) < BVH_TINY ? copysign(BVH_TINY, x) : x);
}

// The leaf block's items against the ray (in rows of BVHL_WIDTH): where one is hit before *tmax,
// *tmax, *best (its PlanarRec) and its coordinates a, b take the nearest.
// Returns whether one was.
INLINE_VEC3 int bvh_leaf1(const Scene *sc, uint blk, real3 o, real3 d, real *tmax, int *best, real *a_out, real *b_out)
{
    lreal px = bvh_lrow(sc, blk, BVHL_PX), py = bvh_lrow(sc, blk, BVHL_PY), pz = bvh_lrow(sc, blk, BVHL_PZ);
    lreal nx = bvh_lrow(sc, blk, BVHL_NX), ny = bvh_lrow(sc, blk, BVHL_NY), nz = bvh_lrow(sc, blk, BVHL_NZ);
    lreal kind = bvh_lrow(sc, blk, BVHL_KIND);
    lreal opx = o.x - px, opy = o.y - py, opz = o.z - pz;
    lreal t = -(opx * nx + opy * ny + opz * nz) / (d.x * nx + d.y * ny + d.z * nz);
    lreal qx = mad((lreal)d.x, t, opx), qy = mad((lreal)d.y, t, opy), qz = mad((lreal)d.z, t, opz);
    lreal a = qx * bvh_lrow(sc, blk, BVHL_UX) + qy * bvh_lrow(sc, blk, BVHL_UY) + qz * bvh_lrow(sc, blk, BVHL_UZ);
    lreal b = qx * bvh_lrow(sc, blk, BVHL_VX) + qy * bvh_lrow(sc, blk, BVHL_VY) + qz * bvh_lrow(sc, blk, BVHL_VZ);
    lmask tri = kind >= R(0) || kind == (real)ITEM_FLAT_TRIANGLE;  // >= 0: a smooth triangle
    lmask in = a >= R(0) && b >= R(0) && ((tri && a + b <= R(1)) || (kind == (real)ITEM_QUAD && a <= R(1) && b <= R(1)));
    lreal tt = select((lreal)R(INFINITY), t, in && t > R(0));
    lmask sph = kind == (real)ITEM_SPHERE;
    if (any(sph)) {
        lreal bb = opx * d.x + opy * d.y + opz * d.z;
        lreal fx = mad((lreal)d.x, -bb, opx), fy = mad((lreal)d.y, -bb, opy), fz = mad((lreal)d.z, -bb, opz);
        lreal r2 = nx * nx;
        lreal disc = r2 - (fx * fx + fy * fy + fz * fz);
        lreal c = (opx * opx + opy * opy + opz * opz) - r2;
        lreal q = -bb - copysign(sqrt(fmax(disc, R(0))), bb);
        lreal t0 = c / q, t1 = q;
        lreal tn = fmin(t0, t1), tf = fmax(t0, t1);
        lreal ts = select(tf, tn, tn > R(0));
        tt = select(tt, select((lreal)R(INFINITY), ts, disc >= R(0) && ts > R(0)), sph);
        a = select(a, (lreal)R(0), sph);
        b = select(b, (lreal)R(0), sph);
    }
    tt = select((lreal)R(INFINITY), tt, tt < *tmax);
    real tmin = LEAF_MIN(tt);
    if (!(tmin < *tmax))
        return 0;
    int k = BVHL_WIDTH - 1;
#pragma unroll
    for (int j = BVHL_WIDTH - 2; j >= 0; j--)
        k = BVH_EL(tt, j) == tmin ? j : k;
    *tmax = tmin;
    *best = (int)(blk << 2) | k;  // the block and slot (blocks are below 2^24 records)
    *a_out = BVH_EL(a, k);
    *b_out = BVH_EL(b, k);
    return 1;
}

// One lane's walk: the nearest item before tmax (its record, or -1) and
// its t and coordinates; any = 1 stops at the first item hit (shadow rays).
INLINE_VEC3 int bvh_walk1(const Scene *sc, real3 o, real3 d, real tmax, int any, real *t_out, real *a_out, real *b_out)
{
    real3 inv = (real3)(bvh_safe_inv(d.x), bvh_safe_inv(d.y), bvh_safe_inv(d.z));
    int3 neg = (int3)(inv.x < R(0), inv.y < R(0), inv.z < R(0));
    uint stack[BVH_STACK];
    real stack_t[BVH_STACK];
    int sp = 0, best = -1;
    uint cur = OFF_BVH;
    for (;;) {
        if (cur & BVH_LEAF_BIT) {
            if (bvh_leaf1(sc, cur & ~BVH_LEAF_BIT, o, d, &tmax, &best, a_out, b_out) && any)
                break;
        } else {
            breal8 tn = bvh_node_enter1(sc, cur, o, inv, neg, tmax);
            // The nearest child and whether any was hit in one reduction: the
            // entry distances' bits (>= 0, so ordered as integers) with the
            // child's index in their lowest three (ties and near-ties go to
            // the lower index; a missed child's +inf stays above every hit;
            // the sign bit is dropped, for a -0 entry distance).
            bkey8 key = (BVH_AS_KEY8(tn) & (bkey8)BVH_KEY_MASK) | BVH_IOTA8;
            __typeof__(key.lo) k4 = min(key.lo, key.hi);
            __typeof__(k4.lo) k2 = min(k4.lo, k4.hi);
            bkeyel kmin = min(k2.x, k2.y);
            if (kmin < BVH_KEY_INF) {
                // Enter the nearest child; push the others hit.
                breal8 ptr = bvh_row(sc, cur, BVH_PTR), cnt = bvh_row(sc, cur, BVH_COUNT);
                uint8 pk = convert_uint8(ptr) | (as_uint8(BVH_I8(cnt > R(0))) & (uint8)BVH_LEAF_BIT);
                int8 hits = -BVH_I8(tn < R(INFINITY));
                int kn = (int)(kmin & 7);
                int4 h4 = hits.lo + hits.hi;
                int2 h2 = h4.lo + h4.hi;
                cur = ((private uint *)&pk)[kn];
                if (h2.x + h2.y > 1) {
#pragma unroll
                    for (int k = 0; k < 8; k++) {
                        stack[sp] = ((private uint *)&pk)[k];
                        stack_t[sp] = BVH_EL(tn, k);
                        sp += ((private int *)&hits)[k] & (k != kn);
                    }
                }
                continue;
            }
        }
        // Pop the next child still nearer than the nearest hit.
        for (;;) {
            if (sp == 0) {
                *t_out = tmax;
                return best;
            }
            sp--;
            if (stack_t[sp] <= tmax)
                break;
        }
        cur = stack[sp];
    }
    *t_out = tmax;
    return best;
}

// Lane l's ray, and its hit written into h.
inline void bvh_lane_closest(const Scene *sc, V3 o, V3 d, Hit *h, int l)
{
    real3 ol = (real3)(VLANE_R(o.x, l), VLANE_R(o.y, l), VLANE_R(o.z, l));
    real3 dl = (real3)(VLANE_R(d.x, l), VLANE_R(d.y, l), VLANE_R(d.z, l));
    real t, a, b;
    int best = bvh_walk1(sc, ol, dl, VLANE_R(h->t, l), 0, &t, &a, &b);
    if (best < 0)
        return;
    real4 p, n, wu, wv;
    bvh_leaf_item(sc, (uint)best >> 2, best & 3, &p, &n, &wu, &wv);
    real3 ng = n.xyz;
    if (wv.w == (real)ITEM_SPHERE) {
        real k = R(1) / n.x;
        ng = (real3)(mad(dl.x, t, ol.x - p.x) * k, mad(dl.y, t, ol.y - p.y) * k, mad(dl.z, t, ol.z - p.z) * k);
    }
    VLANE_R(h->t, l) = t;
    VLANE_R(h->ng.x, l) = ng.x; VLANE_R(h->ng.y, l) = ng.y; VLANE_R(h->ng.z, l) = ng.z;
    VLANE_R(h->mat, l) = p.w;
    VLANE_R(h->light, l) = n.w;
    VLANE_R(h->prim, l) = wu.w;
    VLANE_R(h->bu, l) = a;
    VLANE_R(h->bv, l) = b;
    VLANE_R(h->nrm, l) = wv.w;
    VLANE_R(h->err, l) = wv.w == (real)ITEM_SPHERE ? max_abs4(p) + n.x : max_abs4(p);
}

inline vmask bvh_lanes_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask occ)
{
    for (int l = 0; l < CLPT_LANES; l++) {
        if (VLANE_M(occ, l) != 0)
            continue;
        real3 ol = (real3)(VLANE_R(o.x, l), VLANE_R(o.y, l), VLANE_R(o.z, l));
        real3 dl = (real3)(VLANE_R(d.x, l), VLANE_R(d.y, l), VLANE_R(d.z, l));
        real t, a, b;
        if (bvh_walk1(sc, ol, dl, VLANE_R(tmax, l), 1, &t, &a, &b) >= 0)
            VLANE_M(occ, l) = CLPT_LANES == 1 ? 1 : -1;  // a true mask lane
    }
    return occ;
}

// --- the packet walk: every lane against each child box ----------------------
// One walk for both queries (any: a constant where it is inlined). The
// closest hit (any = 0) tests leaves with the lanes' vector tests into *h and
// enters boxes nearer than h->t; any hit (any = 1) or's the lanes a leaf
// blocks before tmax into *occ, enters boxes only for lanes still open
// (settled lanes take tmax -1) and ends once every lane is settled.
CLPT_INLINE void bvh_packet_walk(const Scene *sc, V3 o, V3 d, int any, Hit *h, vreal tmax, vmask *occ)
{
    V3 inv = v3(R(1) / d.x, R(1) / d.y, R(1) / d.z);
    vreal open_tmax = any ? VSEL(tmax, (vreal)R(-1), *occ) : tmax;
    uint stack[BVH_STACK];
    real stack_t[BVH_STACK];
    int sp = 0;
    uint cur = OFF_BVH;
    for (;;) {
        int go = 0;
        if (cur & BVH_LEAF_BIT) {
            uint blk = cur & ~BVH_LEAF_BIT;
            bvh_leaf_lanes(sc, blk, o, d, any, h, tmax, occ);
            if (any) {
                open_tmax = VSEL(tmax, (vreal)R(-1), *occ);
                if (VALL(*occ))
                    break;
            }
        } else {
            breal8 lx = bvh_row(sc, cur, BVH_LO_X), hx = bvh_row(sc, cur, BVH_HI_X);
            breal8 ly = bvh_row(sc, cur, BVH_LO_Y), hy = bvh_row(sc, cur, BVH_HI_Y);
            breal8 lz = bvh_row(sc, cur, BVH_LO_Z), hz = bvh_row(sc, cur, BVH_HI_Z);
            breal8 ptr = bvh_row(sc, cur, BVH_PTR), cnt = bvh_row(sc, cur, BVH_COUNT);
            breal8 tk8;
#pragma unroll
            for (int k = 0; k < 8; k++) {
                real4 lo = (real4)(BVH_EL(lx, k), BVH_EL(ly, k), BVH_EL(lz, k), R(0));
                real4 hi = (real4)(BVH_EL(hx, k), BVH_EL(hy, k), BVH_EL(hz, k), R(0));
                vreal tk = bvh_enter(lo, hi, o, inv, any ? open_tmax : h->t);
                BVH_EL(tk8, k) = BVH_EL(cnt, k) >= R(0) ? vmin_lane(tk) : R(INFINITY);
            }
            real tmin = bvh_min8(tk8);
            if (tmin < R(INFINITY)) {
                int taken = 0;
                uint next = 0;
#pragma unroll
                for (int k = 0; k < 8; k++) {
                    real tk = BVH_EL(tk8, k);
                    uint p = (uint)BVH_EL(ptr, k) | (BVH_EL(cnt, k) > R(0) ? BVH_LEAF_BIT : 0u);
                    int near = !taken && tk == tmin;
                    next = near ? p : next;
                    taken |= near;
                    stack[sp] = p;
                    stack_t[sp] = tk;
                    sp += !near && tk < R(INFINITY);
                }
                cur = next;
                go = 1;
            }
        }
        if (!go) {
            if (sp == 0)
                break;
            cur = stack[--sp];
        }
    }
}

inline void bvh_packet_closest(const Scene *sc, V3 o, V3 d, Hit *h)
{
    vmask none = (vreal)R(0) != (vreal)R(0);
    bvh_packet_walk(sc, o, d, 0, h, (vreal)R(0), &none);
}

inline vmask bvh_packet_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask occ)
{
    bvh_packet_walk(sc, o, d, 1, 0, tmax, &occ);
    return occ;
}

// Whether every lane is active and starts at one point (camera rays after
// all lanes restarted together): then the packet walk pays.
inline int bvh_coherent(V3 o, vmask active)
{
#if CLPT_LANES == 1
    return 0;
#else
    vmask same = o.x == (vreal)VLANE_R(o.x, 0) && o.y == (vreal)VLANE_R(o.y, 0) && o.z == (vreal)VLANE_R(o.z, 0);
    return VALL(active && same);
#endif
}

// Closest hits of the active lanes (the others' h is left as it is).
void bvh_closest(const Scene *sc, V3 o, V3 d, Hit *h, vmask active)
{
#if CLPT_BVH_PACKETS
    if (bvh_coherent(o, active)) {
        bvh_packet_closest(sc, o, d, h);
        return;
    }
#endif
    for (int l = 0; l < CLPT_LANES; l++)
        if (VLANE_M(active, l) != 0)
            bvh_lane_closest(sc, o, d, h, l);
}

vmask bvh_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask occ)
{
#if CLPT_BVH_PACKETS
    if (bvh_coherent(o, !occ))
        return bvh_packet_occluded(sc, o, d, tmax, occ);
#endif
    return bvh_lanes_occluded(sc, o, d, tmax, occ);
}
