"""Watching a render: Renderer.render(on_update=...), streaming to tev (checked
by a stand-in viewer that decodes tev's packets), and notebook display."""

import importlib.util
import socket
import struct
import time
import warnings
import zlib

import numpy as np
import pytest

import clpt
from clpt.device import select_devices
from clpt.preview import RenderUpdate

from tevserver import TevServer, decode

from clpt.tev import TevViewer, parse_address

needs_tevclient = pytest.mark.skipif(importlib.util.find_spec("tevclient") is None,
                                     reason="tevclient (pip install 'clpt[tev]') builds tev's packets")

W, H = 40, 24  # not a multiple of the 64-pixel tiles, nor square


@pytest.fixture(scope="module")
def cbox(device_spec):
    return clpt.Renderer("cornell_box", device=device_spec)


@pytest.fixture(scope="module")
def cbox_aux(device_spec):
    return clpt.Renderer("cornell_box", device=device_spec, aux=True)


def many_passes(r, spp=16, **kw):
    """A render of one sample per pass, an update after each."""
    return r.render(spp, width=W, height=H, seed=3, pass_seconds=1e-9, update_interval=0.0, **kw)


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


# --- on_update --------------------------------------------------------------


def test_updates_between_passes_then_one_final_equal_to_the_result(cbox):
    ups = []
    res = many_passes(cbox, on_update=ups.append)
    assert [u.final for u in ups] == [False] * (len(ups) - 1) + [True]
    assert len(ups) >= 8  # one pass per sample: an update after each (the last may fall in the final)
    done = [u.spp_done for u in ups]
    assert done == sorted(done) and done[-1] == 16
    for u in ups[:-1]:  # each image is the mean of exactly the samples it counts
        assert u.image.shape == (H, W, 3) and u.image.dtype == np.float32
        assert (u.sample_count == u.spp_done).all()
        assert np.isfinite(u.image).all() and np.isfinite(u.lum_var).all()
        assert u.aux is None and u.filtered is None
    # the update after k samples is exactly the render of k samples
    k = ups[3].spp_done
    assert np.array_equal(ups[3].image, cbox.render(k, width=W, height=H, seed=3).image)
    f = ups[-1]
    assert np.array_equal(f.image, res.image) and np.array_equal(f.sample_count, res.sample_count)
    assert f.stats is res.stats and f.spp_total == 16


def test_update_interval_limits_the_rate(cbox):
    ups = []
    many_passes(cbox, spp=24, on_update=ups.append)
    fast = len(ups)
    ups = []
    res = cbox.render(24, width=W, height=H, seed=3, pass_seconds=1e-9, update_interval=3600.0, on_update=ups.append)
    assert len(ups) == 2 and ups[-1].final  # the first pass, then only the final
    assert fast > 2 and res.stats.render_seconds < 3600


def test_updates_of_adaptive_rounds_and_feature_buffers(cbox_aux):
    ups = []
    res = cbox_aux.render(32, width=W, height=H, seed=1, adaptive=clpt.AdaptiveSettings(min_spp=8),
                          filter=clpt.FilterSettings(), update_interval=0.0, on_update=ups.append)
    assert res.stats.adaptive_rounds >= 1
    rounds = [u for u in ups if not u.final and u.spp_done > 8]
    assert rounds and any(u.sample_count.min() < u.sample_count.max() for u in rounds)
    for u in rounds:
        assert abs(u.sample_count.mean() - u.spp_done) < 1e-9
        assert {"normal", "albedo", "depth", "emission"} <= set(u.aux)
    f = ups[-1]
    assert f.final and np.array_equal(f.filtered, res.filtered) and np.array_equal(f.display_image(), res.filtered)


def test_several_devices_update_with_the_merged_image(device_spec):
    dev = select_devices(device_spec)[0]
    r = clpt.Renderer("cornell_box", device=[dev, dev])
    ups = []
    res = r.render(64, width=W, height=H, seed=2, pass_seconds=1e-9, update_interval=0.0, on_update=ups.append)
    assert ups[-1].final and np.array_equal(ups[-1].image, res.image)
    for u in ups[:-1]:  # both devices' sums: counts are whole samples per pixel, image their mean
        assert (u.sample_count == u.sample_count.flat[0]).all() and u.sample_count.flat[0] >= 1


