"""Bounding volume hierarchies over primitive boxes, built on the host in numpy.

Two builders share one level-by-level frame (every node of a level is split
in one set of vectorized array operations, so the Python loop runs once per
level, not once per node):

  "sah"   binned surface-area heuristic: 16 bins of centroids per axis and
          node, the split of least expected cost (Wald 2007), for nodes of
          more than SAH_MIN primitives; smaller ones split as in "lbvh";
  "lbvh"  linear BVH: primitives sorted once along a 63-bit Morton curve of
          their centroids, each node split where its codes' highest
          differing bit changes (Karras 2012's hierarchy, built top-down).

``build`` returns a ``Tree``: nodes in breadth-first order, each a range of
``order`` (the primitive permutation), with its box and children, leaves
of at most LEAF_SIZE (4) primitives. ``collapse`` turns the binary tree
into WIDTH-ary (8) nodes, opening the largest child first (as Embree's and
pbrt's wide BVHs do), and ``flatten`` and ``leaf_blocks`` into the device
records of clpt/layout.py's BVH_NODE (8 children's boxes as rows of 8
reals, which kernels/bvh.h tests against one ray in one vector operation)
and BVH_LEAF (up to 4 items' records as rows of 4 reals, tested likewise).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from . import layout

METHODS = ("sah", "lbvh")
BINS = 16
SAH_MIN = 64        # smaller nodes take the Morton split (binning them costs more than it gains)
MAX_LEAF = 4        # a node with more primitives is always split (a device leaf block holds 4)
LEAF_SIZE = 4       # the default leaf bound
MAX_DEPTH = 64       # the binary tree's depth bound
MAX_STACK = 96       # entries of the kernels' traversal stack (BVH_STACK in kernels/bvh.h)
SAH_TRAVERSAL = 1.0  # cost of visiting a node, relative to one primitive test


@dataclass
class Tree:
    order: np.ndarray   # primitive index of each leaf slot
    start: np.ndarray   # node -> first slot
    count: np.ndarray   # node -> slots
    left: np.ndarray    # node -> left child (-1: leaf); right child = left + 1
    lo: np.ndarray      # node boxes (n_nodes, 3)
    hi: np.ndarray
    seconds: float = 0.0

    @property
    def n_nodes(self) -> int:
        return len(self.start)

    @property
    def n_leaves(self) -> int:
        return int((self.left < 0).sum())

    levels: int = 1

    def depth(self) -> int:
        """Edges from the root to the deepest leaf (nodes are built level by level)."""
        return self.levels - 1

    def sah_cost(self) -> float:
        """Expected cost of a random ray through the root (SAH units)."""
        ext = np.maximum(self.hi - self.lo, 0)
        area = ext[:, 0] * ext[:, 1] + ext[:, 1] * ext[:, 2] + ext[:, 0] * ext[:, 2]
        leaf = self.left < 0
        return float((area[~leaf].sum() * SAH_TRAVERSAL + (area[leaf] * self.count[leaf]).sum()) / area[0])


def _segments(a, starts, counts, op):
    """op.reduce of a over each range [start, start + count) (counts > 0;
    ranges in increasing, disjoint order)."""
    idx = np.empty(2 * len(starts), dtype=np.int64)
    idx[0::2] = starts
    idx[1::2] = starts + counts
    pad = np.concatenate([a, a[:1]])  # the end index of the last range may be len(a)
    return op.reduceat(pad, idx, axis=0)[0::2]


def _morton(c, lo, hi):
    """63-bit Morton codes (21 bits per axis) of points c in the box lo..hi."""
    ext = np.where(hi > lo, hi - lo, 1.0)
    q = np.clip(((c - lo) / ext * (1 << 21)).astype(np.int64), 0, (1 << 21) - 1).astype(np.uint64)
    out = np.zeros(len(c), dtype=np.uint64)
    for axis in range(3):
        v = q[:, axis]
        v = (v | (v << np.uint64(32))) & np.uint64(0x1F00000000FFFF)
        v = (v | (v << np.uint64(16))) & np.uint64(0x1F0000FF0000FF)
        v = (v | (v << np.uint64(8))) & np.uint64(0x100F00F00F00F00F)
        v = (v | (v << np.uint64(4))) & np.uint64(0x10C30C30C30C30C3)
        v = (v | (v << np.uint64(2))) & np.uint64(0x1249249249249249)
        out |= v << np.uint64(2 - axis)
    return out


def _area(ext):
    ext = np.maximum(ext, 0)
    return ext[..., 0] * ext[..., 1] + ext[..., 1] * ext[..., 2] + ext[..., 0] * ext[..., 2]


def _sah_splits(cen, lo, hi, starts, counts, node_lo, node_hi):
    """For each node (range): the cost of its best binned-SAH split (inf if
    none), each of its primitives' side (True: right), their slots and nodes."""
    m = len(starts)
    nid = np.repeat(np.arange(m), counts)
    sl = np.repeat(starts - np.concatenate([[0], np.cumsum(counts)[:-1]]), counts) + np.arange(counts.sum())
    c = cen[sl]
    cmin = _segments(cen, starts, counts, np.minimum)
    cmax = _segments(cen, starts, counts, np.maximum)
    ext = cmax - cmin
    scale = np.where(ext > 0, BINS * (1 - 1e-9) / np.where(ext > 0, ext, 1), 0.0)
    b = np.clip(((c - cmin[nid]) * scale[nid]).astype(np.int64), 0, BINS - 1)
    plo, phi = lo[sl], hi[sl]
    best_cost = np.full(m, np.inf)
    best_axis = np.zeros(m, dtype=np.int64)
    best_bin = np.ones(m, dtype=np.int64)
    for axis in range(3):
        key = nid * BINS + b[:, axis]
        cnt = np.bincount(key, minlength=m * BINS).reshape(m, BINS)
        blo = np.full((m * BINS, 3), np.inf)
        bhi = np.full((m * BINS, 3), -np.inf)
        for k in range(3):
            np.minimum.at(blo[:, k], key, plo[:, k])
            np.maximum.at(bhi[:, k], key, phi[:, k])
        blo, bhi = blo.reshape(m, BINS, 3), bhi.reshape(m, BINS, 3)
        # Left: bins < j; right: bins >= j, for j = 1 .. BINS-1.
        llo = np.minimum.accumulate(blo, axis=1)[:, :-1]
        lhi = np.maximum.accumulate(bhi, axis=1)[:, :-1]
        rlo = np.minimum.accumulate(blo[:, ::-1], axis=1)[:, ::-1][:, 1:]
        rhi = np.maximum.accumulate(bhi[:, ::-1], axis=1)[:, ::-1][:, 1:]
        nl = np.cumsum(cnt, axis=1)[:, :-1]
        nr = counts[:, None] - nl
        with np.errstate(invalid="ignore"):
            cost = np.where(nl > 0, _area(lhi - llo) * nl, 0) + np.where(nr > 0, _area(rhi - rlo) * nr, 0)
        cost = np.where((nl > 0) & (nr > 0), cost, np.inf)
        j = np.argmin(cost, axis=1)
        cj = cost[np.arange(m), j]
        better = cj < best_cost
        best_cost = np.where(better, cj, best_cost)
        best_axis = np.where(better, axis, best_axis)
        best_bin = np.where(better, j + 1, best_bin)
    parent = _area(node_hi - node_lo)
    with np.errstate(invalid="ignore", divide="ignore"):
        cost = SAH_TRAVERSAL + best_cost / np.where(parent > 0, parent, 1)
    side = b[np.arange(len(sl)), best_axis[nid]] >= best_bin[nid]
    return cost, side, sl, nid


