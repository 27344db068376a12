"""Options that several subcommands share, each defined once: its flags,
type, and the default and help most commands give it. A command may give
another default or help text (`common.size(p, 128, 128)`,
`common.device(p, help=...)`)."""

from __future__ import annotations


def _option(*flags, **base):
    """add(parser, **overrides): the option added to parser (or a group)."""
    def add(p, **override):
        return p.add_argument(*flags, **{**base, **override})
    return add


DEVICE_HELP = ("device index, platform:device, name substring, 'all', or a comma list (default: PYOPENCL_CTX, a "
               "GPU, else the CPU runtime measured fastest for the scene that renders here; see clpt devices -v)")

device = _option("--device", "-d", default=None)
width = _option("--width", type=int)
height = _option("--height", type=int)
spp = _option("--spp", type=int)
seed = _option("--seed", type=int)
max_depth = _option("--max-depth", type=int)
rounds = _option("--rounds", type=int)
output = _option("-o", "--output", help="image file: .png, .jpg (8-bit sRGB) or .exr (linear float); "
                                        "default <scene>.png")
json = _option("--json", action="store_true")
reference = _option("--reference", default=None)
ref_spp = _option("--ref-spp", type=int, default=16384)
ref_dir = _option("--ref-dir", default=".clpt-references", help="where references are cached")
no_nee = _option("--no-nee", action="store_true")
sampler = _option("--sampler", choices=("stratified", "independent"), default=None,
                  help="each pixel's camera positions and first-vertex decisions from scrambled (0,2)-sequences "
                       "(stratified, the default) or every number independent")


def counts(text: str) -> list[int]:
    """argparse type: a comma list of counts ("1e5,1e6"; empty: none), each >= 0."""
    import argparse

    try:
        out = [int(float(c)) for c in text.split(",") if c.strip()]
    except (ValueError, OverflowError):
        raise argparse.ArgumentTypeError(f"expected a comma list of counts such as 1e5,1e6 (got {text!r})") from None
    if any(c < 0 for c in out):
        raise argparse.ArgumentTypeError(f"counts must be >= 0 (got {text!r})")
    return out


def seconds(text: str) -> list[float]:
    """argparse type: a comma list of times in seconds ("4,16"), each > 0."""
    import argparse
    import math

    try:
        out = [float(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a comma list of seconds such as 4,16 (got {text!r})") from None
    if not out or not all(math.isfinite(s) and s > 0 for s in out):
        raise argparse.ArgumentTypeError(f"times must be finite and > 0 (got {text!r})")
    return out


def size(p, w=None, h=None):
    """--width and --height, with their defaults (None: the scene's)."""
    width(p, default=w)
    height(p, default=h)


def scene_params(p):
    """-D NAME=VALUE and --strict: a Mitsuba XML scene's parameters."""
    p.add_argument("-D", "--param", action="append", default=[], metavar="NAME=VALUE",
                   help="set a Mitsuba XML scene parameter ($NAME), overriding its <default> (repeatable)")
    p.add_argument("--strict", action="store_true", help="Mitsuba XML: treat every import warning as an error")


def scene_params_dict(a) -> dict:
    from ..scene import SceneError

    params = {}
    for item in a.param:
        name, eq, value = item.partition("=")
        if not eq or not name.strip():
            raise SceneError(f"-D {item}: expected NAME=VALUE")
        params[name.strip()] = value
    return params


def load(a):
    """The scene named by a.scene, with -D's parameters and --strict."""
    from ..loading import load_scene

    return load_scene(a.scene, scene_params_dict(a), strict=a.strict)


def warn(msg):
    import sys

    print(f"clpt: warning: {msg}", file=sys.stderr)
