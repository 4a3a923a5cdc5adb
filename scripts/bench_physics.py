#!/usr/bin/env python3
"""Throughput of the physics plant in lockstep: samples per second and the real-time factor.

    .venv/bin/python scripts/bench_physics.py [--trials 2] [--models p3dx husky]
        [--rate 240] [--stack]

For 3 robots (paper-triangle3) and 6 (paper-hexagon6), each model: ``--trials`` noise-free
trials of the law against the PyBullet world in one process (``studies.physics.run_physics``:
every robot's command, then ``substeps`` engine steps per sample), timed inside the trial
loop. The real-time factor is simulated seconds per wall second: above 1 the plant keeps up
with a realtime run. The CPU columns divide by the process's CPU time instead (set-up
included): what one core gives when the machine is shared, as the wall figures are not.
``--stack`` also times a lockstep ``formation-ilc launch --plant
physics`` (one process per robot; its plant's own timing, from summary.json) for 3 robots.
Prints figures, asserts nothing: docs/physics.md has the measured numbers.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from formation_ilc.config.scenario import load_scenario, scenario_from_text  # noqa: E402
from formation_ilc.model.physics import MODELS, robot_model  # noqa: E402
from formation_ilc.studies.physics import run_physics  # noqa: E402


def spaced(name: str, factor: float):
    """A built-in scenario with its offsets scaled (a Husky's body needs room)."""
    sc = load_scenario(name)
    if factor == 1.0:
        return sc
    import yaml

    data = yaml.safe_load(sc.text)
    for off in data["formation"]["offsets"].values():
        off["x"] *= factor
        off["y"] *= factor
    return scenario_from_text(yaml.safe_dump(data), f"{name} (offsets x {factor})")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=2)
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=list(MODELS))
    ap.add_argument("--rate", type=float, default=240.0)
    ap.add_argument("--stack", action="store_true")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    print(f"{'model':6} {'robots':>6} {'substeps':>8} {'samples/s':>10} {'realtime x':>10} "
          f"{'CPU samples/s':>13} {'CPU realtime x':>14}")
    for model in args.models:
        for name in ("paper-triangle3", "paper-hexagon6"):
            # the memory must not drive robots into each other during the bench: no law,
            # only the engine would be too kind; a spaced formation learns without contact
            sc = spaced(name, 2.0 if model == "husky" else 1.0)
            quiet = sc.with_options(noise=False, delay=False)
            cpu0 = time.process_time()
            res = run_physics(quiet, robot_model(model), args.trials, rate=args.rate,
                              collide=False)
            cpu = time.process_time() - cpu0  # the engine is one thread: one core's worth
            sps = res.samples / res.seconds
            sub = int(round(sc.dt * args.rate))
            print(f"{model:6} {sc.n:>6} {sub:>8} {sps:>10.1f} {sps * sc.dt:>10.2f} "
                  f"{res.samples / cpu:>13.1f} {res.samples / cpu * sc.dt:>14.2f}", flush=True)
    if args.stack:
        with tempfile.TemporaryDirectory() as tmp:
            short = Path(tmp) / "short.yaml"
            short.write_text(load_scenario("paper-triangle3").text.replace(
                "samples: 140", "samples: 60"))
            subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch", str(short),
                            "--plant", "physics", "--trials", "2", "--no-noise", "--no-delay",
                            "--links", "direct", "--no-plots", "--out", f"{tmp}/run"],
                           check=True, capture_output=True)
            timing = json.loads((Path(tmp) / "run" / "summary.json").read_text())["timing"]
            print(f"stack, lockstep, 3 x p3dx, one process per robot: "
                  f"{timing['samples_per_s']:.1f} samples/s, realtime x "
                  f"{timing['samples_per_s'] * 0.2:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