def build(lo, hi, method: str = "sah", max_leaf: int | None = None) -> Tree:
    """BVH over the boxes lo[i]..hi[i] (float64 (N, 3)); leaves of at most
    max_leaf (default LEAF_SIZE) primitives."""
    max_leaf = LEAF_SIZE if max_leaf is None else max_leaf
    if method not in METHODS:
        raise ValueError(f"BVH method must be one of {', '.join(METHODS)} (got {method!r})")
    t0 = time.perf_counter()
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    n = len(lo)
    cen = 0.5 * (lo + hi)
    codes = _morton(cen, cen.min(0), cen.max(0))
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    lo, hi, cen = lo[order], hi[order], cen[order]

    starts, counts, lefts = [np.array([0])], [np.array([n])], []
    level_s, level_c = starts[0], counts[0]
    next_id = 1
    while len(level_s):
        split = level_c > max_leaf
        s, c = level_s[split], level_c[split]
        left = np.full(len(level_s), -1, dtype=np.int64)
        if len(s):
            keep = np.ones(len(s), dtype=bool)
            lc = np.empty(len(s), dtype=np.int64)
            big = (c > SAH_MIN) if method == "sah" else np.zeros(len(s), dtype=bool)
            if big.any():
                sb, cb = s[big], c[big]
                node_lo = _segments(lo, sb, cb, np.minimum)
                node_hi = _segments(hi, sb, cb, np.maximum)
                cost, side, sl, nid = _sah_splits(cen, lo, hi, sb, cb, node_lo, node_hi)
                no_split = ~np.isfinite(cost)  # all centroids in one bin: split at the middle
                nr = np.bincount(nid, weights=side, minlength=len(sb)).astype(np.int64)
                # Stable partition within each range, left side first (which
                # keeps each side in Morton order for the splits below).
                rank_l = np.cumsum(~side) - 1
                rank_r = np.cumsum(side) - 1
                base_l = np.concatenate([[0], np.cumsum(cb - nr)[:-1]])
                base_r = np.concatenate([[0], np.cumsum(nr)[:-1]])
                pos = np.where(side, sb[nid] + (cb - nr)[nid] + rank_r - base_r[nid],
                               sb[nid] + rank_l - base_l[nid])
                dest = np.where(no_split[nid], sl, pos)
                for arr in (lo, hi, cen, codes, order):
                    arr[dest] = arr[sl].copy()
                lc[big] = np.where(no_split, cb // 2, cb - nr)
            small = ~big
            if small.any():
                # Morton split: where the node's codes' highest differing bit
                # changes (its codes are sorted), or the middle if all equal.
                ss, cs = s[small], c[small]
                first, last = codes[ss], codes[ss + cs - 1]
                diff = first ^ last
                with np.errstate(over="ignore"):
                    hb = np.floor(np.log2(np.where(diff > 0, diff, 1).astype(np.float64))).astype(np.int64)
                # float64 log2 of a 63-bit value may round up past the bit: correct it.
                hb = np.where((diff >> hb.astype(np.uint64)) == 0, hb - 1, hb)
                nid = np.repeat(np.arange(len(ss)), cs)
                sl = np.repeat(ss - np.concatenate([[0], np.cumsum(cs)[:-1]]), cs) + np.arange(cs.sum())
                zero = ((codes[sl] >> hb[nid].astype(np.uint64)) & np.uint64(1)) == 0
                n0 = np.bincount(nid, weights=zero, minlength=len(ss)).astype(np.int64)
                lc[small] = np.clip(np.where(diff > 0, n0, cs // 2), 1, cs - 1)
            ls, rs, rc = s, s + lc, c - lc
            idx = np.flatnonzero(split)[keep]
            ls, lc, rs, rc = ls[keep], lc[keep], rs[keep], rc[keep]
            left[idx] = next_id + 2 * np.arange(len(idx))
            next_id += 2 * len(idx)
            ns = np.empty(2 * len(idx), dtype=np.int64)
            nc = np.empty(2 * len(idx), dtype=np.int64)
            ns[0::2], ns[1::2], nc[0::2], nc[1::2] = ls, rs, lc, rc
        else:
            ns = nc = np.zeros(0, dtype=np.int64)
        lefts.append(left)
        starts.append(ns)
        counts.append(nc)
        level_s, level_c = ns, nc
    start = np.concatenate(starts)
    count = np.concatenate(counts)
    left_all = np.concatenate(lefts)
    # Boxes bottom-up: the leaves' from their primitives in one pass (leaves
    # tile the slots), then each level's inner nodes from their children.
    nlo = np.empty((len(start), 3))
    nhi = np.empty((len(start), 3))
    leaf = np.flatnonzero(left_all < 0)
    leaf = leaf[np.argsort(start[leaf], kind="stable")]
    nlo[leaf] = np.minimum.reduceat(lo, start[leaf], axis=0)
    nhi[leaf] = np.maximum.reduceat(hi, start[leaf], axis=0)
    ends = np.cumsum([len(x) for x in starts])
    for k in range(len(starts) - 1, -1, -1):
        ids = np.arange(ends[k] - len(starts[k]), ends[k])
        ids = ids[left_all[ids] >= 0]
        if len(ids):
            lc = left_all[ids]
            nlo[ids] = np.minimum(nlo[lc], nlo[lc + 1])
            nhi[ids] = np.maximum(nhi[lc], nhi[lc + 1])
    return Tree(order=order, start=start, count=count, left=left_all, lo=nlo, hi=nhi,
                seconds=time.perf_counter() - t0, levels=sum(1 for x in starts if len(x)))


WIDTH = 8            # children per device node (kernels/bvh.h tests them in one vector)


@dataclass
class Wide:
    """The binary tree collapsed to WIDTH-ary nodes: children[w] are binary
    node ids (-1: an empty slot); wide node 0 is the root."""
    children: np.ndarray   # (n_wide, WIDTH) int64
    levels: int = 1

    @property
    def n_nodes(self) -> int:
        return len(self.children)


def collapse(tree: Tree, width: int = WIDTH) -> Wide:
    """Greedy collapse (as Embree's and pbrt's wide BVHs): each wide node
    starts from a binary node's two children and repeatedly opens its
    largest-area inner child until it has `width` children. All wide nodes
    of a level are opened together in array operations."""
    left = tree.left
    if left[0] < 0:
        ch = np.full((1, width), -1, dtype=np.int64)
        ch[0, 0] = 0
        return Wide(ch)
    area = _area(tree.hi - tree.lo)
    is_inner = left >= 0
    frontier = np.array([0])
    levels = []
    while len(frontier):
        m = len(frontier)
        rows = np.arange(m)
        ch = np.full((m, width), -1, dtype=np.int64)
        ch[:, 0], ch[:, 1] = left[frontier], left[frontier] + 1
        n = np.full(m, 2)
        for _ in range(width - 2):
            c = np.maximum(ch, 0)
            a = np.where((ch >= 0) & is_inner[c], area[c], -1.0)
            j = np.argmax(a, axis=1)
            ok = a[rows, j] >= 0
            if not ok.any():
                break
            r, jj = rows[ok], j[ok]
            opened = ch[r, jj]
            ch[r, jj] = left[opened]
            ch[r, n[ok]] = left[opened] + 1
            n = n + ok
        levels.append(ch)
        c = np.maximum(ch, 0)
        frontier = ch[(ch >= 0) & is_inner[c]]
    return Wide(np.concatenate(levels), levels=len(levels))


def stack_need(wide: Wide) -> int:
    """Most entries the kernels' walk can have on its stack: every wide
    level on the way down leaves at most WIDTH - 1 children behind."""
    return (WIDTH - 1) * wide.levels + 1


def flatten(tree: Tree, wide: Wide, node_base: int, leaf_base: int, double: bool):
    """Device records of the wide nodes, (n_wide * BVH_NODE.stride, 4)
    float64 rows (clpt/layout.py BVH_NODE, filled by field name: per child
    slot lo.x, hi.x, lo.y, hi.y, lo.z, hi.z, pointer, count), and the leaves
    in block order. A child's pointer is an absolute real4 index: of its
    wide node (count 0) or of its leaf block (count > 0 items); count -1
    marks an empty slot. Leaf blocks are numbered in leaf order
    (tree.start). Boxes are rounded outwards to the kernel's precision."""
    ch = wide.children
    n_wide, width = ch.shape
    left = tree.left
    leaves = np.flatnonzero(left < 0)
    leaves = leaves[np.argsort(tree.start[leaves], kind="stable")]
    leaf_id = np.full(tree.n_nodes, -1, dtype=np.int64)
    leaf_id[leaves] = np.arange(len(leaves))
    wide_id = np.full(tree.n_nodes, -1, dtype=np.int64)
    if left[0] >= 0:
        inner_children = ch[(ch >= 0) & (left[np.maximum(ch, 0)] >= 0)]
        wide_id[0] = 0
        wide_id[inner_children] = 1 + np.arange(len(inner_children))
    lo, hi = _outward(tree.lo, tree.hi, double)
    valid = ch >= 0
    c = np.maximum(ch, 0)
    is_leaf = left[c] < 0
    ptr = np.where(is_leaf, leaf_base + layout.BVH_LEAF.stride * leaf_id[c],
                   node_base + layout.BVH_NODE.stride * wide_id[c])
    cnt = np.where(is_leaf, tree.count[c], 0)
    out = layout.BVH_NODE.zeros(n_wide)
    for axis, name in enumerate("xyz"):
        out[f"lo_{name}"] = np.where(valid, lo[c, axis], 0.0)
        out[f"hi_{name}"] = np.where(valid, hi[c, axis], 0.0)
    out["ptr"] = np.where(valid, ptr, 0)
    out["count"] = np.where(valid, cnt, -1)
    return layout.Rows.rows(out), leaves


def leaf_blocks(tree: Tree, leaves, items, width: int = MAX_LEAF):
    """SoA leaf blocks, (n_leaves * BVH_LEAF.stride, 4) float64 rows, of the
    leaves (in the order given) over items, the PLANAR records (structured,
    clpt/layout.py) in tree slot order: per item slot, its corner p.xyz,
    normal n.xyz, duals wu.xyz and wv.xyz, kind (wv.w), material (p.w),
    light + 1 (n.w) and primitive id (wu.w), by field name; empty slots have
    kind ITEM_EMPTY and zeros elsewhere."""
    start, count = tree.start[leaves], tree.count[leaves]
    if len(count) and count.max() > width:
        raise ValueError(f"a BVH leaf has {count.max()} items, more than {width}")
    k = np.arange(width)
    slot = start[:, None] + k[None, :]
    valid = k[None, :] < count[:, None]
    g = items[np.where(valid, slot, 0)]          # (leaves, width) PLANAR records
    out = layout.BVH_LEAF.zeros(len(leaves))
    for src, dst in (("corner_mat", "p"), ("n_light", "n"), ("wu_prim", "u"), ("wv_kind", "v")):
        for axis, name in enumerate("xyz"):
            out[dst + name] = g[src][..., axis] * valid
    for src, dst in (("wv_kind", "kind"), ("corner_mat", "mat"), ("n_light", "light"), ("wu_prim", "prim")):
        out[dst] = g[src][..., 3] * valid
    out["kind"] = np.where(valid, out["kind"], layout.ITEM_EMPTY)
    return layout.Rows.rows(out)


def _outward(lo, hi, double):
    """Boxes rounded outwards to float32 (conservative), or kept for double."""
    if double:
        return lo, hi
    lo32, hi32 = lo.astype(np.float32), hi.astype(np.float32)
    lo32 = np.where(lo32 > lo, np.nextafter(lo32, np.float32(-np.inf)), lo32)
    hi32 = np.where(hi32 < hi, np.nextafter(hi32, np.float32(np.inf)), hi32)
    return lo32.astype(np.float64), hi32.astype(np.float64)
