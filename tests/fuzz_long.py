"""A long fuzz run of scene files and `clpt render` options, counted by outcome.

    nice -n 19 python tests/fuzz_long.py --minutes 10 [--render-every 20] [--json out.json]

The same inputs and checks as tests/test_fuzz.py (tests/fuzzing.py), for as
long as asked: scene files are loaded and checked, every render_every-th one
is also rendered (4x4, 1 spp, the generic kernel), and command lines run
`clpt render` in this process. Prints the counts by outcome and every failure
(an input neither rendered right nor refused with a one-line error); each
input has a time limit (SIGALRM), so a hang counts as a failure too.
"""

import argparse
import collections
import json
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("CLPT_CACHE_DIR", tempfile.mkdtemp(prefix="clpt-fuzz-cache-"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from hypothesis import HealthCheck, given, seed, settings  # noqa: E402

import fuzzing  # noqa: E402
from test_fuzz import run_main  # noqa: E402


class Hang(Exception):
    pass


def _alarm(signum, frame):
    raise Hang()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--render-every", type=int, default=20)
    ap.add_argument("--cli-share", type=float, default=0.1, help="fraction of the inputs that are command lines")
    ap.add_argument("--timeout", type=int, default=60, help="seconds one input may take")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    counts = collections.Counter()
    failures = []
    tmp = Path(tempfile.mkdtemp(prefix="clpt-fuzz-"))
    signal.signal(signal.SIGALRM, _alarm)
    t_end = time.monotonic() + a.minutes * 60
    n = {"scene": 0}

    def guarded(kind, fn, what):
        signal.alarm(a.timeout)
        try:
            counts[f"{kind}: {fn()}"] += 1
        except fuzzing.Failure as e:
            counts[f"{kind}: FAILURE"] += 1
            failures.append(str(e)[:2000])
        except Hang:
            counts[f"{kind}: HANG (> {a.timeout} s)"] += 1
            failures.append(f"hang: {what!r}"[:2000])
        except Exception as e:  # noqa: BLE001 - the check itself broke: count it, go on
            counts[f"{kind}: FAILURE"] += 1
            failures.append(f"{type(e).__name__}: {e} for {what!r}"[:2000])
        finally:
            signal.alarm(0)

    opts = settings(max_examples=200, deadline=None, suppress_health_check=list(HealthCheck), database=None)

    @opts
    @given(text=fuzzing.scene_texts())
    def scenes(text):
        n["scene"] += 1
        p = tmp / "scene.toml"
        p.write_bytes(text)
        guarded("scene", lambda: fuzzing.check_scene_file(p, render=n["scene"] % a.render_every == 0), text[:300])

    @opts
    @given(cmd=fuzzing.command_lines())
    def commands(cmd):
        guarded("cli", lambda: fuzzing.check_command(cmd[0], cmd[1], tmp, run_main), cmd)

    chunk = 0
    while time.monotonic() < t_end:
        chunk += 1
        is_cli = (chunk * a.cli_share) % 1 + a.cli_share >= 1  # every 1/cli_share-th chunk
        seed(chunk)(commands if is_cli else scenes)()
        total = sum(counts.values())
        print(f"{total} inputs, {len(failures)} failures, {t_end - time.monotonic():.0f} s left", file=sys.stderr)
    total = sum(counts.values())
    print(f"\n{total} inputs in {a.minutes:g} minutes")
    for k, v in sorted(counts.items()):
        print(f"  {v:7d}  {k}")
    for f in failures[:20]:
        print("FAILURE:", f)
    if a.json:
        Path(a.json).write_text(json.dumps({"inputs": total, "counts": counts, "failures": failures}, indent=1))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
