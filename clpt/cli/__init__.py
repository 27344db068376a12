"""The clpt command line: render, the benchmarks and studies, devices,
scenes, check, cache; one module per subcommand (its parser and its run),
options that several share defined once in common.py.

The benchmarks' and studies' modules load their tools (clpt/tools/) only
when they run: `clpt render` loads none of them.

Exit codes: 0 done, 1 a device or kernel-build failure, 2 a mistake in the
command or the scene (reported in one line, never a traceback), 130
interrupted by Ctrl-C, 143 by SIGTERM, 129 by SIGHUP (a render still writes
the image it has so far, and a checkpoint to continue it from).
"""

from __future__ import annotations

import argparse
import sys
import warnings

from .. import __version__
from . import (bench, bench_builds, bench_bvh, bench_denoise, bench_photons, cache, check, compare, devices, render,
               scenes, tradeoff)

# In the order `clpt --help` lists them.
COMMANDS = (render, bench, bench_builds, bench_photons, bench_denoise, bench_bvh, compare, tradeoff, devices, scenes,
            check, cache)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="clpt", description="OpenCL path tracer with caustic photon mapping")
    ap.add_argument("--version", action="version", version=f"clpt {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return ap


def main(argv=None) -> int:
    from ..device import DeviceError
    from ..image import ImageError
    from ..program import KernelBuildError
    from ..scene import SceneError

    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return args.func(args)
    except SceneError as e:
        print(f"clpt: error: {e}", file=sys.stderr)
        return 2
    except (DeviceError, KernelBuildError, ImageError) as e:
        print(f"clpt: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("\nclpt: interrupted", file=sys.stderr)
        return 130


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Scene warnings as one line each, like the errors."""
    import pyopencl as cl

    from ..device import DeviceWarning
    from ..scene import SceneWarning

    if issubclass(category, cl.CompilerWarning):
        return  # compiler remarks are not the user's business (builds in threads can slip past program.build's filter)
    if issubclass(category, (SceneWarning, DeviceWarning)):
        print(f"clpt: warning: {message}", file=sys.stderr)
    else:
        print(warnings.formatwarning(message, category, filename, lineno, line), file=sys.stderr, end="")
