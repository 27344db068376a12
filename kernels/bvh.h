// bvh.h: closest-hit and shadow queries through the scene's BVH.
//
// Layout (clpt/layout.py BvhNode, built by clpt/bvh.py, packed by
// clpt/pack.py): a node holds both children's boxes, lo.xyz | hi.xyz, with a
// pointer in lo.w and a count in hi.w: count > 0 is a leaf of that many
// items (PlanarRec each, spheres among them) from record pointer, 0 an inner
// node at record pointer, -1 no child (a root that is a single leaf). The
// root is the node at OFF_BVH.
//
// Two walks (CLPT_BVH_LANE_WALK chooses; README "BVH" has the measurements):
//   packet (0)  all CLPT_LANES rays of the work-item walk the tree together:
//               each node's two boxes are tested against every lane at once,
//               a child is entered if any lane enters it, the nearer first
//               (by the smallest entry distance among the lanes); a leaf's
//               items get the lanes' vector tests of the plain loops.
//   per lane (1) each lane's ray walks alone in scalar code with its own
//               stack, nearer child first; tests mirror the vector ones.
// The stack holds at most the tree's depth, which the host bounds.

#define BVH_STACK 64

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

// Smallest lane, by halving the vector (no trip through memory).
#if CLPT_DOUBLE
#define BVH_RN(n) CLPT_CAT(double, n)
#else
#define BVH_RN(n) CLPT_CAT(float, n)
#endif
inline real bvh_min_lane(vreal v)
{
#if CLPT_LANES == 1
    return v;
#elif CLPT_LANES == 2
    return fmin(v.x, v.y);
#elif CLPT_LANES == 4
    BVH_RN(2) a = fmin(v.lo, v.hi);
    return fmin(a.x, a.y);
#elif CLPT_LANES == 8
    BVH_RN(4) a = fmin(v.lo, v.hi);
    BVH_RN(2) b = fmin(a.lo, a.hi);
    return fmin(b.x, b.y);
#else
    BVH_RN(8) a = fmin(v.lo, v.hi);
    BVH_RN(4) b = fmin(a.lo, a.hi);
    BVH_RN(2) c = fmin(b.lo, b.hi);
    return fmin(c.x, c.y);
#endif
}

// Closest hits among a leaf's items, into h.
inline void bvh_leaf_closest(const Scene *sc, uint first, uint count, V3 o, V3 d, Hit *h)
{
    for (uint k = 0; k < count; k++) {
        uint r = first + PLANAR_STRIDE * k;
        real4 p = scene_rec(sc, r), n = scene_rec(sc, r + 1), wu = scene_rec(sc, r + 2), wv = scene_rec(sc, r + 3);
        if (wv.w == (real)ITEM_SPHERE) {
            real4 cr = (real4)(p.x, p.y, p.z, n.x);
            vreal t = intersect_sphere(cr, o, d);
            hit_sphere(h, t, t < h->t, cr, o, d, p.w, n.w, wu.w);
        } else {
            vreal a, b;
            vreal t = intersect_planar_recs(p, n, wu, wv, o, d, wv.w != (real)ITEM_QUAD, &a, &b);
            hit_planar(h, t, t < h->t, p, n, wu, wv, a, b);
        }
    }
}

// Lanes among !occ that a leaf's items block before tmax, or'ed into occ.
inline vmask bvh_leaf_occluded(const Scene *sc, uint first, uint count, V3 o, V3 d, vreal tmax, vmask occ)
{
    for (uint k = 0; k < count; k++) {
        uint r = first + PLANAR_STRIDE * k;
        real4 p = scene_rec(sc, r), n = scene_rec(sc, r + 1), wu = scene_rec(sc, r + 2), wv = scene_rec(sc, r + 3);
        vreal t;
        if (wv.w == (real)ITEM_SPHERE) {
            t = intersect_sphere((real4)(p.x, p.y, p.z, n.x), o, d);
        } else {
            vreal a, b;
            t = intersect_planar_recs(p, n, wu, wv, o, d, wv.w != (real)ITEM_QUAD, &a, &b);
        }
        occ = occ || t < tmax;
    }
    return occ;
}

