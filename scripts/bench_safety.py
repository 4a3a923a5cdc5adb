#!/usr/bin/env python3
"""What the safety filter costs: per robot and sample, and on the physics plant.

    .venv/bin/python scripts/bench_safety.py [--robots 6] [--repeat 3] [--physics-trials 1]

(``--physics-trials 0`` leaves out section 2.)

1. The filter of one robot with ``--robots - 1`` others in range (every other robot within
   its sensing radius, in a formation 1.5 m apart, as in a hexagon of P3-DX-size robots;
   half the samples with the barrier binding): microseconds per call of
   ``core.safety.filter_command`` compiled by numba (``filter_command.jit``) and as plain
   Python (what a node runs: it loads no compiler), and of the robot's whole step as a node
   runs it, in CPU time of this process (a busy machine slows the wall clock, not this)
   (``RobotLearner._filter``: the poses heard, their motion, the filter). Target: at most
   100 us per sample per robot with 6 robots in range.
2. The physics plant with 6 robots through the filter (``studies.physics.run_physics``,
   hexagon6-p3dx, one process): samples per second and the real-time factor (simulated
   seconds per wall second; above 1 it keeps up with a realtime run), per wall second and
   per CPU second of the process.
3. Messages a sample costs the robots to hear each other: one ``team/poses`` from the plant
   to every robot (N deliveries of N poses), against every robot reading every other
   robot's pose (N (N - 1) deliveries), at 6, 24 and 50 robots.

Prints its figures and ratios; asserts nothing (docs/safety.md has the measured numbers).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from formation_ilc.core.clock import SampleClock  # noqa: E402
from formation_ilc.core.safety import OTHER_FIELDS, filter_command  # noqa: E402
from formation_ilc.model.physics import MODELS  # noqa: E402
from formation_ilc.model.safety import spec_for  # noqa: E402
from formation_ilc.studies.physics import run_physics  # noqa: E402

TARGET_US = 100.0
HEXAGON = ROOT / "docs" / "examples" / "hexagon6-p3dx.yaml"


def cases(n: int, count: int, seed: int = 1) -> list[tuple]:
    """``count`` filter calls of one robot with n - 1 others on a circle of 1.5 m spacing
    around it, random headings and motions, nominal commands near the previous ones."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        others = np.zeros((n - 1, OTHER_FIELDS))
        ang = np.linspace(0, 2 * math.pi, n - 1, endpoint=False) + rng.uniform(0, 1)
        rad = rng.uniform(0.9, 1.6, n - 1)
        others[:, 0] = rad * np.cos(ang)
        others[:, 1] = rad * np.sin(ang)
        others[:, 2] = rng.uniform(-math.pi, math.pi, n - 1)
        others[:, 3:5] = rng.normal(scale=0.3, size=(n - 1, 2))
        prev = rng.uniform(0.0, 0.8), rng.uniform(-0.5, 0.5)
        nominal = prev[0] + rng.uniform(-0.05, 0.05), prev[1] + rng.uniform(-0.1, 0.1)
        out.append((nominal, (0.0, 0.0, rng.uniform(-math.pi, math.pi)), prev, others))
    return out


def time_filter(fn, sp, data, repeat: int) -> tuple[float, float]:
    """(median us per call over ``repeat`` passes, share of calls the barrier bound)."""
    params = sp.params()
    out = np.zeros(2)
    ages = np.zeros(len(data[0][3]))
    bound = 0
    best = []
    for _ in range(repeat):
        t0 = time.process_time()
        for nominal, own, prev, others in data:
            f = fn(nominal[0], nominal[1], own[0], own[1], own[2], prev[0], prev[1], others,
                   ages, len(others), params, out)
            bound += bool(f & 2)
        best.append((time.process_time() - t0) / len(data) * 1e6)
    return float(np.median(best)), bound / (repeat * len(data))


