// grid.cl: builds the photon map's hash grid on the device (photon_grid.h).
//
// From: trace_photons' slots (ph_pos.w = 1 for a stored photon).
//   photon_keys      one work-item per slot: key = hash bucket of the
//                    photon's cell, or table_size for an empty slot (sorts last)
//   radix_histogram  one work-item per chunk of slots: digit counts, in order
//   radix_offsets    one work-item: exclusive prefix over (digit, chunk)
//   radix_scatter    one work-item per chunk, walking it in order: a stable
//                    LSD radix sort of (key, slot) pairs, 8 bits a pass
//   photon_permute   one work-item per slot: photons into key order
//   bucket_starts    one work-item per slot and one more: index of each
//                    bucket's first photon (bucket_start, table size + 1)
//   photon_occupancy one work-item per slot: the occupancy bits (below)
// To: sorted ph_pos/ph_dir/ph_pow, bucket_start and the occupancy bits, read
// by photon_gather.
// Every step is deterministic (no atomics decide an order), so a photon map
// and the images gathered from it are the same bits every time.

#define RADIX 256

__kernel void photon_keys(__global const float4 *ph_pos, uint n, real inv_cell, uint mask,
                          __global uint *keys, __global uint *vals)
{
    uint i = get_global_id(0);
    if (i >= n)
        return;
    float4 p = ph_pos[i];
    keys[i] = p.w != 0.0f ? grid_bucket(grid_cell(REAL3(p.xyz), inv_cell), mask) : mask + 1u;
    vals[i] = i;
}

__kernel void radix_histogram(__global const uint *keys, uint n, uint shift, uint chunk, __global uint *hist)
{
    uint c = get_global_id(0);
    uint h[RADIX];
    for (int d = 0; d < RADIX; d++)
        h[d] = 0;
    uint begin = c * chunk, end = min(n, begin + chunk);
    for (uint i = begin; i < end; i++)
        h[(keys[i] >> shift) & (RADIX - 1)]++;
    for (int d = 0; d < RADIX; d++)
        hist[c * RADIX + d] = h[d];
}

__kernel void radix_offsets(__global uint *hist, uint n_chunks)
{
    if (get_global_id(0) != 0)
        return;
    uint running = 0;
    for (uint d = 0; d < RADIX; d++)
        for (uint c = 0; c < n_chunks; c++) {
            uint t = hist[c * RADIX + d];
            hist[c * RADIX + d] = running;
            running += t;
        }
}

__kernel void radix_scatter(__global const uint *keys, __global const uint *vals, uint n, uint shift, uint chunk,
                            __global const uint *offsets, __global uint *keys_out, __global uint *vals_out)
{
    uint c = get_global_id(0);
    uint o[RADIX];
    for (int d = 0; d < RADIX; d++)
        o[d] = offsets[c * RADIX + d];
    uint begin = c * chunk, end = min(n, begin + chunk);
    for (uint i = begin; i < end; i++) {
        uint k = keys[i];
        uint at = o[(k >> shift) & (RADIX - 1)]++;
        keys_out[at] = k;
        vals_out[at] = vals[i];
    }
}

__kernel void photon_permute(__global const uint *vals, uint n, __global const float4 *pos,
                             __global const float4 *dir, __global const float4 *pow,
                             __global float4 *pos_out, __global float4 *dir_out, __global float4 *pow_out)
{
    uint i = get_global_id(0);
    if (i >= n)
        return;
    uint j = vals[i];
    pos_out[i] = pos[j];
    dir_out[i] = dir[j];
    pow_out[i] = pow[j];
}

__kernel void bucket_starts(__global const uint *keys, uint n, uint mask, __global uint *bucket_start)
{
    // Work-item i (0..n) fills bucket_start for the buckets from just after
    // slot i-1's key up to slot i's key (slot n and empty slots: the table
    // size), so every bucket, empty or not, gets the index of its first photon.
    uint i = get_global_id(0);
    if (i > n)
        return;
    uint table = mask + 1u;
    uint lo = i == 0 ? 0u : keys[i - 1] + 1u;
    uint hi = i == n ? table : keys[i];
    for (uint b = lo; b <= hi && b <= table; b++)
        bucket_start[b] = i;
}

// One work-item per slot: sets, in a bit table hashed like the buckets (with
// its own mask), the bits of the occupancy cells (OCC_SPLIT per grid cell
// and axis: photon_grid.h) that come within the radius of a stored photon,
// padded for rounding. A gather point whose own occupancy cell's bit is clear
// has no photon within the radius (a set bit may be a hash collision), so
// most empty gathers end after one vector test (photon_maybe). OR is
// order-free: the table is the same bits every time.
__kernel void photon_occupancy(__global const float4 *ph_pos, uint n, real inv_cell, uint occ_mask,
                               __global uint *occ)
{
    uint i = get_global_id(0);
    if (i >= n)
        return;
    float4 p = ph_pos[i];
    if (p.w == 0.0f)
        return;
    // In occupancy cells: the photon at q, the radius `reach` (grid cells are two radii).
    real3 q = clamp(REAL3(p.xyz) * (inv_cell * R(OCC_SPLIT)), -GRID_COORD_LIMIT, GRID_COORD_LIMIT);
    real reach = R(0.5 * OCC_SPLIT * OCC_PAD);
    real3 tol = fabs(q) * R(OCC_REL_TOL);  // the gather's rounding of a coordinate, in cells
    real3 lo = floor(q - reach - tol), hi = floor(q + reach + tol);
    for (real cz = lo.z; cz <= hi.z; cz += R(1)) {
        real dz = fmax(fmax(cz - q.z, q.z - cz - R(1)) - tol.z, R(0));
        for (real cy = lo.y; cy <= hi.y; cy += R(1)) {
            real dy = fmax(fmax(cy - q.y, q.y - cy - R(1)) - tol.y, R(0));
            // A row's cells are consecutive bits: one atomic per word they fill.
            uint word = 0xFFFFFFFFu, bits = 0u;
            for (real cx = lo.x; cx <= hi.x; cx += R(1)) {
                real dx = fmax(fmax(cx - q.x, q.x - cx - R(1)) - tol.x, R(0));
                if (dx * dx + dy * dy + dz * dz > reach * reach)
                    continue;  // the cell's nearest point is beyond the radius
                uint b = grid_bucket((int3)((int)cx, (int)cy, (int)cz), occ_mask);
                if (b >> 5 != word) {
                    if (bits != 0u)
                        atomic_or(&occ[word], bits);
                    word = b >> 5;
                    bits = 0u;
                }
                bits |= 1u << (b & 31u);
            }
            if (bits != 0u)
                atomic_or(&occ[word], bits);
        }
    }
}
