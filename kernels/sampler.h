// sampler.h: every random decision of a path, by name.
//
// rng.h draws dimensions in groups of four from (seed, pixel, sample,
// group). This file is the one table of which decision reads which
// dimension (pbrt's Get1D/Get2D order, written out), so a call site asks for
// "the light sample at this depth", never for a group number or a component
// another decision left over. A new decision gets a free component or a
// new group here, and nowhere else.
//
// Camera paths (trace_paths), per (seed, pixel, sample index):
//   group 0            camera   .a .b  position in the pixel (through the pixel
//                                      filter's inverse CDF: camera.h)
//   per vertex at depth k (the camera's first hit is depth 0):
//   group 2k + 1       light    .a     which light (by power)
//                               .b .c  the point on it
//                      merge    .d     whether to merge here (the roulette on
//                                      the technique) and, rescaled, the
//                                      gather's subsampling offset
//   group 2k + 2       bsdf     .a     which lobe (Russian roulette over the
//                                      lobes and absorption)
//                               .b .c  the direction in the lobe
//                               .d     reflection or refraction (Fresnel)
// Photon paths (trace_photons), per (salted seed, photon index, 0):
//   group 0            emission .a .b .c  light and point (as "light" above)
//                               .d     which caustic caster to aim at
//   group 1            aim      .a .b  the direction in its cone
//   group 2 + b        bounce b .a     which lobe, .b Fresnel (as "bsdf")

typedef struct { vreal x, y; } CameraU;                // a position in the pixel
typedef struct { vreal pick, u1, u2; } LightU;         // a light and a point on it
typedef struct { vreal lobe, u1, u2, fresnel; } BsdfU;  // a lobe, a direction in it, and Fresnel's choice
typedef struct { LightU light; vreal caster, u1, u2; } EmitU;  // a photon's start: light point, caster, direction

// --- stratified dimensions -----------------------------------------------------
// The camera's position and every decision of the first CLPT_STRATIFIED_DEPTH
// vertices are drawn, per pixel, from scrambled (0,2)-sequences: the
// first 2^m samples of a pixel put one point in each of the 2^m elementary
// intervals of every shape (the m-bit strata of x times the (m-k)-bit
// strata of y), however the samples are split among passes and devices.
// Each pair of dimensions (camera x y; a light's point; a lobe's
// direction; the light pick with the merge decision; the lobe with
// Fresnel's choice) takes the pixel's samples in its own shuffled order,
// so no pair follows another. Deeper vertices draw independent numbers
// (rng.h): past the first bounces stratification no longer pays its cost.
#ifndef CLPT_STRATIFIED_DEPTH
#define CLPT_STRATIFIED_DEPTH 1
#endif

// The bits of each word in reverse order. LLVM-based compilers turn the
// swaps into their bitreverse intrinsic (one instruction on GPUs, a few
// byte shuffles on CPUs); Oclgrind cannot run that intrinsic, so there
// (CLPT_BITREVERSE_TABLE, clpt/program.py device_options) each byte is
// looked up instead.
#if CLPT_BITREVERSE_TABLE
__constant uchar NIBBLE_REVERSED[16] = {0x0, 0x8, 0x4, 0xc, 0x2, 0xa, 0x6, 0xe, 0x1, 0x9, 0x5, 0xd, 0x3, 0xb, 0x7, 0xf};

inline uint word_reversed(uint x)
{
    uint r = 0u;
    for (int k = 0; k < 8; k++)  // nibble k to nibble 7 - k, its bits reversed
        r |= (uint)NIBBLE_REVERSED[(x >> (4 * k)) & 15u] << (4 * (7 - k));
    return r;
}

inline vuint bits_reversed(vuint x)
{
#if CLPT_LANES == 1
    return word_reversed(x);
#else
    vuint r;
    for (int l = 0; l < CLPT_LANES; l++)
        VLANE_U(r, l) = word_reversed(VLANE_U(x, l));
    return r;
#endif
}
#else
inline vuint bits_reversed(vuint x)
{
    x = (x << 16) | (x >> 16);
    x = ((x & 0x00ff00ffu) << 8) | ((x >> 8) & 0x00ff00ffu);
    x = ((x & 0x0f0f0f0fu) << 4) | ((x >> 4) & 0x0f0f0f0fu);
    x = ((x & 0x33333333u) << 2) | ((x >> 2) & 0x33333333u);
    return ((x & 0x55555555u) << 1) | ((x >> 1) & 0x55555555u);
}
#endif

