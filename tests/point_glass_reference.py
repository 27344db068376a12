"""The reference `clpt bench-photons tests/data/point_glass.xml` is measured
against: path tracing cannot form a point light's caustic through a smooth
sphere at all (its path-traced reference would have no caustic), so the
reference is a long render with photon merging (progressive: the radius
shrinks with the maps, so its blur vanishes), saved with its noise (per
pixel: the merged estimate's own variance, which leaves out the noise its
photon maps share) as the bench's reference EXR:

    python tests/point_glass_reference.py /tmp/point_glass_ref.exr [spp] [device]   # and its .noise.exr
    clpt bench-photons tests/data/point_glass.xml --reference /tmp/point_glass_ref.exr \
        --equal-time 4,16 --cpu-time --device intel

That the merged caustic is the true one (not merely the estimator's own
limit) is checked in tests/test_lights.py: a point light's photon caustic
through glass carries the energy of the same caustic path traced from a
tiny sphere light of the same power.
"""

import sys
from pathlib import Path

import numpy as np

import clpt
from clpt.image import save_image
from clpt.photons import PhotonSettings
from clpt.tools.reference import noise_path

SCENE = Path(__file__).resolve().parent / "data" / "point_glass.xml"


def main(out, spp=16384, device=None):
    scene = clpt.load_scene(SCENE)
    res = clpt.Renderer(scene, device=device).render(spp, seed=12345, max_depth=64,
                                                     photons=PhotonSettings(pilot=False))
    noise_map = res.lum_var.astype(np.float64) / np.maximum(res.sample_count, 1)
    noise = float(noise_map.mean())
    save_image(out, res.image, metadata={"clpt:reference_spp": spp, "clpt:noise": noise, "clpt:max_depth": 64,
                                         "clpt:reference_method": "photon merging (progressive)"})
    save_image(noise_path(out), noise_map, metadata={"clpt:reference_spp": spp,
                                                     "clpt:content": "variance of each pixel's luminance mean"})
    print(f"{out}: {spp} spp in {res.stats.render_seconds:.1f} s, noise {noise:.3g}")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 16384, sys.argv[3] if len(sys.argv) > 3 else None)
