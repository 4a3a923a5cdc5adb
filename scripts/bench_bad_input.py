#!/usr/bin/env python3
"""What hostile or mistaken input costs before it is refused, and what keeping a run's memory
costs (the figures behind the reliability notes).

Prints:
  * wall time and peak RSS of `formation-ilc check` refusing a YAML "billion laughs" and a
    binary file (each a fresh process: start-up included);
  * the same for a scenario of 10^9 samples (refused by the memory estimate);
  * ms to write memory.npz (atomic; with and without fsync) for both built-in scenarios,
    against their ms per trial, and the overhead of writing at most every 2 s;
  * the unicycle reference (paper-triangle3's leader) per sample: the step-by-step loop
    against the vectorised version (bit for bit equal).

Usage: python scripts/bench_bad_input.py [--repeats 50]
"""

from __future__ import annotations

import argparse
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core import trajectory as tr
from formation_ilc.model.simulate import simulate
from formation_ilc.store.memoryfile import save_memory

BOMB = "".join(f"{c}: &{c} [{', '.join([f'*{p}'] * 9)}]\n" for p, c in zip("abcdefgh", "bcdefghi",
                                                                             strict=True))
BOMB = 'a: &a ["lol","lol","lol","lol","lol","lol","lol","lol","lol"]\n' + BOMB + "name: *i\n"


_CHILD = """
import resource, runpy, sys
sys.argv = ["formation-ilc", "check", sys.argv[1]]
try:
    runpy.run_module("formation_ilc.cli", run_name="__main__")
except SystemExit as exc:
    status = exc.code
print(f"@@ {status} {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}", file=sys.stderr)
"""


def refusal(path: Path) -> tuple[float, float, str]:
    """(seconds, peak RSS MB, exit status and last error line) of `formation-ilc check PATH`."""
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", _CHILD, str(path)], capture_output=True,
                       text=True, timeout=600)
    took = time.perf_counter() - t0
    lines = r.stderr.strip().splitlines()
    status, peak = lines[-1].split()[1:]
    error = lines[-2] if len(lines) > 1 else ""
    return took, int(peak) / 1024, f"exit {status}: {error[:110]}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--dir", type=Path, default=Path("."),
                    help="where to write (the file system a run's --out is on; default .)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix=".bench-bad-input-", dir=args.dir))

    print("refusals (a fresh `formation-ilc check` process each):")
    (tmp / "bomb.yaml").write_text(BOMB)
    (tmp / "junk.yaml").write_bytes(np.random.default_rng(0).bytes(4096))
    text = load_scenario("paper-hexagon6").text
    (tmp / "huge.yaml").write_text(re.sub(r"^samples: *\d+", "samples: 1000000000", text,
                                          flags=re.M))
    for name in ("bomb.yaml", "junk.yaml", "huge.yaml"):
        took, peak, line = refusal(tmp / name)
        print(f"  {name:10s} {took:6.2f} s  peak RSS {peak:6.0f} MB  {line}")

    print("memory.npz writes (median of", args.repeats, "):")
    for scen in ("paper-triangle3", "paper-hexagon6"):
        sc = load_scenario(scen)
        simulate(sc, trials=2)  # compile / load the cache
        t0 = time.perf_counter()
        simulate(sc, trials=50)
        per_trial = (time.perf_counter() - t0) / 50 * 1000
        mem = np.random.default_rng(0).normal(size=(sc.n, sc.samples, 2))
        cost = {}
        for durable in (False, True):
            ts = []
            for i in range(args.repeats):
                t0 = time.perf_counter()
                save_memory(tmp / "memory.npz", mem, sc, i, durable=durable)
                ts.append(time.perf_counter() - t0)
            cost[durable] = statistics.median(ts) * 1000
        size = (tmp / "memory.npz").stat().st_size
        print(f"  {scen:16s} {size / 1024:5.1f} KiB: {cost[False]:6.2f} ms, with fsync "
              f"{cost[True]:6.2f} ms; a trial {per_trial:6.2f} ms; every trial would add "
              f"{100 * cost[True] / per_trial:5.0f} %, every 2 s adds "
              f"{100 * cost[True] / 2000:5.2f} %")

    print("unicycle reference (paper-triangle3's leader, dt 0.2):")
    v = tr.paper_ivb_speed
    w = lambda t: v(t) / 1.5  # noqa: E731
    for m in (300, 3000):
        t0 = time.perf_counter()
        a = tr._unicycle_reference_loop(v, w, m, 0.2)
        loop = (time.perf_counter() - t0) / m * 1e6
        t0 = time.perf_counter()
        b = tr.unicycle_reference(v, w, m, 0.2)
        vec = (time.perf_counter() - t0) / m * 1e6
        print(f"  {m:6d} samples: loop {loop:8.1f} us/sample, vectorised {vec:6.1f} us/sample, "
              f"equal: {np.array_equal(a, b)}")
    t0 = time.perf_counter()
    tr.unicycle_reference(v, w, 10 ** 6, 0.2)
    print(f"  10^6 samples vectorised: {time.perf_counter() - t0:.1f} s")
    shutil.rmtree(tmp)


if __name__ == "__main__":
    main()
