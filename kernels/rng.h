// rng.h: counter-based random numbers.
//
// Every random number is a pure function of (seed, pixel, sample index,
// dimension): nothing is carried between launches, so any sample can be
// replayed alone and work can be split across passes, work-groups and devices
// without changing a single bit of the image.
//
// The mixer is the 4-D PCG hash of Jarzynski and Olano ("Hash Functions for
// GPU Rendering", JCGT 2020): a 4-word input gives 4 well-mixed output words,
// so one call yields four dimensions. Dimensions are used in groups of four:
// group g holds dimensions 4g .. 4g+3.

typedef struct { vuint x, y, z, w; } U4;

inline U4 pcg4d(vuint x, vuint y, vuint z, vuint w)
{
    x = x * 1664525u + 1013904223u;
    y = y * 1664525u + 1013904223u;
    z = z * 1664525u + 1013904223u;
    w = w * 1664525u + 1013904223u;
    x += y * w; y += z * x; z += x * y; w += y * z;
    x ^= x >> 16; y ^= y >> 16; z ^= z >> 16; w ^= w >> 16;
    x += y * w; y += z * x; z += x * y; w += y * z;
    U4 r; r.x = x; r.y = y; r.z = z; r.w = w;
    return r;
}

// Top 24 bits of a word as a real in [0, 1 - 2^-24]: the same values in float
// and double builds, so both precisions draw identical sample streams.
inline vreal rng_to_unit(vuint b) { return VREAL(b >> 8) * R(5.9604644775390625e-08); }

typedef struct { vreal a, b, c, d; } Rand4;

// Four uniform numbers for dimension group g of sample (pixel, sample).
inline Rand4 rng_uniform4(uint seed, vuint pixel, vuint sample, vuint group)
{
    // pcg4d is a bijection of 128 bits and (pixel, sample, group, seed) maps
    // one-to-one onto its input, so no two dimensions anywhere share a word.
    // Folding the seed into the pixel word as well decorrelates low seeds.
    U4 h = pcg4d(pixel ^ (seed * 0x9E3779B9u), sample, group, (vuint)(seed + 0x632BE5ABu));
    Rand4 r;
    r.a = rng_to_unit(h.x); r.b = rng_to_unit(h.y); r.c = rng_to_unit(h.z); r.d = rng_to_unit(h.w);
    return r;
}
