"""Rendering on a Dask cluster: a LocalCluster of two worker processes gives
the one-process image, also when a worker is killed mid-render."""

import os
import signal
import threading

import numpy as np
import pytest

import clpt

distributed = pytest.importorskip("distributed", reason="Dask is an optional extra: pip install 'clpt[dask]'")


@pytest.fixture(scope="module")
def client():
    # One OpenCL thread per worker process: two processes share the machine's cores.
    os.environ.setdefault("POCL_MAX_PTHREAD_COUNT", "1")
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0")
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


ARGS = dict(width=24, height=16, seed=9, pass_seconds=0.05)


def assert_same(a, b):
    assert np.array_equal(a.sample_count, b.sample_count)
    # The same samples; only the order of float64 additions differs.
    assert np.allclose(a.image, b.image, rtol=1e-6, atol=0)
    assert np.allclose(a.lum_var, b.lum_var, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("scene,kw", [("cornell_box", {}),
                                       ("cornell_box_caustics", {"photons": clpt.PhotonSettings(
                                           count=20_000, progressive=True, spp_per_map=4, pilot=False)}),
                                       ("cornell_box", {"adaptive": clpt.AdaptiveSettings(min_spp=8, pass_spp=8)})])
def test_two_workers_give_the_one_process_image(client, device_spec, scene, kw):
    r = clpt.Renderer(scene, device=device_spec)
    one = r.render(32, **ARGS, **kw)
    dist = r.render(32, **ARGS, **kw, executor=client)
    assert_same(one, dist)
    hosts = {p[0] for p in dist.stats.passes}
    assert len(hosts) >= 1 and dist.stats.launches.get("trace_paths", 0) >= 2


def test_a_worker_killed_mid_render_changes_nothing(client, device_spec):
    r = clpt.Renderer("cornell_box", device=device_spec)
    one = r.render(400, **ARGS)
    pids = list(client.run(os.getpid).values())
    killed = []

    def progress(done, total, elapsed, rate):
        if done >= 40 and not killed:
            killed.append(pids[0])
            os.kill(pids[0], signal.SIGKILL)

    dist = r.render(400, **ARGS, executor=client, progress=progress)
    assert killed, "the render ended before a worker could be killed"
    assert_same(one, dist)
    client.wait_for_workers(2, timeout=120)  # the nanny restarts it
