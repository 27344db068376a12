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

// --- camera paths --------------------------------------------------------------
typedef struct {
    uint seed;
    vuint pixel, sample;
} Sampler;

inline Sampler sampler_make(uint seed, vuint pixel, vuint sample)
{
    Sampler s;
    s.seed = seed;
    s.pixel = pixel;
    s.sample = sample;
    return s;
}

inline vuint sampler_vertex_group(vreal depth) { return VUINT(depth) * 2u + 1u; }

// Position of the sample within its pixel, in [0, 1)^2.
inline CameraU sample_camera(const Sampler *s)
{
    Rand4 r = rng_uniform4(s->seed, s->pixel, s->sample, (vuint)0u);
    CameraU u;
    u.x = r.a; u.y = r.b;
    return u;
}

inline LightU sample_light(const Sampler *s, vreal depth)
{
    Rand4 r = rng_uniform4(s->seed, s->pixel, s->sample, sampler_vertex_group(depth));
    LightU u;
    u.pick = r.a; u.u1 = r.b; u.u2 = r.c;
    return u;
}

inline vreal sample_merge(const Sampler *s, vreal depth)
{
    return rng_uniform4(s->seed, s->pixel, s->sample, sampler_vertex_group(depth)).d;
}

inline BsdfU sample_bsdf(const Sampler *s, vreal depth)
{
    Rand4 r = rng_uniform4(s->seed, s->pixel, s->sample, sampler_vertex_group(depth) + 1u);
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
