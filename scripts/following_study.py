#!/usr/bin/env python3
"""How closely a physics P3-DX goes where its commands say (docs/safety.md, the margin).

    .venv/bin/python scripts/following_study.py [--model p3dx] [--samples 1500] [--seed 1]

One robot on the physics plant (PyBullet) drives a random sequence of commands inside its
base's limits (a new target speed and turn rate every 3 s, approached at the acceleration
limits, a fifth of them a stop). For every sample it prints how far the body ends from the
exact unicycle arc of its command from where it was (median, 99th percentile, largest),
the same over 1 s and 2.6 s of commands, and then for brakings from 0.3, 0.5 and 0.75 m/s
while turning: how far the body stops from where the braking commands say. What the safety
filter's margin must hold of the body's own following, beside the poses' noise (which the
filter's estimate holds) and the discs' cover.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from formation_ilc.core.kinematics import arc_step  # noqa: E402
from formation_ilc.model.physics import MODELS, PhysicsWorld  # noqa: E402


def arc(p: np.ndarray, v: float, w: float, dt: float) -> np.ndarray:
    return np.array(arc_step(float(p[0]), float(p[1]), float(p[2]), v, w, dt))


def ramp(u: np.ndarray, target: np.ndarray, step: np.ndarray) -> np.ndarray:
    return u + np.clip(target - u, -step, step)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", choices=sorted(MODELS), default="p3dx")
    ap.add_argument("--samples", type=int, default=1500)
    ap.add_argument("--dt", type=float, default=0.2, help="sample time [s] (default 0.2)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    model, dt = MODELS[args.model], args.dt
    lim = model.limits
    step = np.array([lim.a_max, lim.alpha_max]) * dt
    rng = np.random.default_rng(args.seed)
    every = max(1, int(round(3.0 / dt)))
    cmds, u = [], np.zeros(2)
    for t in range(args.samples):
        if t % every == 0:
            target = np.array([rng.uniform(0, lim.v_max) if rng.random() < 0.8 else 0.0,
                               rng.uniform(-lim.omega_max, lim.omega_max)])
        u = ramp(u, target, step)
        cmds.append(u.copy())
    with PhysicsWorld(model, 1, dt) as world:
        world.place(np.zeros((1, 3)))
        poses = [world.truth()[0].copy()]
        for c in cmds:
            world.step(c[None, :])
            poses.append(world.truth()[0].copy())
        print(f"{args.model}, dT {dt} s, {args.samples} samples of random commands in its limits")
        for h in (1, int(round(1.0 / dt)), int(round(2.6 / dt))):
            off = []
            for t in range(len(cmds) - h):
                p = poses[t]
                for k in range(h):
                    p = arc(p, cmds[t + k][0], cmds[t + k][1], dt)
                off.append(math.hypot(*(p[:2] - poses[t + h][:2])))
            q = np.array(off)
            print(f"  after {h * dt:.1f} s of commands: off by {1e3 * np.median(q):.1f} mm "
                  f"median, {1e3 * np.percentile(q, 99):.1f} mm p99, {1e3 * q.max():.1f} mm most")
        worst = 0.0
        for v0 in (0.3, 0.5, min(0.75, lim.v_max)):
            for w0 in (0.0, 0.5, 1.0, -1.5):
                world.place(np.zeros((1, 3)))
                u, brake = np.zeros(2), []
                for _ in range(25):
                    u = ramp(u, np.array([v0, w0]), step)
                    world.step(u[None, :])
                start = world.truth()[0].copy()
                for _ in range(25):
                    u = ramp(u, np.zeros(2), step)
                    brake.append(u.copy())
                    world.step(u[None, :])
                p = start
                for c in brake:
                    p = arc(p, c[0], c[1], dt)
                d = math.hypot(*(p[:2] - world.truth()[0][:2]))
                worst = max(worst, d)
                print(f"  braking from {v0} m/s, {w0} rad/s: stops {1e3 * d:.1f} mm off")
        print(f"  braking, the most: {1e3 * worst:.1f} mm")
    return 0


if __name__ == "__main__":
    sys.exit(main())