def time_learner(n: int, sp, repeat: int) -> float:
    """us per sample of a robot's whole filter step (RobotLearner._filter) with n - 1
    others heard in lockstep, paper-triangle3's grid stretched to n robots' poses."""
    from formation_ilc.config.scenario import load_scenario
    from formation_ilc.model.simulate import Problem
    from formation_ilc.protocol.learner import RobotLearner

    sc = load_scenario(str(HEXAGON))
    pb = Problem.from_scenario(sc.for_plant("arc"), "arc", sp)
    clock = SampleClock.for_run(sc.dt, sc.samples)
    lrn = RobotLearner(pb, 0, clock, safety=sp)
    lrn.on_pose(clock.stamp_ns(0, 0), pb.eta_d[0, 0])
    samples = min(200, pb.samples)
    for t in range(samples + 1):
        for j in range(1, pb.n):
            lrn.on_team_pose(j, clock.stamp_ns(0, t), pb.eta_d[j, t])
    runs = []
    for _ in range(repeat):
        t0 = time.process_time()
        for t in range(1, samples):
            lrn.t = t
            lrn.u[0] = pb.eta_d[0, t, :2] * 0 + (0.5, 0.1)
            lrn._filter(t)
        runs.append((time.process_time() - t0) / (samples - 1) * 1e6)
    return float(np.median(runs))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--robots", type=int, default=6)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--physics-trials", type=int, default=1)
    ap.add_argument("--interpreted", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    m = MODELS["p3dx"]
    sp = spec_for(m.footprint, m.limits, 0.1)
    if args.interpreted:  # a child with NUMBA_DISABLE_JIT=1: every kernel plain Python
        py, _ = time_filter(filter_command, sp, cases(args.robots, 300), args.repeat)
        step = time_learner(args.robots, sp, args.repeat)
        print(f"{py} {step}")
        return 0
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")
    data = cases(args.robots, 2000)
    # the kernel is a plain function (what the nodes run); its compiled form is .jit
    filter_command.jit(*data[0][0], *data[0][1], *data[0][2], data[0][3],
                       np.zeros(args.robots - 1), args.robots - 1, sp.params(), np.zeros(2))
    jit, share = time_filter(filter_command.jit, sp, data, args.repeat)
    import subprocess

    child = subprocess.run([sys.executable, __file__, "--interpreted", "--robots",
                            str(args.robots), "--repeat", str(args.repeat)],
                           env={**os.environ, "NUMBA_DISABLE_JIT": "1"}, capture_output=True,
                           text=True, check=True)
    py, step = (float(x) for x in child.stdout.split()[-2:])
    print(f"\n1. the filter of one robot, {args.robots - 1} others in range (barrier binding "
          f"in {share:.0%} of the calls), per sample:")
    print(f"   filter_command, compiled (numba)   {jit:8.1f} us   target {TARGET_US:.0f} us: "
          f"{'MET' if jit <= TARGET_US else 'MISSED'} (ratio {jit / TARGET_US:.2f})")
    print(f"   filter_command, plain Python       {py:8.1f} us   target {TARGET_US:.0f} us: "
          f"{'MET' if py <= TARGET_US else 'MISSED'} (ratio {py / TARGET_US:.2f})")
    print(f"   a robot's whole step, plain Python {step:8.1f} us   target {TARGET_US:.0f} us: "
          f"{'MET' if step <= TARGET_US else 'MISSED'} (ratio {step / TARGET_US:.2f})")
    print(f"   (load average {os.getloadavg()[0]:.1f} after the plain-Python runs)")

    if args.physics_trials > 0:
        physics(args.physics_trials, m)
    print("\n3. hearing the team, messages per sample (deliveries):")
    print(f"   {'robots':>6} {'team/poses':>11} {'peers':>7} {'bytes, team':>12}")
    for n in (6, 24, 50):
        # a nav_msgs/Path of n PoseStamped: about 60 bytes a pose on the wire
        print(f"   {n:6d} {n:11d} {n * (n - 1):7d} {n * n * 60:12d}")
    return 0


def physics(trials: int, m) -> None:
    """Section 2: ``trials`` trials of the hexagon on the physics plant, model ``m``."""
    print(f"\n2. the physics plant, 6 P3-DX-size robots through the filter "
          f"({trials} trial(s) of {HEXAGON.name}):")
    from formation_ilc.config.scenario import load_scenario

    sc = load_scenario(str(HEXAGON)).with_options(noise=False, delay=False)
    spec = spec_for(m.footprint, m.limits, sc.dt)
    cpu0, t0 = time.process_time(), time.perf_counter()
    res = run_physics(sc, m, trials, safety=spec)
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - t0
    sim_s = res.samples * sc.dt
    print(f"   {res.samples / res.seconds:.1f} samples/s in the loop, real time x "
          f"{sim_s / res.seconds:.2f} (wall), x {sim_s / cpu:.2f} per CPU second "
          f"({wall:.1f} s wall, {cpu:.1f} s CPU); faster than real time: "
          f"{'MET' if sim_s / res.seconds > 1 else 'MISSED'}")

if __name__ == "__main__":
    sys.exit(main())