// A random permutation of the words in which bit k is flipped by a function
// of the key and bits 0 .. k-1 alone (adds carry, and products by even
// constants shift, only towards the high bits). On an index with its bits
// reversed, that flips each bit of the index by the bits above it: a nested
// uniform (Owen) scramble of the order, which keeps every aligned block of
// 2^m indices within itself.
inline vuint owen_flips(vuint x, vuint key)
{
    x += key;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

// Sample index i's point of a (0,2)-sequence, its order shuffled by
// `shuffle` and its digits XOR-ed with (kx, ky) (a random digital shift:
// Kollig and Keller's scrambling), as top-24-bit reals; ri is i with its
// bits reversed. The sequence is Sobol's first two dimensions, as binary
// fractions: x is the shuffled index with its bits reversed (van der
// Corput), and y's digit q is the XOR of x's digits q' whose positions
// (31 - bit) are subsets of q's (the generator matrix is Pascal's triangle
// mod 2: a subset-sum transform in five steps). A shuffled prefix of 2^m
// samples is an aligned block of indices, so a (0,m,2)-net, and a shift
// keeps it one; each pair has its own shuffle, so no pair follows another.
inline void sobol_pair(vuint ri, vuint shuffle, vuint kx, vuint ky, vreal *x, vreal *y)
{
    vuint t = owen_flips(ri, shuffle);
    vuint p = t;
    p ^= (p << 1) & 0xaaaaaaaau;
    p ^= (p << 2) & 0xccccccccu;
    p ^= (p << 4) & 0xf0f0f0f0u;
    p ^= (p << 8) & 0xff00ff00u;
    p ^= p << 16;
    *x = rng_to_unit(t ^ kx);
    *y = rng_to_unit(p ^ ky);
}

#define STRATA_SALT 0x2f6b3c5du  // the pairs' keys apart from rng.h's independent numbers

// The keys of a pixel's pairs, by group (0: the camera, 1: the first
// vertex's light, 2: its lobe; each .x, .y the shuffles of pairs (.b, .c)
// and (.a, .d), .z, .w the shifts): a hash of (seed, pixel, group), worked
// out when a lane takes a pixel (sampler_keys_take), not at every vertex.
typedef struct {
#if CLPT_STRATIFIED_DEPTH > 0
    vuint k[3][4];
#else
    int none;
#endif
} SamplerKeys;

inline void sampler_keys_take(SamplerKeys *keys, uint seed, vuint pixel, vmask took)
{
#if CLPT_STRATIFIED_DEPTH > 0
    if (!VANY(took))
        return;
    vint m = VINT(took);  // (a 32-bit mask for 32-bit words, in double builds too)
    for (uint g = 0; g < 3u; g++) {
        U4 k = pcg4d(pixel ^ (seed * 0x9E3779B9u), (vuint)g, (vuint)(seed ^ STRATA_SALT), (vuint)0x51ed27u);
        keys->k[g][0] = VSEL(keys->k[g][0], k.x, m); keys->k[g][1] = VSEL(keys->k[g][1], k.y, m);
        keys->k[g][2] = VSEL(keys->k[g][2], k.z, m); keys->k[g][3] = VSEL(keys->k[g][3], k.w, m);
    }
#endif
}

// Every lane's keys (for the pixels they have now).
inline SamplerKeys sampler_keys_make(uint seed, vuint pixel)
{
    SamplerKeys keys;
    sampler_keys_take(&keys, seed, pixel, (vreal)R(0) == (vreal)R(0));
    return keys;
}

// --- camera paths --------------------------------------------------------------
typedef struct {
    uint seed;
    vuint pixel, sample;
#if CLPT_STRATIFIED_DEPTH > 0
    vuint rsample;  // the sample index, bits reversed (every pair starts from it)
    const SamplerKeys *keys;
#endif
} Sampler;

inline Sampler sampler_make(uint seed, vuint pixel, vuint sample, const SamplerKeys *keys)
{
    Sampler s;
    s.seed = seed;
    s.pixel = pixel;
    s.sample = sample;
#if CLPT_STRATIFIED_DEPTH > 0
    s.rsample = bits_reversed(sample);
    s.keys = keys;
#endif
    return s;
}

// Group g's numbers, into *r: independent (rng.h), or where `strata` holds
// (then g is 1 or 2), from two scrambled pairs: (.b, .c) and, if `both`,
// (.a, .d) (a compile-time constant: a pair nobody reads is not computed;
// always inlined, so it fills *r rather than returning a struct: simd.h).
CLPT_INLINE void sampler_uniform4(const Sampler *s, vuint group, vmask strata, int g, int both, Rand4 *r)
{
    *r = rng_uniform4(s->seed, s->pixel, s->sample, group);
#if CLPT_STRATIFIED_DEPTH > 0
    if (VANY(strata)) {
        const vuint *k = s->keys->k[g];
        vreal x, y;
        sobol_pair(s->rsample, k[0], k[2], k[3], &x, &y);
        r->b = VSEL(r->b, x, strata); r->c = VSEL(r->c, y, strata);
        if (both) {
            sobol_pair(s->rsample, k[1], k[2] ^ k[1], k[3] ^ k[1], &x, &y);
            r->a = VSEL(r->a, x, strata); r->d = VSEL(r->d, y, strata);
        }
    }
#endif
}

inline vuint sampler_vertex_group(vreal depth) { return VUINT(depth) * 2u + 1u; }
inline vmask sampler_strata(vreal depth) { return depth < R(CLPT_STRATIFIED_DEPTH > 0); }

// The light pick and the merge decision, and the lobe with Fresnel's choice,
// are worth a pair only where they decide something: several lights or
// photons; a lobe besides the diffuse one (before rr_depth a diffuse
// material's lobe coin decides nothing: absorption is left out there).
#if CLPT_PHOTONS || !defined(CLPT_NUM_LIGHTS)
#define LIGHT_PICK_STRATA 1
#elif CLPT_NUM_LIGHTS > 1
#define LIGHT_PICK_STRATA 1
#else
#define LIGHT_PICK_STRATA 0
#endif
#if CLPT_HAS_PHONG || CLPT_HAS_MIRROR || CLPT_HAS_GLASS || CLPT_HAS_MICROFACET || CLPT_HAS_PLASTIC \
    || CLPT_HAS_ROUGH_DIELECTRIC
#define LOBE_STRATA 1
#else
#define LOBE_STRATA 0
#endif

// Position of the sample within its pixel, in [0, 1)^2.
inline CameraU sample_camera(const Sampler *s)
{
    CameraU u;
#if CLPT_STRATIFIED_DEPTH > 0
    const vuint *k = s->keys->k[0];
    sobol_pair(s->rsample, k[0], k[2], k[3], &u.x, &u.y);
#else
    Rand4 r = rng_uniform4(s->seed, s->pixel, s->sample, (vuint)0u);
    u.x = r.a; u.y = r.b;
#endif
    return u;
}

inline LightU sample_light(const Sampler *s, vreal depth)
{
    Rand4 r;
    sampler_uniform4(s, sampler_vertex_group(depth), sampler_strata(depth), 1, LIGHT_PICK_STRATA, &r);
    LightU u;
    u.pick = r.a; u.u1 = r.b; u.u2 = r.c;
    return u;
}

inline vreal sample_merge(const Sampler *s, vreal depth)
{
    Rand4 r;
    sampler_uniform4(s, sampler_vertex_group(depth), sampler_strata(depth), 1, 1, &r);
    return r.d;
}

inline BsdfU sample_bsdf(const Sampler *s, vreal depth)
{
    Rand4 r;
    sampler_uniform4(s, sampler_vertex_group(depth) + 1u, sampler_strata(depth), 2, LOBE_STRATA, &r);
    BsdfU u;
    u.lobe = r.a; u.u1 = r.b; u.u2 = r.c; u.fresnel = r.d;
    return u;
}

// --- photon paths ----------------------------------------------------------------
#define PHOTON_SEED_SALT 0x5bd1e995u  // photon streams apart from the camera's

typedef struct {
    uint seed;     // salted
    vuint photon;  // photon index
} PhotonSampler;

inline PhotonSampler photon_sampler_make(uint seed, vuint photon)
{
    PhotonSampler s;
    s.seed = seed ^ PHOTON_SEED_SALT;
    s.photon = photon;
    return s;
}

inline EmitU sample_photon_emission(const PhotonSampler *s)
{
    Rand4 r0 = rng_uniform4(s->seed, s->photon, (vuint)0u, (vuint)0u);
    Rand4 r1 = rng_uniform4(s->seed, s->photon, (vuint)0u, (vuint)1u);
    EmitU u;
    u.light.pick = r0.a; u.light.u1 = r0.b; u.light.u2 = r0.c;
    u.caster = r0.d; u.u1 = r1.a; u.u2 = r1.b;
    return u;
}

// Bounce b: only the delta lobes (.lobe) and Fresnel's choice (.fresnel) are drawn.
inline BsdfU sample_photon_bounce(const PhotonSampler *s, uint bounce)
{
    Rand4 r = rng_uniform4(s->seed, s->photon, (vuint)0u, (vuint)(2u + bounce));
    BsdfU u;
    u.lobe = r.a; u.fresnel = r.b;
    u.u1 = u.u2 = (vreal)R(0);
    return u;
}