def test_bad_on_update_and_interval(cbox):
    with pytest.raises(TypeError, match="on_update"):
        cbox.render(1, width=4, height=4, on_update=3)
    for bad in (-1.0, float("nan"), float("inf"), "0.1", True):
        with pytest.raises(ValueError, match="update_interval"):
            cbox.render(1, width=4, height=4, on_update=print, update_interval=bad)
    with pytest.raises(TypeError):
        RenderUpdate(spp_done=0, spp_total=1, elapsed=0.0, stats=None)


# --- tev ----------------------------------------------------------------------


@needs_tevclient
def test_decoder_reads_tevclient_packets():
    """The stand-in's decoder against packets built by tev's own client, with a
    strided tile: what goes in comes out."""
    from tevclient import packet

    c = decode(bytes(packet.create_image("a b", 5, 3, ["R", "G", "B", "x.Y"])))
    assert c == {"type": "create", "focus": True, "name": "a b", "width": 5, "height": 3,
                 "channels": ["R", "G", "B", "x.Y"]}
    tile = np.arange(2 * 4 * 3, dtype=np.float32).reshape(2, 4, 3)
    u = decode(bytes(packet.update_image("a b", tile[:, ::2], ["R", "G", "B"], 1, 2)))
    assert (u["x"], u["y"], u["width"], u["height"], u["channels"]) == (1, 2, 2, 2, ["R", "G", "B"])
    assert np.array_equal(u["data"], tile[:, ::2])
    assert decode(bytes(packet.close_image("a b"))) == {"type": "close", "name": "a b"}
    # Channels one after another (offset c * w * h, stride 1), as other clients send them.
    body = (struct.pack("<BB", 6, 0) + b"p\0" + struct.pack("<i", 2) + b"R\0G\0" + struct.pack("<iiii", 0, 0, 3, 2)
            + struct.pack("<qq", 0, 6) + struct.pack("<qq", 1, 1) + np.arange(12, dtype="<f4").tobytes())
    planar = decode(struct.pack("<I", len(body) + 4) + body)
    assert np.array_equal(planar["data"], np.stack([np.arange(6).reshape(2, 3), np.arange(6, 12).reshape(2, 3)], -1))


@needs_tevclient
def test_tev_gets_one_create_tiles_covering_the_image_and_the_final_images(cbox_aux):
    srv = TevServer()
    viewer = TevViewer("cbox seed 3", srv.address, tile=16)
    res = many_passes(cbox_aux, spp=12, filter=clpt.FilterSettings(), on_update=viewer)
    viewer.close()
    srv.wait()
    assert not srv.errors
    creates = [p for p in srv.packets if p["type"] == "create"]
    assert srv.packets[0] == creates[0]
    assert [p["name"] for p in creates] == ["cbox seed 3", "cbox seed 3 filtered", "cbox seed 3 raw"]
    assert (creates[0]["width"], creates[0]["height"], creates[0]["focus"]) == (W, H, True)
    assert creates[0]["channels"] == ["R", "G", "B", "spp", "relerr", "albedo.R", "albedo.G", "albedo.B",
                                      "normal.X", "normal.Y", "normal.Z"]
    main = srv.images["cbox seed 3"]
    assert main.covered.all()
    first = [p for p in srv.updates("cbox seed 3")][:6]  # the first update: 3 x 2 tiles of 16 covering 40 x 24
    assert sorted((p["x"], p["y"], p["width"], p["height"]) for p in first) == \
        [(0, 0, 16, 16), (0, 16, 16, 8), (16, 0, 16, 16), (16, 16, 16, 8), (32, 0, 8, 16), (32, 16, 8, 8)]
    assert viewer.updates >= 2 and len(srv.updates("cbox seed 3")) == 6 * viewer.updates
    assert np.array_equal(main.channel("R", "G", "B"), res.filtered)  # the last image shown is the filtered one
    assert np.array_equal(main.channel("spp")[..., 0], res.sample_count)
    assert np.array_equal(main.channel("albedo.R", "albedo.G", "albedo.B"), res.aux["albedo"])
    assert np.array_equal(main.channel("normal.X", "normal.Y", "normal.Z"), res.aux["normal"])
    # relerr is adaptive sampling's measure: the standard error over sqrt(mean^2 + 0.1^2) (clpt/adaptive.py)
    mean = res.image @ [0.2126, 0.7152, 0.0722]
    rel = np.sqrt(res.lum_var / res.sample_count) / np.sqrt(mean * mean + 0.1 ** 2)
    np.testing.assert_allclose(main.channel("relerr")[..., 0], rel, rtol=1e-4, atol=1e-6)
    assert np.array_equal(srv.images["cbox seed 3 filtered"].channel("R", "G", "B"), res.filtered)
    assert np.array_equal(srv.images["cbox seed 3 raw"].channel("R", "G", "B"), res.image)
    srv.close()


