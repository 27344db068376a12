"""Stream a render to the tev HDR viewer (https://github.com/Tom94/tev) while it runs.

    viewer = TevViewer("cornell_box seed 0", cpu_device=True)  # tev listens on 127.0.0.1:14158
    res = renderer.render(256, on_update=viewer, update_interval=UPDATE_INTERVAL)  # up to ~4 updates a second
    viewer.close()                                               # after the final image is sent

The image is created once in tev, with the channels R, G, B, spp (samples
per pixel), relerr (each pixel's relative error) and, when the Renderer has
feature buffers, albedo.R/G/B and normal.X/Y/Z (sent with the first, every
8th and the final update: they settle within a few samples). Each update
sends only the tiles whose samples changed; the final update sends the
final image (the filtered one when a filter was asked for) and, with a filter, the filtered
and raw images as images of their own. Packets are built by tevclient, tev's
own Python client; the sending runs in a thread of its own, which also turns
the render's copy of the device sums into images, so that the render thread
only queues that copy. That thread runs at a lower priority than the render
and takes at most CPU_SHARE of the CPU time the render gets (with
cpu_device, the process's measured CPU rate; else the cores): on a busy
machine it sends less often. When no viewer listens, or the viewer goes
away, one warning is given and the render goes on without it.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import time
import warnings

import numpy as np

DEFAULT_ADDRESS = "127.0.0.1:14158"
TILE = 64
UPDATE_INTERVAL = 0.2  # with passes of about 0.25 s (the default), an update after every pass: ~4 a second
CPU_SHARE = 0.015  # of the CPU time the render gets, at most, for the sending thread
AUX_EVERY = 8
NICER = 10  # the sending thread's niceness above the render's


def _cpu_count() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


def parse_address(text: str) -> tuple[str, int]:
    """'HOST:PORT', 'HOST', ':PORT' or '[IPv6]:PORT' -> (host, port); defaults 127.0.0.1 and 14158."""
    host, port = "127.0.0.1", 14158
    text = str(text).strip()
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            raise ValueError(f"tev address {text!r}: missing ']'")
        host, rest = text[1:end], text[end + 1:]
        if rest and not rest.startswith(":"):
            raise ValueError(f"tev address {text!r}: expected [HOST]:PORT")
        port_text = rest[1:] if rest else ""
    elif text.count(":") == 1:
        host_text, port_text = text.split(":")
        host = host_text or host
    elif ":" in text:
        raise ValueError(f"tev address {text!r}: write IPv6 hosts as [HOST]:PORT")
    else:
        host, port_text = text or host, ""
    if port_text:
        if not port_text.isdigit() or not 0 < int(port_text) < 65536:
            raise ValueError(f"tev address {text!r}: the port must be a number from 1 to 65535")
        port = int(port_text)
    return host, port


def _packets():
    try:
        from tevclient import packet  # optional (clpt[tev]): imported when a viewer connects
    except ImportError:
        raise ImportError("streaming to tev needs the tevclient package: pip install 'clpt[tev]'") from None
    return packet


def _tile_sums(a: np.ndarray, tile: int) -> np.ndarray:
    """Sums of a (H, W) array over tile x tile blocks."""
    rows = np.add.reduceat(a.astype(np.float64), np.arange(0, a.shape[0], tile), axis=0)
    return np.add.reduceat(rows, np.arange(0, a.shape[1], tile), axis=1)


class TevViewer:
    """An on_update for Renderer.render that streams the render to tev.

    name: the image's name in tev; address: 'HOST:PORT' (default
    127.0.0.1:14158); warn(message): called once if there is no viewer or it
    goes away (default: warnings.warn); connect_timeout, send_timeout:
    seconds to wait for the connection, or for a send, before the viewer
    counts as gone; cpu_device: the render runs on a CPU device (its share of
    the CPU is then measured, not assumed). One viewer follows one render at
    a time; a render of another size creates the image anew.
    """

    def __init__(self, name: str, address: str = DEFAULT_ADDRESS, *, warn=None, connect_timeout: float = 2.0,
                 send_timeout: float = 10.0, tile: int = TILE, cpu_device: bool = False):
        self._packet = _packets()
        if not isinstance(name, str) or not name or "\0" in name:
            raise ValueError(f"tev image name must be a non-empty string (got {name!r})")
        if not isinstance(tile, int) or tile < 1:
            raise ValueError(f"tev tile size must be an integer >= 1 (got {tile!r})")
        self.name, self.tile = name, tile
        self.host, self.port = parse_address(address)
        self._warn = warn or (lambda m: warnings.warn(m, RuntimeWarning, stacklevel=2))
        self.connect_timeout, self.send_timeout = connect_timeout, send_timeout
        self.cpu_device = bool(cpu_device)
        self.updates = self.tiles = self.bytes = 0
        self.send_seconds = 0.0
        self.cpu_seconds = 0.0  # the sending thread's CPU time
        self._first = self._last = None
        self._created = None  # the (height, width) of the image created in tev
        self._sent_counts = None
        self._pending = None
        self._closing = False
        self._cond = threading.Condition()
        self._thread = None
        self._sock = self._connect()

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def _connect(self):
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except OSError as e:
            self._warn(f"no tev viewer at {self.host}:{self.port} ({e.strerror or e}); rendering without it")
            return None
        sock.settimeout(self.send_timeout)
        return sock

    def __call__(self, update):
        """Take the render's latest update; the sending thread sends the newest one it has."""
        if self._sock is None:
            return
        with self._cond:
            # An earlier render's final image is never replaced before it is taken.
            while self._pending is not None and self._pending.final and self._sock is not None:
                self._cond.wait(0.1)
            self._pending = update
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="clpt-tev", daemon=True)
                self._thread.start()
            self._cond.notify()

    def close(self, timeout: float | None = 30.0):
        """Send what is pending (the final image), then close the connection."""
        with self._cond:
            self._closing = True
            self._cond.notify()
            thread = self._thread
        if thread is not None:
            thread.join(timeout)
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def rate(self) -> float:
        """Updates sent per second, between the first and the last."""
        if self.updates < 2:
            return 0.0
        return (self.updates - 1) / max(self._last - self._first, 1e-9)

    def summary(self) -> str:
        return (f"tev: {self.updates} updates ({self.rate():.1f}/s), {self.tiles} tiles, "
                f"{self.bytes / 2**20:.1f} MiB, {self.send_seconds:.2f}s sending")

    def _budget(self, wall0, cpu0) -> float:
        """CPU seconds per second the thread may take: CPU_SHARE of the
        machine's cores, or, for a render on a CPU device, of the CPU time
        the process has been getting (less than every core on a busy machine)."""
        cores = _cpu_count()
        if not self.cpu_device:
            return CPU_SHARE * cores
        rate = (time.process_time() - cpu0) / max(time.perf_counter() - wall0, 1e-9)
        return CPU_SHARE * min(max(rate, 0.1), cores)

    def _run(self):
        # The thread takes at most CPU_SHARE of the CPU, and at a lower priority
        # than the render's: on a CPU device what it takes is taken from the render.
        with contextlib.suppress(AttributeError, OSError):  # Linux sets a thread's own niceness
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(),
                           min(os.getpriority(os.PRIO_PROCESS, 0) + NICER, 19))
        wall0, cpu0 = time.perf_counter(), time.process_time()
        ready = 0.0  # when the thread may send again

        def due():
            u = self._pending
            return self._closing or (u is not None and (u.final or time.perf_counter() >= ready))

        while True:
            with self._cond:
                while not due():
                    self._cond.wait(None if self._pending is None else max(ready - time.perf_counter(), 1e-3))
                update, self._pending = self._pending, None
                self._cond.notify_all()
            if update is None:
                return
            t0, c0 = time.perf_counter(), time.thread_time()
            try:
                self._send(update)
            except OSError as e:
                self._warn(f"the tev viewer at {self.host}:{self.port} went away ({e.strerror or e}); "
                           f"rendering on without it")
                with self._cond:
                    self._sock.close()
                    self._sock = None
                    self._pending = None
                return
            now = time.perf_counter()
            self.send_seconds += now - t0
            cpu = time.thread_time() - c0
            self.cpu_seconds += cpu
            ready = t0 + cpu / self._budget(wall0, cpu0)
            self._first = now if self._first is None else self._first
            self._last = now
            self.updates += 1

    def _check_open(self):
        """tev sends nothing back: a readable socket means the viewer closed it."""
        readable, _, _ = select.select([self._sock], [], [], 0)
        if readable and not self._sock.recv(4096):
            raise ConnectionResetError(104, "closed by the viewer")

    def _layers(self, update, with_aux: bool) -> tuple[list, np.ndarray]:
        img = update.display_image() if update.final else update.image
        names = ["R", "G", "B", "spp", "relerr"]
        planes = [img, update.sample_count[..., None], update.relative_error()[..., None]]
        if with_aux and update.aux is not None:
            names += ["albedo.R", "albedo.G", "albedo.B", "normal.X", "normal.Y", "normal.Z"]
            planes += [update.aux["albedo"], update.aux["normal"]]
        return names, np.concatenate([np.asarray(p, dtype=np.float32) for p in planes], axis=2)

    def _tiles(self, name, data, channels, which=None):
        h, w = data.shape[:2]
        t = self.tile
        out = []
        for ty, y in enumerate(range(0, h, t)):
            for tx, x in enumerate(range(0, w, t)):
                if which is None or which[ty, tx]:
                    out.append(self._packet.update_image(name, data[y:y + t, x:x + t], channels, x, y))
        self.tiles += len(out)
        return out

    def _send(self, update):
        self._check_open()
        p = self._packet
        h, w = update.shape
        create = self._created != (h, w)
        # The feature buffers settle within a few samples: their layers go out
        # when the image is created, with every AUX_EVERY-th update and the final one.
        channels, data = self._layers(update, create or update.final or self.updates % AUX_EVERY == 0)
        out = []
        if create:
            out.append(p.create_image(self.name, w, h, channels, grab_focus=True))
            self._created, self._sent_counts = (h, w), None
        sums = _tile_sums(update.sample_count, self.tile)
        changed = None if (update.final or self._sent_counts is None) else sums != self._sent_counts
        self._sent_counts = sums
        out += self._tiles(self.name, data, channels, changed)
        if update.final and update.filtered is not None:
            for tag, img in (("filtered", update.filtered), ("raw", update.image)):
                name = f"{self.name} {tag}"
                out.append(p.create_image(name, w, h, ["R", "G", "B"], grab_focus=False))
                out += self._tiles(name, np.asarray(img, dtype=np.float32), ["R", "G", "B"])
        payload = b"".join(out)
        self._sock.sendall(payload)
        self.bytes += len(payload)
