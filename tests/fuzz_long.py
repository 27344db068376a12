"""A long fuzz run of every file clpt reads and of `clpt render` options,
counted by reader and outcome.

    nice -n 19 python tests/fuzz_long.py --inputs 10000 [--readers xml,obj,ply,checkpoint]
        [--render-every 20] [--device intel] [--json out.json]
    nice -n 19 python tests/fuzz_long.py --minutes 10

The same inputs and checks as tests/test_fuzz*.py (tests/fuzzing.py): for
each reader in turn, a chunk of inputs (a new hypothesis seed per chunk) is
written to a file and checked; every render_every-th input that loads is also
rendered (4x4, 1 spp, the generic kernel; checkpoints resumed). It stops when
every reader has had --inputs inputs, or after --minutes. Prints the counts
by reader and outcome and every failure: an input neither loaded right nor
refused with a one-line error naming the file and the place. Each input has a
time limit (SIGALRM), so a hang counts as a failure, and the process's peak
memory is watched, so a blow-up does too.
"""

import argparse
import atexit
import collections
import json
import os
import resource
import shutil
import signal
import sys
import tempfile
import time
import traceback
from pathlib import Path

if "CLPT_CACHE_DIR" not in os.environ:  # a build cache of its own, removed at exit
    os.environ["CLPT_CACHE_DIR"] = tempfile.mkdtemp(prefix="clpt-fuzz-cache-")
    atexit.register(shutil.rmtree, os.environ["CLPT_CACHE_DIR"], ignore_errors=True)
os.environ.setdefault("CLPT_TUNE", "query")
sys.path.insert(0, str(Path(__file__).resolve().parent))

from hypothesis import HealthCheck, given, seed, settings  # noqa: E402

import fuzzing  # noqa: E402
from test_fuzz import run_main  # noqa: E402

CHUNK = 200  # inputs per hypothesis run


class Hang(BaseException):
    """An input over its time limit (a BaseException, so that no check's
    `except Exception` takes it for the input's own error)."""


def _alarm(signum, frame):
    raise Hang()


def peak_rss_bytes() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--readers", default=",".join([*fuzzing.READERS, "cli"]),
                    help=f"comma-separated: {', '.join(fuzzing.READERS)}, cli")
    ap.add_argument("--inputs", type=int, default=None, help="stop once every reader has had this many")
    ap.add_argument("--minutes", type=float, default=None, help="stop after this long (default 10 without --inputs)")
    ap.add_argument("--render-every", type=int, default=20, help="render every N-th input that loads (0: never)")
    ap.add_argument("--device", default=os.environ.get("CLPT_TEST_DEVICE"), help="--device for the renders")
    ap.add_argument("--timeout", type=int, default=60, help="seconds one input may take")
    ap.add_argument("--max-rss-gib", type=float, default=6.0, help="peak memory that counts as a blow-up")
    ap.add_argument("--first-seed", type=int, default=1, help="hypothesis seed of the first chunk (then +1 each): "
                                                            "another first seed, other inputs")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    if a.inputs is None and a.minutes is None:
        a.minutes = 10.0
    names = [n for n in a.readers.split(",") if n]
    for n in names:
        if n not in fuzzing.READERS and n != "cli":
            ap.error(f"unknown reader {n!r}")
    counts = collections.Counter()
    tried = collections.Counter()
    failures = []
    signal.signal(signal.SIGALRM, _alarm)
    t0 = time.monotonic()
    t_end = t0 + a.minutes * 60 if a.minutes else float("inf")
    loaded = collections.Counter()
    max_rss = a.max_rss_gib * 2 ** 30

    def guarded(kind, fn, what):
        tried[kind] += 1
        signal.alarm(a.timeout)
        try:
            outcome = fn()
            counts[(kind, outcome)] += 1
        except fuzzing.Failure as e:
            counts[(kind, "FAILURE")] += 1
            where = ""
            if e.__cause__ is not None:  # an exception where a refusal was due: where it was raised
                tb = traceback.extract_tb(e.__cause__.__traceback__)[-3:]
                where = " [" + "; ".join(f"{Path(f.filename).name}:{f.lineno} {f.line}" for f in tb) + "]"
            failures.append(f"{kind}: {str(e)[:1500]}{where} for {what!r}"[:2500])
        except Hang:
            counts[(kind, f"HANG (> {a.timeout} s)")] += 1
            failures.append(f"{kind}: hang for {what!r}"[:2000])
        except Exception as e:  # noqa: BLE001 - the check itself broke: count it, go on
            counts[(kind, "FAILURE")] += 1
            failures.append(f"{kind}: {type(e).__name__}: {e} for {what!r}"[:2000])
        finally:
            signal.alarm(0)
        if peak_rss_bytes() > max_rss:
            counts[(kind, "MEMORY BLOW-UP")] += 1
            failures.append(f"{kind}: peak memory {peak_rss_bytes() / 2**30:.1f} GiB after {what!r}"[:2000])
            raise SystemExit(report(a, counts, tried, failures, t0))

    opts = settings(max_examples=CHUNK, deadline=None, suppress_health_check=list(HealthCheck), database=None)
    def command_run(tmp):
        @opts
        @given(cmd=fuzzing.command_lines())
        def commands(cmd):
            guarded("cli", lambda: fuzzing.check_command(cmd[0], cmd[1], tmp, run_main, device=a.device), cmd)
        return commands

    def file_run(reader, folder):
        @opts
        @given(data=reader.inputs())
        def files(data):
            p = folder / reader.filename
            p.write_bytes(data)

            def check():
                outcome = reader.check(p, render=False)
                if outcome != "refused" and a.render_every:
                    loaded[reader.name] += 1
                    if loaded[reader.name] % a.render_every == 0:
                        outcome = reader.check(p, render=True, device=a.device)
                return outcome
            guarded(reader.name, check, data[:300])
        return files

    runs = {n: command_run(Path(tempfile.mkdtemp(prefix="clpt-fuzz-cli-"))) if n == "cli"
            else file_run(fuzzing.READERS[n], fuzzing.READERS[n].workspace()) for n in names}

    chunk = a.first_seed - 1
    while time.monotonic() < t_end:
        todo = [n for n in names if a.inputs is None or tried[n] < a.inputs]
        if not todo:
            break
        chunk += 1
        for name in todo:
            seed(chunk)(runs[name])()
        print(f"{sum(tried.values())} inputs, {len(failures)} failures, {time.monotonic() - t0:.0f} s",
              file=sys.stderr, flush=True)
    return report(a, counts, tried, failures, t0)


def report(a, counts, tried, failures, t0) -> int:
    total = sum(tried.values())
    print(f"\n{total} inputs in {(time.monotonic() - t0) / 60:.1f} minutes (render every {a.render_every}-th "
          f"that loads; device {a.device or 'default'})")
    for kind in sorted(tried):
        print(f"  {kind}: {tried[kind]}")
        for (k, outcome), v in sorted(counts.items()):
            if k == kind:
                print(f"    {v:7d}  {outcome}")
    for f in failures[:20]:
        print("FAILURE:", f)
    if a.json:
        Path(a.json).write_text(json.dumps({"inputs": dict(tried), "counts": {f"{k}: {o}": v for (k, o), v in
                                                                                counts.items()},
                                            "failures": failures}, indent=1))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