// The walk shared by both queries. LEAF(first, count) tests a leaf; TMAX is
// the per-lane distance beyond which boxes are not entered (lanes with
// nothing left to find have it at -1); DONE ends the walk early.
#define BVH_WALK(TMAX, LEAF, DONE)                                                                  \
    V3 inv = v3(R(1) / d.x, R(1) / d.y, R(1) / d.z);                                                \
    uint stack[BVH_STACK];                                                                          \
    int sp = 0;                                                                                     \
    uint node = OFF_BVH;                                                                            \
    for (;;) {                                                                                      \
        real4 l0 = scene_rec(sc, node), l1 = scene_rec(sc, node + 1);                               \
        real4 r0 = scene_rec(sc, node + 2), r1 = scene_rec(sc, node + 3);                           \
        vreal tl = bvh_enter(l0, l1, o, inv, TMAX);                                                 \
        vreal tr = r1.w >= R(0) ? bvh_enter(r0, r1, o, inv, TMAX) : (vreal)R(INFINITY);            \
        int hl = VANY(tl < R(INFINITY)), hr = VANY(tr < R(INFINITY));                               \
        if (hl && l1.w > R(0)) { LEAF((uint)l0.w, (uint)l1.w); hl = 0; if (DONE) break; }          \
        if (hr && r1.w > R(0)) { LEAF((uint)r0.w, (uint)r1.w); hr = 0; if (DONE) break; }          \
        if (hl && hr) {                                                                             \
            int right_first = bvh_min_lane(tr) < bvh_min_lane(tl);                                  \
            stack[sp++] = right_first ? (uint)l0.w : (uint)r0.w;                                    \
            node = right_first ? (uint)r0.w : (uint)l0.w;                                           \
        } else if (hl) {                                                                            \
            node = (uint)l0.w;                                                                      \
        } else if (hr) {                                                                            \
            node = (uint)r0.w;                                                                      \
        } else {                                                                                    \
            if (sp == 0) break;                                                                     \
            node = stack[--sp];                                                                     \
        }                                                                                           \
    }

#if !CLPT_BVH_LANE_WALK
void bvh_closest(const Scene *sc, V3 o, V3 d, Hit *h)
{
#define BVH_LEAF_CLOSEST(first, count) bvh_leaf_closest(sc, first, count, o, d, h)
    BVH_WALK(h->t, BVH_LEAF_CLOSEST, 0)
#undef BVH_LEAF_CLOSEST
}

vmask bvh_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask occ)
{
    vreal tm = VSEL(tmax, (vreal)R(-1), occ);
#define BVH_LEAF_OCCLUDED(first, count) \
    do { occ = bvh_leaf_occluded(sc, first, count, o, d, tmax, occ); tm = VSEL(tmax, (vreal)R(-1), occ); } while (0)
    BVH_WALK(tm, BVH_LEAF_OCCLUDED, VALL(occ))
#undef BVH_LEAF_OCCLUDED
    return occ;
}

#else
// --- per-lane walk: each lane's ray in scalar code with its own stack ----------
// The scalar tests mirror the vector ones operation for operation, so both
// walks find the same hits.
inline real bvh_enter1(real4 lo, real4 hi, real3 o, real3 inv, real tmax)
{
    real x0 = (lo.x - o.x) * inv.x, x1 = (hi.x - o.x) * inv.x;
    real y0 = (lo.y - o.y) * inv.y, y1 = (hi.y - o.y) * inv.y;
    real z0 = (lo.z - o.z) * inv.z, z1 = (hi.z - o.z) * inv.z;
    real tn = fmax(fmax(fmin(x0, x1), fmin(y0, y1)), fmax(fmin(z0, z1), R(0)));
    real tf = fmin(fmin(fmax(x0, x1), fmax(y0, y1)), fmax(z0, z1)) * R(1 + 4 * REAL_EPS);
    return tn <= fmin(tf, tmax) ? tn : R(INFINITY);
}

