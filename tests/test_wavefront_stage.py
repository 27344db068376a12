"""tests/bench_wavefront.py's intersection stage (tests/kernels/wavefront.cl)
answers as the kernels' own queries do: the same closest hits and shadow
tests as the probes (scene_intersect, scene_occluded) on the same rays, at
the scene's specialised build, in one lane and eight."""

import numpy as np
import pytest

import clpt
from bench_wavefront import Stage, camera_rays, cosine_about, make_queues, morton_order


@pytest.fixture(scope="module")
def box_renderer(device_spec):
    return {lanes: clpt.Renderer(clpt.load_scene("cornell_box"), device=device_spec, photons=False, lanes=lanes)
            for lanes in (1, 8)}


@pytest.mark.parametrize("lanes", [1, 8])
def test_stage_hits_equal_the_probes(box_renderer, probes, lanes):
    r = box_renderer[lanes]
    stage = Stage(r, lanes)
    rng = np.random.default_rng(3)
    o, d = camera_rays(r.scene.camera, rng)
    o, d = o[::7], d[::7]
    (t, nx, ny, nz, light), _ = stage.run("wf_closest", [*o.T, *d.T], 5)
    hit = np.isfinite(t)
    assert 0.8 < hit.mean() < 1  # the box's open front shows at the image's corners
    probe = probes(lanes=lanes)
    tmax = np.where(hit, t * rng.uniform(0.5, 1.5, len(t)), 10.0)
    ref = probe.run("probe_hit", [*o.T, *d.T, tmax], 9, prefix=probe.scene_args(r.packed))
    np.testing.assert_allclose(t, ref[0], rtol=1e-6)
    np.testing.assert_allclose(np.stack([nx, ny, nz]), np.stack(ref[4:7]), atol=1e-6)
    (occ,), _ = stage.run("wf_occluded", [*o.T, *d.T, tmax], 1)
    np.testing.assert_array_equal(occ, ref[8])
    # tmax below the hit: unblocked. (Beyond it the segment may leave the box through a wall that
    # shadow rays skip, clpt/pack.py _mark_shadowless, so it need not count as blocked.)
    assert (occ[tmax < t * 0.999] == 0).all() and (occ[~hit] == 0).all()
    assert 0.1 < occ[hit & (tmax > t * 1.001)].mean() < 1  # the blocks and the lamp still block


def test_queues_are_rays_of_real_paths(box_renderer):
    r = box_renderer[8]
    stage = Stage(r, 8)
    rng = np.random.default_rng(5)
    q = make_queues(stage, r.scene.camera, 2, rng, 1e-4 * r.packed.extent)
    w, h = r.scene.camera.width, r.scene.camera.height
    assert len(q["camera"][0]) == w * h
    # Escaped paths leave the queue (the box is open at the front): each generation is smaller.
    nb = len(q["bounce"][0])
    assert 0.6 * 2 * w * h < nb < 2 * w * h
    assert 0.3 * (w * h + nb) < len(q["shadow"][0]) <= w * h + nb
    o, dd, tmax = q["shadow"]
    assert (tmax > 0).all() and np.allclose(np.linalg.norm(dd, axis=1), 1, atol=1e-5)
    k = morton_order(o, dd)
    assert sorted(k.tolist()) == list(range(len(o)))
    n = rng.normal(size=(1000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    c = cosine_about(n, rng)
    cos = np.sum(c * n, axis=1)
    assert (cos >= 0).all() and abs(cos.mean() - 2 / 3) < 0.03  # E[cos] of a cosine lobe