@needs_tevclient
def test_tev_sends_only_the_tiles_whose_samples_changed():
    srv = TevServer()
    viewer = TevViewer("x", srv.address, tile=8)  # 5 x 3 tiles
    count = np.ones((H, W), np.uint32)
    img = np.full((H, W, 3), 0.5, np.float32)

    def send(n, final=False):
        viewer(RenderUpdate(spp_done=1, spp_total=4, elapsed=0.0, stats=None, final=final, image=img.copy(),
                            sample_count=count.copy(), lum_var=np.zeros((H, W), np.float32)))
        deadline = time.monotonic() + 10
        while viewer.updates < n and time.monotonic() < deadline:  # sent before the next one replaces it
            time.sleep(0.01)

    send(1)
    count[9:11, 17] += 1  # in the tile at x 16-23, y 8-15
    img[9:11, 17] = 2.0
    send(2)
    send(3, final=True)
    viewer.close()
    srv.wait()
    ups = srv.updates("x")
    assert len(ups) == 15 + 1 + 15  # all tiles, the one that changed, then all of the final
    assert (ups[15]["x"], ups[15]["y"], ups[15]["width"], ups[15]["height"]) == (16, 8, 8, 8)
    assert np.array_equal(srv.images["x"].channel("R", "G", "B"), img)
    srv.close()


@needs_tevclient
def test_no_viewer_listening_one_warning_and_the_render_goes_on(cbox):
    messages = []
    viewer = TevViewer("cbox", f"127.0.0.1:{free_port()}", warn=messages.append)
    res = many_passes(cbox, spp=8, on_update=viewer)
    viewer.close()
    assert len(messages) == 1 and "no tev viewer at 127.0.0.1:" in messages[0]
    assert not viewer.connected and viewer.updates == 0
    assert np.array_equal(res.image, many_passes(cbox, spp=8).image)
    with pytest.warns(RuntimeWarning, match="no tev viewer"):
        TevViewer("cbox", f"127.0.0.1:{free_port()}").close()


@needs_tevclient
def test_viewer_closing_mid_render_does_not_stop_it(cbox):
    srv = TevServer(close_after=3)  # the create and two tiles, then it is gone
    messages = []
    viewer = TevViewer("cbox", srv.address, warn=messages.append, tile=16)

    def on_update(u):
        viewer(u)
        if u.spp_done == 1:
            srv.wait()  # the viewer is gone while the render has 47 passes to go

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = many_passes(cbox, spp=48, on_update=on_update)
    viewer.close()
    srv.wait()
    assert len(srv.packets) == 3
    assert np.array_equal(res.image, many_passes(cbox, spp=48).image) and res.spp == 48
    assert len(messages) == 1 and "went away" in messages[0], messages
    srv.close()