inline real intersect_item1(real4 p, real4 n, real4 wu, real4 wv, real3 o, real3 d, real *a_out, real *b_out)
{
    *a_out = *b_out = R(0);
    if (wv.w == (real)ITEM_SPHERE) {
        real3 oc = (real3)(o.x - p.x, o.y - p.y, o.z - p.z);
        real b = oc.x * d.x + oc.y * d.y + oc.z * d.z;
        real3 f = (real3)(mad(d.x, -b, oc.x), mad(d.y, -b, oc.y), mad(d.z, -b, oc.z));
        real r2 = n.x * n.x;
        real disc = r2 - (f.x * f.x + f.y * f.y + f.z * f.z);
        real c = (oc.x * oc.x + oc.y * oc.y + oc.z * oc.z) - r2;
        real q = -b - copysign(sqrt(fmax(disc, R(0))), b);
        real t0 = c / q, t1 = q;
        real tn = fmin(t0, t1), tf = fmax(t0, t1);
        real t = tn > R(0) ? tn : tf;
        return disc >= R(0) && t > R(0) ? t : R(INFINITY);
    }
    real3 op = (real3)(o.x - p.x, o.y - p.y, o.z - p.z);
    real t = -(op.x * n.x + op.y * n.y + op.z * n.z) / (d.x * n.x + d.y * n.y + d.z * n.z);
    real3 q = (real3)(mad(d.x, t, op.x), mad(d.y, t, op.y), mad(d.z, t, op.z));
    real a = q.x * wu.x + q.y * wu.y + q.z * wu.z, b = q.x * wv.x + q.y * wv.y + q.z * wv.z;
    int in = wv.w != (real)ITEM_QUAD ? (a >= R(0) && b >= R(0) && a + b <= R(1))
                                     : (a >= R(0) && b >= R(0) && a <= R(1) && b <= R(1));
    *a_out = a;
    *b_out = b;
    return in && t > R(0) ? t : R(INFINITY);
}

// One lane's walk: the nearest item before tmax (its record, or -1) and
// its t and coordinates; any = 1 stops at the first item hit (shadow rays).
inline int bvh_walk1(const Scene *sc, real3 o, real3 d, real tmax, int any, real *t_out, real *a_out, real *b_out)
{
    real3 inv = (real3)(R(1) / d.x, R(1) / d.y, R(1) / d.z);
    uint stack[BVH_STACK];
    int sp = 0, best = -1;
    uint node = OFF_BVH;
    for (;;) {
        real4 l0 = scene_rec(sc, node), l1 = scene_rec(sc, node + 1);
        real4 r0 = scene_rec(sc, node + 2), r1 = scene_rec(sc, node + 3);
        real tl = bvh_enter1(l0, l1, o, inv, tmax);
        real tr = r1.w >= R(0) ? bvh_enter1(r0, r1, o, inv, tmax) : R(INFINITY);
        int hl = tl < R(INFINITY), hr = tr < R(INFINITY);
        for (int side = 0; side < 2; side++) {
            real4 c0 = side ? r0 : l0, c1 = side ? r1 : l1;
            if (!(side ? hr : hl) || c1.w <= R(0))
                continue;
            for (uint k = 0; k < (uint)c1.w; k++) {
                uint r = (uint)c0.w + PLANAR_STRIDE * k;
                real a, b;
                real t = intersect_item1(scene_rec(sc, r), scene_rec(sc, r + 1), scene_rec(sc, r + 2),
                                         scene_rec(sc, r + 3), o, d, &a, &b);
                if (t < tmax) {
                    tmax = t; best = (int)r; *a_out = a; *b_out = b;
                    if (any) { *t_out = t; return best; }
                }
            }
            if (side) hr = 0; else hl = 0;
        }
        if (hl && hr) {
            int right_first = tr < tl;
            stack[sp++] = right_first ? (uint)l0.w : (uint)r0.w;
            node = right_first ? (uint)r0.w : (uint)l0.w;
        } else if (hl) {
            node = (uint)l0.w;
        } else if (hr) {
            node = (uint)r0.w;
        } else {
            if (sp == 0) break;
            node = stack[--sp];
        }
    }
    *t_out = tmax;
    return best;
}

void bvh_closest(const Scene *sc, V3 o, V3 d, Hit *h)
{
    for (int l = 0; l < CLPT_LANES; l++) {
        real3 ol = (real3)(VLANE_R(o.x, l), VLANE_R(o.y, l), VLANE_R(o.z, l));
        real3 dl = (real3)(VLANE_R(d.x, l), VLANE_R(d.y, l), VLANE_R(d.z, l));
        real t, a, b;
        int best = bvh_walk1(sc, ol, dl, VLANE_R(h->t, l), 0, &t, &a, &b);
        if (best < 0)
            continue;
        uint r = (uint)best;
        real4 p = scene_rec(sc, r), n = scene_rec(sc, r + 1), wu = scene_rec(sc, r + 2), wv = scene_rec(sc, r + 3);
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
    }
}

vmask bvh_occluded(const Scene *sc, V3 o, V3 d, vreal tmax, vmask occ)
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
#endif
