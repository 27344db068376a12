// features.h: every CLPT_* flag the host must define (clpt/features.py), each
// as 0 or 1 (or a count), tested with #if. A missing flag is a build error
// here rather than a silently disabled feature.

#if !defined(CLPT_LANES) || !defined(CLPT_DOUBLE) || !defined(CLPT_ACCUM_DOUBLE) || !defined(CLPT_GENERIC) \
    || !defined(CLPT_NEE)
#error "clpt: CLPT_LANES, CLPT_DOUBLE, CLPT_ACCUM_DOUBLE, CLPT_GENERIC and CLPT_NEE must be defined"
#endif
#if CLPT_DOUBLE && !CLPT_ACCUM_DOUBLE
#error "clpt: double-precision kernels accumulate in double"
#endif
#if !defined(CLPT_HAS_SPHERES) || !defined(CLPT_HAS_QUADS) || !defined(CLPT_HAS_TRIANGLES) \
    || !defined(CLPT_HAS_PLANES)
#error "clpt: every CLPT_HAS_<shape> flag must be defined"
#endif
#if !defined(CLPT_HAS_PHONG) || !defined(CLPT_HAS_MIRROR) || !defined(CLPT_HAS_GLASS) \
    || !defined(CLPT_HAS_MICROFACET) || !defined(CLPT_HAS_PLASTIC) || !defined(CLPT_HAS_ROUGH_DIELECTRIC)
#error "clpt: every CLPT_HAS_<lobe> flag must be defined"
#endif
#if !defined(CLPT_HAS_TRIANGLE_LIGHTS) || !defined(CLPT_HAS_SPHERE_LIGHTS) || !defined(CLPT_HAS_MESH_LIGHTS) \
    || !defined(CLPT_HAS_POINT_LIGHTS) || !defined(CLPT_HAS_SPOT_LIGHTS) || !defined(CLPT_HAS_DIRECTIONAL_LIGHTS) \
    || !defined(CLPT_HAS_ENV_LIGHT)
#error "clpt: every CLPT_HAS_<kind>_LIGHTS flag (and CLPT_HAS_ENV_LIGHT) must be defined"
#endif
// Point, spot and directional lights: delta lights, found by next event estimation only.
#define CLPT_HAS_DELTA_LIGHTS (CLPT_HAS_POINT_LIGHTS || CLPT_HAS_SPOT_LIGHTS || CLPT_HAS_DIRECTIONAL_LIGHTS)
#if !defined(CLPT_LUMA_R) || !defined(CLPT_OFFSET_REL_FLOAT)
#error "clpt: the generated constants (clpt/constants.py) must come first"
#endif
#if !defined(CLPT_HAS_BVH) || !defined(CLPT_HAS_SMOOTH) || !defined(CLPT_BVH_PACKETS) \
    || !defined(CLPT_MITSUBA_SHADING)
#error "clpt: CLPT_HAS_BVH, CLPT_HAS_SMOOTH, CLPT_BVH_PACKETS and CLPT_MITSUBA_SHADING must be defined"
#endif
#if !defined(CLPT_HAS_TEXTURES) || !defined(CLPT_HAS_TEXTURED_EMITTERS) || !defined(CLPT_HAS_TEXTURED_SPOTS)
#error "clpt: CLPT_HAS_TEXTURES, CLPT_HAS_TEXTURED_EMITTERS and CLPT_HAS_TEXTURED_SPOTS must be defined"
#endif
#if !defined(CLPT_PHOTONS) || !defined(CLPT_AUX) || !defined(CLPT_PIXEL_FILTER)
#error "clpt: CLPT_PHOTONS, CLPT_AUX and CLPT_PIXEL_FILTER must be defined"
#endif
#if !CLPT_GENERIC && (!defined(CLPT_NUM_MATERIALS) || !defined(CLPT_NUM_SPHERES) || !defined(CLPT_NUM_QUADS) \
    || !defined(CLPT_NUM_TRIANGLES) || !defined(CLPT_NUM_PLANES) || !defined(CLPT_NUM_LIGHTS) \
    || !defined(CLPT_NUM_CAUSTICS) || !defined(CLPT_NUM_NODES))
#error "clpt: a specialized build needs every CLPT_NUM_* count"
#endif
