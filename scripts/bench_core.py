#!/usr/bin/env python3
"""Benchmark of the numerical core on paper-hexagon6 (6 robots, 300 samples per trial).

Prints, with the targets of the core issue:
  * ms of compute per trial for laws 9, 22, 23 (compiled kernel; target <= 1 ms);
  * the same for a straightforward per-sample numpy loop (law 9), checked to give the same
    result, and the speed-up (target >= 15x);
  * trials per second with a batch of 64 seeds stacked on the robot axis;
  * wall time of the whole `formation-ilc simulate paper-hexagon6 --trials 2000 --no-plots`
    process, start-up included: cold (an empty numba cache: every kernel is compiled) once,
    and warm (the cache that run left, loaded) --repeats times (target <= 3 s, warm).

Usage: python scripts/bench_core.py [--trials 1000] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.kinematics import step as kstep
from formation_ilc.model.simulate import Problem, simulate, simulate_seeds


def wrap(a: np.ndarray) -> np.ndarray:
    return a - 2 * np.pi * np.ceil((a - np.pi) / (2 * np.pi))


def numpy_trial(pb: Problem, memory, xi0, dist, noise, tau, tau0):
    """Law (9), feed-forward memory, as a plain numpy loop over samples (robots vectorised)."""
    n, n_links = pb.src.shape
    n_t = pb.samples
    src = np.clip(pb.src, 0, None)
    valid = (pb.src >= 0) & (pb.weight > 0)
    rows = np.arange(n)[:, None]
    ar = np.arange(n)
    xi = np.zeros((n, n_t + 1, 3))
    eta = np.zeros_like(xi)
    u = np.zeros((n, n_t, 2))
    xi[:, 0] = xi0
    for t in range(n_t):
        eta[:, t] = xi[:, t] + noise[:, t]
        s = t - tau[:, :, t]
        ok = valid & (s >= 1)
        sc = np.clip(s, 0, None)
        e = (pb.eta_d[rows, sc] - pb.eta_d[src, sc]) - (eta[rows, sc] - eta[src, sc])
        e[..., 2] = wrap(e[..., 2])
        acc = ((pb.weight * ok)[..., None] * e).sum(axis=1)
        s0 = t - tau0[:, t]
        ok0 = (pb.leader > 0) & (s0 >= 1)
        s0c = np.clip(s0, 0, None)
        e0 = pb.eta_d[ar, s0c] - eta[ar, s0c]
        e0[:, 2] = wrap(e0[:, 2])
        acc += (pb.leader * ok0)[:, None] * e0
        th = eta[:, t, 2]
        u[:, t, 0] = memory[:, t, 0] + pb.gain_prime * (np.cos(th) * acc[:, 0]
                                                         + np.sin(th) * acc[:, 1])
        u[:, t, 1] = memory[:, t, 1] + pb.gain_prime * acc[:, 2]
        xi[:, t + 1] = kstep(xi[:, t], u[:, t], pb.dt, dist[:, t])
    eta[:, n_t] = xi[:, n_t] + noise[:, n_t]
    e = (pb.eta_d[:, None, 1:] - pb.eta_d[src, 1:]) - (eta[:, None, 1:] - eta[src, 1:])
    e[..., 2] = wrap(e[..., 2])
    p = ((pb.weight * valid)[..., None, None] * e).sum(axis=1)
    e0 = pb.eta_d[:, 1:] - eta[:, 1:]
    e0[..., 2] = wrap(e0[..., 2])
    p += pb.leader[:, None, None] * e0
    th = eta[:, :-1, 2]
    nxt = memory.copy()
    nxt[..., 0] += pb.gain[:, None] * (np.cos(th) * p[..., 0] + np.sin(th) * p[..., 1])
    nxt[..., 1] += pb.gain[:, None] * p[..., 2]
    return xi, eta, u, nxt


def kernel_trial(pb: Problem, memory, xi0, dist, noise, tau, tau0):
    return pb.trial(memory, xi0, dist, noise, tau, tau0)


def bench_baseline(trials: int) -> tuple[float, float]:
    """(numpy ms/trial, kernel ms/trial) on the same draws, after checking they agree."""
    sc = load_scenario("paper-hexagon6")
    pb = Problem.from_scenario(sc)
    unc = sc.uncertainty
    draws = []
    for k in range(trials):
        shift, dist, noise = unc.draw_plant(sc.seed, k, pb.n, pb.samples)
        tau, tau0 = unc.draw_delays(sc.seed, k, pb.n, pb.src.shape[1], pb.samples)
        draws.append((pb.eta_d[:, 0] + shift, dist, noise, tau, tau0))
    times = {}
    results = {}
    for name, fn in (("numpy", numpy_trial), ("kernel", kernel_trial)):
        fn(pb, np.zeros((pb.n, pb.samples, 2)), *draws[0])  # warm-up (compile)
        mem = np.zeros((pb.n, pb.samples, 2))
        t0 = time.perf_counter()
        for d in draws:
            out = fn(pb, mem, *d)
            mem = out[3]
        times[name] = 1000 * (time.perf_counter() - t0) / trials
        results[name] = out
    for a, b in zip(results["numpy"], results["kernel"], strict=True):
        if not np.allclose(a, b, rtol=1e-9, atol=1e-9):
            raise SystemExit("baseline and kernel disagree: the comparison would be meaningless")
    return times["numpy"], times["kernel"]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=1000, help="trials per law (default 1000)")
    ap.add_argument("--repeats", type=int, default=3, help="process runs to time (default 3)")
    args = ap.parse_args()

    sc = load_scenario("paper-hexagon6")
    simulate(sc, trials=2)  # compile / load the cache
    print(f"paper-hexagon6: {sc.n} robots, {sc.samples} samples per trial, noise and delays on")
    print(f"{'law':>6s} {'ms/trial':>10s}   (simulate(): draws + kernel + metrics)")
    worst = 0.0
    for law in (9, 22, 23):
        s = sc.with_options(law=law)
        t0 = time.perf_counter()
        simulate(s, trials=args.trials)
        ms = 1000 * (time.perf_counter() - t0) / args.trials
        worst = max(worst, ms)
        print(f"{law:>6d} {ms:10.3f}")
    print(f"  target <= 1 ms/trial: worst {worst:.3f} ms -> {'MET' if worst <= 1 else 'MISSED'}")

    base_trials = 30
    np_ms, k_ms = bench_baseline(base_trials)
    ratio = np_ms / k_ms
    print(f"baseline, per-sample numpy loop (law 9, {base_trials} trials, same draws, results "
          f"equal to 1e-9): {np_ms:.2f} ms/trial; kernel trial alone {k_ms:.3f} ms/trial")
    print(f"  speed-up {ratio:.0f}x (target >= 15x) -> {'MET' if ratio >= 15 else 'MISSED'}")

    seeds = list(range(64))
    simulate_seeds(sc, seeds[:2], 1)
    k = 20
    t0 = time.perf_counter()
    simulate_seeds(sc, seeds, k)
    el = time.perf_counter() - t0
    print(f"batch of 64 seeds (teams stacked on the robot axis): {64 * k / el:.0f} trials/s "
          f"({1000 * el / (64 * k):.3f} ms per seed-trial)")

    exe = Path(sys.executable).with_name("formation-ilc")
    cmd = [str(exe), "simulate", "paper-hexagon6", "--trials", "2000", "--no-plots"]
    with tempfile.TemporaryDirectory() as tmp:
        # a cache of this run's own: cold starts empty, warm loads what cold compiled
        env = dict(os.environ, NUMBA_CACHE_DIR=os.path.join(tmp, "numba-cache"))

        def wall(i: int) -> float:
            t0 = time.perf_counter()
            subprocess.run(cmd + ["--out", os.path.join(tmp, str(i))], check=True,
                           capture_output=True, env=env)
            return time.perf_counter() - t0

        cold = wall(0)
        walls = [wall(1 + i) for i in range(args.repeats)]
    med = statistics.median(walls)
    print(f"whole process `{' '.join(cmd[1:])}`:")
    print(f"  cold (empty numba cache, compiles): {cold:.2f} s")
    print(f"  warm (cache loaded): median {med:.2f} s over {args.repeats} runs "
          f"(min {min(walls):.2f}, max {max(walls):.2f})")
    print(f"  target <= 3 s warm -> {'MET' if med <= 3 else 'MISSED'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