@needs_tevclient
def test_cli_streams_to_tev(tmp_path, capsys):
    from clpt.cli import main
    from clpt.image import load_image

    srv = TevServer()
    out = tmp_path / "c.exr"
    assert main(["render", "cornell_box", "--spp", "4", "--width", str(W), "--height", str(H), "--seed", "5",
                 "--tev", srv.address, "-o", str(out), "-q"]) == 0
    srv.wait()
    img = srv.images["cornell_box seed 5"]
    assert np.array_equal(img.channel("R", "G", "B"), load_image(out)[..., :3])
    assert main(["render", "cornell_box", "--spp", "1", "--width", "8", "--height", "8",
                 "--tev", f"127.0.0.1:{free_port()}", "-o", str(tmp_path / "d.png"), "-q"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clpt: warning: no tev viewer at 127.0.0.1:")
    with pytest.raises(SystemExit) as e:
        main(["render", "--tev", "host:99999"])
    assert e.value.code == 2
    srv.close()


def test_parse_address():
    assert parse_address("127.0.0.1:14158") == ("127.0.0.1", 14158)
    assert parse_address("viewer") == ("viewer", 14158)
    assert parse_address(":9000") == ("127.0.0.1", 9000)
    assert parse_address("[::1]:9000") == ("::1", 9000)
    for bad in ("a:b", "a:0", "a:70000", "::1", "[::1"):
        with pytest.raises(ValueError, match="tev address"):
            parse_address(bad)


# --- notebooks ------------------------------------------------------------------


def _png_chunks(data: bytes):
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    i, out = 8, []
    while i < len(data):
        (n,) = struct.unpack(">I", data[i:i + 4])
        kind, body = data[i + 4:i + 8], data[i + 8:i + 8 + n]
        (crc,) = struct.unpack(">I", data[i + 8 + n:i + 12 + n])
        assert crc == zlib.crc32(kind + body), kind
        out.append((kind, body))
        i += 12 + n
    return out


def test_repr_png_is_a_valid_png_of_the_right_size_tone_mapped_as_saved(cbox, tmp_path):
    from clpt.image import load_image

    res = cbox.render(2, width=W, height=H)
    png = res._repr_png_()
    chunks = _png_chunks(png)
    assert [k for k, _ in chunks] == [b"IHDR", b"IDAT", b"IEND"]
    w, h, depth, color = struct.unpack(">IIBB", chunks[0][1][:10])
    assert (w, h, depth, color) == (W, H, 8, 2)
    (tmp_path / "r.png").write_bytes(png)  # OpenImageIO reads it, and it is the PNG save() writes
    res.save(tmp_path / "s.png")
    assert np.array_equal(load_image(tmp_path / "r.png"), load_image(tmp_path / "s.png"))


def test_live_view_updates_in_place(cbox):
    pytest.importorskip("IPython", reason="the notebook display needs IPython")
    from IPython.core.interactiveshell import InteractiveShell
    from clpt.notebook import LiveView, side_by_side

    shell = InteractiveShell.instance()
    published = []
    shell.display_pub.publish = lambda data, metadata=None, **kw: published.append((data, kw))
    try:
        view = LiveView(widgets=False, title="cbox")
        res = many_passes(cbox, spp=6, on_update=view)
    finally:
        InteractiveShell.clear_instance()
    first, updates = published[:2], published[2:]
    assert all(not kw.get("update") for _, kw in first)
    ids = {kw["transient"]["display_id"] for _, kw in first}
    assert len(ids) == 2 and updates and all(kw.get("update") and kw["transient"]["display_id"] in ids
                                             for _, kw in updates)
    pngs = [d["image/png"] for d, _ in updates if "image/png" in d]
    assert len(pngs) == view.updates
    assert "done: 6/6 spp" in updates[-1][0]["text/html"]
    html = side_by_side([res, res.image], ["a", "b"]).data
    assert html.count("<img") == 2 and "<figcaption" in html


@needs_tevclient
def test_one_viewer_for_renders_of_two_sizes_creates_the_image_anew(cbox_aux):
    srv = TevServer()
    viewer = TevViewer("v", srv.address)
    cbox_aux.render(2, width=W, height=H, on_update=viewer)
    res = cbox_aux.render(2, width=16, height=8, on_update=viewer)
    viewer.close()
    srv.wait()
    creates = [p for p in srv.packets if p["type"] == "create"]
    assert [(p["width"], p["height"]) for p in creates] == [(W, H), (16, 8)]
    assert all(len(p["channels"]) == 11 for p in creates)
    assert np.array_equal(srv.images["v"].channel("R", "G", "B"), res.image)
    srv.close()


@pytest.mark.parametrize("mode", ["merge", "offline"])
def test_updates_of_photon_renders_are_the_renders_so_far(device_spec, mode):
    """Photon merging (its default, progressive maps) and the offline caustic
    buffer: each update is the image of the samples it counts."""
    r = clpt.Renderer("cornell_box_caustics", device=device_spec)
    ps = clpt.PhotonSettings(count=2000, mode=mode, offline_spp=2, spp_per_map=2)
    ups = []
    res = many_passes(r, spp=8, photons=ps, on_update=ups.append)
    assert ups[-1].final and np.array_equal(ups[-1].image, res.image)
    mid = [u for u in ups[:-1] if 2 <= u.spp_done < 8]
    assert mid
    u = mid[0]
    assert np.array_equal(u.image, r.render(u.spp_done, width=W, height=H, seed=3, photons=ps).image)
