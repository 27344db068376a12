"""A stand-in for the tev viewer: listens like tev, decodes its IPC packets
and keeps the images they build, so tests can check what a client sent.

The decoder follows tev's published packet layouts (tev's Ipc.h/Ipc.cpp):
every packet is a little-endian uint32 total length (counting these 4
bytes), a type byte, then the fields of its type; strings end with a NUL.

- 4 create image: grab_focus u8, name, width i32, height i32, channel count
  i32, channel names;
- 6 update image: grab_focus u8, name, channel count i32, channel names, x,
  y, width, height i32, per channel an offset i64, per channel a stride i64,
  then float32 data: channel c of tile pixel (i, j) at offset_c + (j * width
  + i) * stride_c;
- 2 close image: name; 1 reload image: grab_focus u8, name; 7 open image:
  grab_focus u8, path, channel selector; 8 vector graphics (kept undecoded).
"""

from __future__ import annotations

import socket
import struct
import threading

import numpy as np

CREATE, UPDATE, CLOSE, RELOAD, OPEN, VECTOR = 4, 6, 2, 1, 7, 8


class _Reader:
    def __init__(self, body: bytes):
        self.b, self.i = body, 0

    def take(self, fmt):
        v = struct.unpack_from("<" + fmt, self.b, self.i)
        self.i += struct.calcsize("<" + fmt)
        return v if len(v) > 1 else v[0]

    def string(self):
        end = self.b.index(b"\0", self.i)
        s = self.b[self.i:end].decode("utf-8")
        self.i = end + 1
        return s

    def rest(self):
        return self.b[self.i:]


def decode(packet: bytes) -> dict:
    """One packet (with its length prefix) -> a dict of its fields."""
    (length,) = struct.unpack_from("<I", packet)
    assert length == len(packet), (length, len(packet))
    r = _Reader(packet[4:])
    kind = r.take("B")
    if kind == CREATE:
        focus, name = r.take("B"), r.string()
        w, h, n = r.take("iii")
        return {"type": "create", "focus": bool(focus), "name": name, "width": w, "height": h,
                "channels": [r.string() for _ in range(n)]}
    if kind == UPDATE:
        focus, name = r.take("B"), r.string()
        n = r.take("i")
        channels = [r.string() for _ in range(n)]
        x, y, w, h = r.take("iiii")
        offsets = [r.take("q") for _ in range(n)]
        strides = [r.take("q") for _ in range(n)]
        data = np.frombuffer(r.rest(), dtype="<f4")
        if offsets == list(range(n)) and strides == [n] * n:  # interleaved channels: a plain reshape
            tile = data[:w * h * n].reshape(h, w, n)
        else:
            pix = np.arange(w * h)
            tile = np.empty((h, w, n), dtype=np.float32)
            for c in range(n):
                tile[:, :, c] = data[offsets[c] + pix * strides[c]].reshape(h, w)
        return {"type": "update", "focus": bool(focus), "name": name, "channels": channels, "x": x, "y": y,
                "width": w, "height": h, "data": tile}
    if kind == CLOSE:
        return {"type": "close", "name": r.string()}
    if kind == RELOAD:
        return {"type": "reload", "focus": bool(r.take("B")), "name": r.string()}
    if kind == OPEN:
        focus = bool(r.take("B"))
        return {"type": "open", "focus": focus, "path": r.string(), "selector": r.string()}
    return {"type": "vector" if kind == VECTOR else f"unknown {kind}"}


class Image:
    def __init__(self, width, height, channels):
        self.width, self.height, self.channels = width, height, list(channels)
        self.data = np.full((height, width, len(channels)), np.nan, dtype=np.float32)
        self.covered = np.zeros((height, width), dtype=bool)

    def channel(self, *names):
        return np.stack([self.data[:, :, self.channels.index(n)] for n in names], axis=-1)


class TevServer:
    """Listens on 127.0.0.1 (a free port); `packets` are the decoded packets in
    order, `images` what they built. close_after=N closes the connection
    after N packets, as a viewer that is shut mid-render; forever=True
    serves one connection after another (and keeps only the last packets)."""

    def __init__(self, close_after: int | None = None, forever: bool = False):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(4)
        self.port = self.sock.getsockname()[1]
        self.address = f"127.0.0.1:{self.port}"
        self.close_after, self.forever = close_after, forever
        self.packets, self.images, self.errors = [], {}, []
        self.connections = 0
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.connections += 1
            self._read(conn)
            self._done.set()
            if not self.forever:
                return

    def _read(self, conn):
        buf, start = bytearray(), 0  # unread bytes are buf[start:]
        with conn:
            while self.close_after is None or len(self.packets) < self.close_after:
                chunk = conn.recv(1 << 20)
                if not chunk:
                    break
                del buf[:start]
                start = 0
                buf += chunk
                while len(buf) - start >= 4:
                    (length,) = struct.unpack_from("<I", buf, start)
                    if len(buf) - start < length:
                        break
                    try:
                        self._apply(decode(bytes(buf[start:start + length])))
                    except Exception as e:  # noqa: BLE001 - reported by the test
                        self.errors.append(e)
                    start += length
                    if self.close_after is not None and len(self.packets) >= self.close_after:
                        break

    def _apply(self, p):
        self.packets.append(p)
        if self.forever and len(self.packets) > 1000:
            del self.packets[:500]
        if p["type"] == "create":
            self.images[p["name"]] = Image(p["width"], p["height"], p["channels"])
        elif p["type"] == "update":
            img = self.images[p["name"]]
            x, y, w, h = p["x"], p["y"], p["width"], p["height"]
            assert 0 <= x and 0 <= y and x + w <= img.width and y + h <= img.height, "tile outside the image"
            idx = [img.channels.index(c) for c in p["channels"]]
            img.data[y:y + h, x:x + w][:, :, idx] = p["data"]
            img.covered[y:y + h, x:x + w] = True

    def wait(self, timeout=10.0):
        """Until the client has closed the connection (or close_after was reached)."""
        assert self._done.wait(timeout), "the tev client did not close the connection"
        return self

    def close(self):
        self.sock.close()

    def updates(self, name=None):
        return [p for p in self.packets if p["type"] == "update" and (name is None or p["name"] == name)]


if __name__ == "__main__":  # a viewer of its own process, for benchmarks: prints its port, serves until killed
    import sys
    import time

    server = TevServer(forever=True)
    print(server.port, flush=True)
    while True:
        time.sleep(3600)
