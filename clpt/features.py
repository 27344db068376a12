"""What a kernel build contains: a small, hashable, printable description.

``scene_features`` reads a packed scene and the render options and returns a
``Features``; its ``options()`` are the sorted ``-D CLPT_*`` flags the kernels
are built with, and are part of every build-cache key. A specialized build
compiles only the shapes, lobes and light kinds the scene has, with its
primitive counts as compile-time constants; a generic build has everything
on and reads the counts at run time.

``Experimental`` holds the kernel variants kept only to be measured against
the defaults (``clpt bench-bvh --walks``); renders never need it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from .pack import PackedScene

KERNEL_MODES = ("specialized", "generic")
PIXEL_FILTERS = ("box", "tent", "gaussian")  # CLPT_PIXEL_FILTER 0, 1, 2 (kernels/camera.h)
BVH_WALKS = ("hybrid", "lane")
# kernels/sampler.h: "stratified" draws the camera's position and the first vertex's decisions from scrambled
# (0,2)-sequences per pixel (CLPT_STRATIFIED_DEPTH 1); "independent", every number from the hash (0)
SAMPLERS = ("stratified", "independent")


@dataclass(frozen=True)
class Experimental:
    """Kernel variants kept for comparison only; `clpt bench` is their one user.

    bvh_walk: "hybrid" (the default: camera rays that share an origin, with
    every lane alive, walk the BVH as one packet; every other ray walks
    alone) or "lane" (every ray walks alone). README "Meshes and the BVH"
    has the measurements that chose the hybrid."""

    bvh_walk: str = "hybrid"

    def check(self):
        if self.bvh_walk not in BVH_WALKS:
            raise ValueError(f"bvh_walk must be one of {', '.join(BVH_WALKS)} (got {self.bvh_walk!r})")
        return self


@dataclass(frozen=True)
class Features:
    lanes: int = 8
    double: bool = False
    accum_double: bool = True  # per-pixel sums in fp64, else Kahan-compensated float
    mode: str = "specialized"
    nee: bool = True
    photons: bool = True       # caustic photon map (only for scenes with caustic casters)
    aux: bool = False          # first-hit feature buffers (normal, albedo, depth) and the filter kernel
    spheres: bool = True
    quads: bool = True
    triangles: bool = True
    planes: bool = True
    phong: bool = True
    mirror: bool = True
    glass: bool = True
    microfacet: bool = True    # the rough conductor's microfacet lobe
    plastic: bool = True       # Mitsuba's plastic and roughplastic (a coated diffuse base)
    rough_dielectric: bool = True  # Mitsuba's roughdielectric (microfacet reflection and transmission)
    triangle_lights: bool = True
    sphere_lights: bool = True
    mesh_lights: bool = True
    point_lights: bool = True
    spot_lights: bool = True
    directional_lights: bool = True
    env_light: bool = True     # an environment (envmap or constant)
    bvh: bool = True           # the scene's primitives are in a BVH
    bvh_walk: str = "hybrid"   # BVH traversal (Experimental): "hybrid" (packets for coherent rays) or "lane"
    smooth: bool = True        # some triangles have vertex normals
    mitsuba_shading: bool = False  # smooth triangles shade by Mitsuba 3's rules (RenderSettings.shading_normals)
    textures: bool = True      # some materials have textures (kernels/texture.h)
    anisotropy: bool = True    # some microfacet lobes have alpha_u != alpha_v (shading-frame tangents)
    textured_emitters: bool = True  # some area lights' radiance is a texture (with textures)
    textured_spots: bool = True  # some spot light has a texture (with textures and spot lights)
    pixel_filter: str = "box"  # the camera's pixel filter (PIXEL_FILTERS); the box compiles no filter code
    sampler: str = "stratified"  # SAMPLERS
    counts: tuple = ()  # materials, spheres, quads, triangles, planes, lights, casters, BVH nodes (not generic)

    def defines(self) -> dict[str, int]:
        d = {
            "CLPT_LANES": self.lanes,
            "CLPT_DOUBLE": int(self.double),
            "CLPT_ACCUM_DOUBLE": int(self.accum_double),
            "CLPT_GENERIC": int(self.mode == "generic"),
            "CLPT_NEE": int(self.nee),
            "CLPT_PHOTONS": int(self.photons),
            "CLPT_AUX": int(self.aux),
            "CLPT_PIXEL_FILTER": PIXEL_FILTERS.index(self.pixel_filter),
            "CLPT_STRATIFIED_DEPTH": int(self.sampler == "stratified"),
            "CLPT_HAS_SPHERES": int(self.spheres),
            "CLPT_HAS_QUADS": int(self.quads),
            "CLPT_HAS_TRIANGLES": int(self.triangles),
            "CLPT_HAS_PLANES": int(self.planes),
            "CLPT_HAS_PHONG": int(self.phong),
            "CLPT_HAS_MIRROR": int(self.mirror),
            "CLPT_HAS_GLASS": int(self.glass),
            "CLPT_HAS_MICROFACET": int(self.microfacet),
            "CLPT_HAS_PLASTIC": int(self.plastic),
            "CLPT_HAS_ROUGH_DIELECTRIC": int(self.rough_dielectric),
            "CLPT_HAS_TRIANGLE_LIGHTS": int(self.triangle_lights),
            "CLPT_HAS_SPHERE_LIGHTS": int(self.sphere_lights),
            "CLPT_HAS_MESH_LIGHTS": int(self.mesh_lights),
            "CLPT_HAS_POINT_LIGHTS": int(self.point_lights),
            "CLPT_HAS_SPOT_LIGHTS": int(self.spot_lights),
            "CLPT_HAS_DIRECTIONAL_LIGHTS": int(self.directional_lights),
            "CLPT_HAS_ENV_LIGHT": int(self.env_light),
            "CLPT_HAS_BVH": int(self.bvh),
            "CLPT_BVH_PACKETS": int(self.bvh_walk == "hybrid"),
            "CLPT_HAS_SMOOTH": int(self.smooth),
            "CLPT_MITSUBA_SHADING": int(self.smooth and self.mitsuba_shading),
            "CLPT_HAS_TEXTURES": int(self.textures),
            "CLPT_HAS_ANISOTROPY": int(self.anisotropy),
            "CLPT_HAS_TEXTURED_EMITTERS": int(self.textures and self.textured_emitters),
            "CLPT_HAS_TEXTURED_SPOTS": int(self.textures and self.spot_lights and self.textured_spots),
        }
        if self.mode != "generic":
            for name, n in zip(("MATERIALS", "SPHERES", "QUADS", "TRIANGLES", "PLANES", "LIGHTS", "CAUSTICS",
                                "NODES"),
                               self.counts):
                d[f"CLPT_NUM_{name}"] = n
        return d

    def options(self) -> list[str]:
        return sorted(f"-D{k}={v}" for k, v in self.defines().items())

    def describe(self) -> str:
        on = [k for k, v in asdict(self).items() if v is True and k not in ("double", "accum_double")]
        counts = ""
        if self.counts:
            counts = " counts=" + ",".join(str(c) for c in self.counts)
        if self.pixel_filter != "box":
            counts += f" pixel-filter={self.pixel_filter}"
        counts += f" sampler={self.sampler}"
        if self.bvh and self.bvh_walk != "hybrid":
            counts += f" bvh-walk={self.bvh_walk}"
        return (f"{self.mode} lanes={self.lanes} {'double' if self.double else 'float'} "
                f"sums={'double' if self.accum_double else 'kahan-float'} "
                f"features={'+'.join(on) or 'none'}{counts}")


def scene_features(packed: PackedScene, *, lanes: int = 8, double: bool = False, accum_double: bool = True,
                   mode: str = "specialized", nee: bool = True, photons: bool | None = None,
                   aux: bool = False, bvh_walk: str = "hybrid", sampler: str = "stratified") -> Features:
    """photons: None turns them on exactly when the scene has caustic casters."""
    if mode not in KERNEL_MODES:
        raise ValueError(f"kernel mode must be one of {', '.join(KERNEL_MODES)} (got {mode!r})")
    if bvh_walk not in BVH_WALKS:
        raise ValueError(f"bvh_walk must be one of {', '.join(BVH_WALKS)} (got {bvh_walk!r})")
    if sampler not in SAMPLERS:
        raise ValueError(f"sampler must be one of {', '.join(SAMPLERS)} (got {sampler!r})")
    use_photons = packed.has_caustics if photons is None else bool(photons) and packed.has_caustics
    # The pixel filter is compiled in (or out) in both modes, as the photons and feature buffers are;
    # textures and anisotropy too, so that a scene without them builds exactly as it did before clpt had them.
    if mode == "generic":
        return Features(lanes=lanes, double=double, accum_double=accum_double, mode=mode, nee=nee,
                        photons=use_photons, aux=aux, bvh_walk=bvh_walk, pixel_filter=packed.pixel_filter,
                        sampler=sampler,
                        textures=bool(packed.textures), anisotropy=packed.anisotropic,
                        textured_emitters=packed.has_textured_emitters, textured_spots=packed.textured_spots,
                        mitsuba_shading=packed.smooth and packed.mitsuba_shading)
    return Features(
        lanes=lanes, double=double, accum_double=accum_double, mode=mode, nee=nee, photons=use_photons, aux=aux,
        pixel_filter=packed.pixel_filter, sampler=sampler,
        spheres=packed.count("spheres") > 0,
        quads=packed.count("quads") > 0,
        triangles=packed.count("triangles") > 0,
        planes=packed.count("planes") > 0,
        phong=packed.has_phong,
        mirror=packed.has_mirror,
        glass=packed.has_glass,
        microfacet=packed.has_microfacet,
        plastic=packed.has_plastic,
        rough_dielectric=packed.has_rough_dielectric,
        triangle_lights="triangle" in packed.light_kinds,
        sphere_lights="sphere" in packed.light_kinds,
        mesh_lights="mesh" in packed.light_kinds,
        point_lights="point" in packed.light_kinds,
        spot_lights="spot" in packed.light_kinds,
        directional_lights="directional" in packed.light_kinds,
        env_light="environment" in packed.light_kinds,
        bvh=packed.count("nodes") > 0,
        smooth=packed.smooth,
        mitsuba_shading=packed.smooth and packed.mitsuba_shading,
        textures=bool(packed.textures),
        anisotropy=packed.anisotropic,
        textured_emitters=packed.has_textured_emitters,
        textured_spots=packed.textured_spots,
        bvh_walk=bvh_walk,
        counts=tuple(packed.counts),
    )
