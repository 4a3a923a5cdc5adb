#!/usr/bin/env python3
"""Whether a change left the safety filter's results as they were: ``filter_command`` of
this tree against that of another git revision, over many varied calls.

    .venv/bin/python scripts/check_filter_same.py [--against main] [--count 3000]

The calls (``varied_cases``): the cases of ``scripts/bench_safety.py`` (6 robots, 1.5 m
apart) and random ones over several specs (1 to 3 discs, the robots' told commands and
estimated boxes, old poses, a window of poses, a P3-DX and a Husky), 1 to 8 robots heard
at any distance (some overlapping: infeasible pairs), commands in and out of the box.
Each tree runs in a child process of its own, plain Python (NUMBA_DISABLE_JIT=1, as a node
runs it) or, with ``--compiled``, the numba form. Prints the largest difference of the
commands and how many flags differ; exits 1 unless the flags are all equal and the
commands within ``--tol`` (default 0: bit for bit).
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def specs() -> list:
    """Filters of several bodies and settings (``model.safety.spec_for``)."""
    from formation_ilc.model.physics import MODELS
    from formation_ilc.model.safety import spec_for

    p3, husky = MODELS["p3dx"], MODELS["husky"]
    return [spec_for(p3.footprint, p3.limits, 0.1),
            spec_for(p3.footprint, p3.limits, 0.2, discs=1),
            spec_for(p3.footprint, p3.limits, 0.1, discs=3, pose_error=0.02,
                     pose_jitter=0.005, speed_uncertainty=0.05),
            spec_for(p3.footprint, p3.limits, 0.1, commands=True, heading_error=0.03,
                     noise=0.01, process=0.005),
            spec_for(husky.footprint, husky.limits, 0.1, stale_speed=0.0, margin=0.1),
            spec_for(husky.footprint, husky.limits, 0.05, commands=True, heading_error=0.1)]


def varied_cases(count: int, seed: int = 7) -> list[tuple]:
    """(spec index, args of ``filter_command`` but ``params`` and ``out``) per call."""
    sys.path.insert(0, str(ROOT / "scripts"))
    from bench_safety import cases

    from formation_ilc.core.safety import OTHER_FIELDS

    out = []
    for nominal, own, prev, others in cases(6, 2000):
        out.append((0, *nominal, *own, *prev, others, np.zeros(len(others)), len(others)))
    rng = np.random.default_rng(seed)
    n_specs = len(specs())
    for _ in range(count):
        n = int(rng.integers(1, 9))
        others = np.zeros((n, OTHER_FIELDS))
        spread = rng.choice([0.6, 1.5, 4.0])
        others[:, 0:2] = rng.normal(scale=spread, size=(n, 2))
        others[:, 2] = rng.uniform(-math.pi, math.pi, n)
        others[:, 3:5] = rng.normal(scale=rng.choice([0.05, 0.4]), size=(n, 2))
        others[:, 5] = rng.normal(scale=0.5, size=n)
        others[:, 6] = rng.random(n) < 0.5
        others[:, 7] = rng.choice([0.0, 0.01, 0.05], size=n)
        ages = rng.choice([0.0, 0.0, 0.1, 0.25], size=n)
        prev = rng.uniform(-1.0, 1.4), rng.uniform(-2.0, 2.0)
        step = rng.choice([0.02, 0.3])
        nominal = prev[0] + rng.normal(scale=step), prev[1] + rng.normal(scale=3 * step)
        own = rng.normal(scale=0.1), rng.normal(scale=0.1), rng.uniform(-math.pi, math.pi)
        out.append((int(rng.integers(n_specs)), *nominal, *own, *prev, others, ages, n))
    return out


def run(count: int, compiled: bool) -> tuple[np.ndarray, np.ndarray]:
    """This tree's filter over ``varied_cases(count)``: commands (N, 2) and flags (N,)."""
    from formation_ilc.core.safety import filter_command

    params = [sp.params() for sp in specs()]
    fn = filter_command.jit if compiled else filter_command
    data = varied_cases(count)
    cmd = np.zeros((len(data), 2))
    flags = np.zeros(len(data), dtype=np.int64)
    for i, (s, *args) in enumerate(data):
        flags[i] = fn(*args, params[s], cmd[i])
    return cmd, flags


def child(tree: Path, count: int, compiled: bool, dest: Path) -> None:
    """``run`` in a child process on the package of ``tree``, into ``dest`` (.npz)."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); "
            "import formation_ilc; assert formation_ilc.__file__.startswith(sys.argv[1]); "
            f"sys.path.insert(0, {str(ROOT / 'scripts')!r}); "
            "import check_filter_same as c, numpy as np; "
            "cmd, flags = c.run(int(sys.argv[2]), sys.argv[3] == '1'); "
            "np.savez(sys.argv[4], cmd=cmd, flags=flags)")
    env = {**os.environ, "NUMBA_DISABLE_JIT": "0" if compiled else "1"}
    subprocess.run([sys.executable, "-c", code, str(tree), str(count), str(int(compiled)),
                    str(dest)], env=env, check=True, cwd=tree)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--against", default="main", help="git revision to compare with")
    ap.add_argument("--count", type=int, default=3000, help="random calls (besides the "
                    "bench's 2000)")
    ap.add_argument("--compiled", action="store_true", help="the numba forms")
    ap.add_argument("--tol", type=float, default=0.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        ref = Path(tmp, "ref")
        ref.mkdir()
        arc = Path(tmp, "ref.tar")
        subprocess.run(["git", "archive", "-o", str(arc), args.against, "formation_ilc"],
                       cwd=ROOT, check=True)
        with tarfile.open(arc) as t:
            t.extractall(ref, filter="data")
        child(ref, args.count, args.compiled, Path(tmp, "old.npz"))
        child(ROOT, args.count, args.compiled, Path(tmp, "new.npz"))
        old, new = np.load(Path(tmp, "old.npz")), np.load(Path(tmp, "new.npz"))
        diff = float(np.abs(old["cmd"] - new["cmd"]).max())
        same = int((old["cmd"] == new["cmd"]).all(axis=1).sum())
        bad = int((old["flags"] != new["flags"]).sum())
        n = len(old["flags"])
        print(f"{n} calls against {args.against} ({'compiled' if args.compiled else 'plain'}"
              f"): commands bit for bit in {same}, largest difference {diff:.3g}; flags "
              f"differ in {bad}; flags: barrier {int((new['flags'] & 2 > 0).sum())}, "
              f"infeasible {int((new['flags'] & 4 > 0).sum())}")
        return 0 if bad == 0 and diff <= args.tol else 1


if __name__ == "__main__":
    sys.exit(main())
