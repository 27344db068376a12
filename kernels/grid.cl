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

// Sets the occupancy bits of the cells x0..x1 of the row (y, z): consecutive
// bits (wrapping at the table's end), one atomic per word they fill.
inline void occupancy_row(__global uint *occ, uint occ_mask, int y, int z, int x0, int x1)
{
    uint b = grid_bucket((int3)(x0, y, z), occ_mask);
    uint n = (uint)(x1 - x0 + 1);
    while (n > 0u) {
        uint shift = b & 31u;
        uint k = min(n, min(32u - shift, occ_mask + 1u - b));
        atomic_or(&occ[b >> 5], (k == 32u ? 0xFFFFFFFFu : (1u << k) - 1u) << shift);
        n -= k;
        b = (b + k) & occ_mask;
    }
}

// One work-item per slot: sets, in a bit table hashed like the buckets (with
// its own mask), the bits of the occupancy cells (OCC_SPLIT per grid cell
// and axis: photon_grid.h) that come within the radius of a stored photon,
// padded for rounding: per row of cells, the run of x the ball reaches. A
// gather point whose own occupancy cell's bit is clear has no photon within
// the radius (a set bit may be a hash collision), so most empty gathers end
// after one vector test (photon_maybe). OR is order-free: the table is the
// same bits every time.
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
    // The gather's rounding of a coordinate, in cells (at most one: past that,
    // far from the origin at a tiny radius, cells are no longer told apart).
    real3 tol = fmin(fabs(q) * R(OCC_REL_TOL), R(1));
    int z0 = (int)floor(q.z - reach - tol.z), z1 = (int)floor(q.z + reach + tol.z);
    int y0 = (int)floor(q.y - reach - tol.y), y1 = (int)floor(q.y + reach + tol.y);
    for (int z = z0; z <= z1; z++) {
        real dz = fmax(fmax((real)z - q.z, q.z - (real)z - R(1)) - tol.z, R(0));
        for (int y = y0; y <= y1; y++) {
            real dy = fmax(fmax((real)y - q.y, q.y - (real)y - R(1)) - tol.y, R(0));
            real rest = reach * reach - dy * dy - dz * dz;
            if (rest < R(0))
                continue;  // the row's nearest point is beyond the radius
            real h = sqrt(rest) + tol.x;
            occupancy_row(occ, occ_mask, y, z, (int)floor(q.x - h), (int)floor(q.x + h));
        }
    }
}
