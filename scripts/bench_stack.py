#!/usr/bin/env python3
"""Benchmark of the distributed stack: lockstep samples/s and per-sample latency.

Runs `formation-ilc launch` (real processes on localhost, own ROS_DOMAIN_ID each run) for
teams of 3, 6, 12 and 24 robots, with emulated and with direct links, one process per robot
and in container mode, and prints samples per second (simulated samples over the wall
time inside trials) and the latency of one sample (simulator publishes the poses -> every
robot's cmd_vel is in) p50/p90/p99.
Teams larger than the built-in scenarios are made from paper-hexagon6 by tiling it
(independent hexagons on one run, the same graph per copy).

    python scripts/bench_stack.py                 # all sizes, 3 trials each
    python scripts/bench_stack.py --sizes 6 24 --trials 2
    python scripts/bench_stack.py --links direct   # one link mode only
    python scripts/bench_stack.py --realtime 24   # only realtime: 24 robots, 1000 samples

Realtime (``--realtime N``): one trial of 1000 samples at dT = 0.1 s (100 s of wall time),
one process per robot (``--rt-container C``: C robot nodes per process). Prints the missed
samples (a robot whose command was not in before the simulator's next tick), the command
arrival after the tick p50/p99/max, and how late the simulator's timer fired.
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

import yaml

from formation_ilc.config.scenario import load_scenario


def team_scenario(n: int, tmp: Path, samples: int | None, dt: float | None = None) -> str:
    """A scenario file with n robots: paper-triangle3 for 3, hexagons tiled otherwise."""
    base = "paper-triangle3" if n == 3 else "paper-hexagon6"
    data = yaml.safe_load(load_scenario(base).text)
    if samples:
        data["samples"] = samples
    if dt:
        data["dt"] = dt
    if n not in (3, 6):
        if n % 6:
            raise SystemExit("sizes other than 3 must be multiples of 6")
        copies = n // 6
        g = data["graph"]
        leader = {}
        edges = []
        offsets = {}
        for c in range(copies):
            for r, w in g["leader"].items():
                leader[int(r) + 6 * c] = w
            for e in g["edges"]:
                ed = dict(e)
                ed["from"] = int(e["from"]) + 6 * c
                ed["to"] = int(e["to"]) + 6 * c
                edges.append(ed)
            for r, o in data["formation"]["offsets"].items():
                o2 = dict(o)
                if "x" in o2:
                    o2["x"] = float(o2["x"]) + 4.0 * c
                offsets[int(r) + 6 * c] = o2
        data["robots"] = n
        data["graph"] = dict(g, leader=leader, edges=edges)
        data["formation"]["offsets"] = offsets
        data["name"] = f"bench-{n}"
    path = tmp / f"team{n}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return str(path)


def run(scenario: str, trials: int, domain: int, container: int, mode: str, out: Path,
        timeout: float, links: str = "emulated") -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", scenario, "--trials",
            str(trials), "--out", str(out), "--domain-id", str(domain), "--no-plots",
            "--mode", mode, "--container", str(container), "--timeout", "60",
            "--links", links]
    t0 = time.perf_counter()
    res = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=timeout)
    wall = time.perf_counter() - t0
    if res.returncode:
        return {"error": (res.stdout + res.stderr)[-800:]}
    s = json.loads((out / "summary.json").read_text())
    s["wall"] = wall
    s["diagnostics"] = json.loads((out / "diagnostics.json").read_text())
    return s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", type=int, nargs="*", default=None,
                    help="lockstep team sizes (default 3 6 12 24; none with --realtime)")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--container", type=int, default=6,
                    help="robots per process in container mode (0: skip container runs)")
    ap.add_argument("--realtime", type=int, nargs="*", default=[],
                    help="team sizes to run in realtime mode (1000 samples at dT 0.1)")
    ap.add_argument("--rt-container", type=int, default=0, metavar="C",
                    help="realtime runs: C robot nodes per process (0: one per robot)")
    ap.add_argument("--rt-samples", type=int, default=1000)
    ap.add_argument("--rt-dt", type=float, default=0.1)
    ap.add_argument("--links", choices=("emulated", "direct", "both"), default="both",
                    help="link modes to run (default both, with the direct/emulated ratio)")
    ap.add_argument("--domain", type=int, default=30 + os.getpid() % 60)
    args = ap.parse_args()
    if args.sizes is None:
        args.sizes = [] if args.realtime else [3, 6, 12, 24]
    modes = ["emulated", "direct"] if args.links == "both" else [args.links]
    rates: dict[tuple[int, int, str], float] = {}
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        dom = args.domain
        for n in args.sizes:
            sc = team_scenario(n, tmp, None)
            for cont in ([0, args.container] if args.container else [0]):
                if cont and cont >= n:
                    cont = n  # all robots in one process
                for links in modes:
                    out = tmp / f"lock-{n}-{cont}-{links}"
                    s = run(sc, args.trials, dom, cont, "lockstep", out, 900, links)
                    dom = 30 + (dom - 29) % 71
                    label = f"{n:3d} robots, {links:8s} " + (
                        f"container {cont}/process" if cont else "one process per robot")
                    if "error" in s:
                        print(f"{label}: FAILED\n{s['error']}", flush=True)
                        continue
                    t = s["timing"]
                    rates[(n, cont, links)] = t["samples_per_s"]
                    print(f"{label:51s} {t['samples_per_s']:7.1f} samples/s  latency p50 "
                          f"{t['p50_ms']:6.2f} p90 {t['p90_ms']:6.2f} p99 {t['p99_ms']:6.2f} "
                          f"max {t['max_ms']:7.2f} ms  (wall {s['wall']:.1f} s incl. "
                          f"start-up)", flush=True)
                if (n, cont, "direct") in rates and (n, cont, "emulated") in rates:
                    r = rates[(n, cont, "direct")] / rates[(n, cont, "emulated")]
                    print(f"{'':51s} direct / emulated = {r:.2f} (target >= 1) -> "
                          f"{'MET' if r >= 1 else 'MISSED'}", flush=True)
        for n in args.realtime:
            # 1000 samples at dT = 0.1 s in realtime: 100 s of wall time
            sc = team_scenario(n, tmp, args.rt_samples, args.rt_dt)
            out = tmp / f"rt-{n}"
            s = run(sc, 1, dom, args.rt_container, "realtime", out, 900, modes[0])
            dom = 30 + (dom - 29) % 71
            layout = (f"container {args.rt_container}/process" if args.rt_container
                      else "one process per robot")
            if "error" in s:
                print(f"realtime {n} robots: FAILED\n{s['error']}")
                continue
            t = s["timing"]
            missed = {r: c for r, c in s.get("missed", {}).items() if c}
            print(f"realtime {n} robots ({layout}), {t['samples']} samples at dT "
                  f"{args.rt_dt} s: missed {sum(missed.values())} of "
                  f"{n * t['samples']} robot-samples {missed or ''}\n"
                  f"  command arrival after the tick p50 {t['p50_ms']:.2f} p90 "
                  f"{t['p90_ms']:.2f} p99 {t['p99_ms']:.2f} max {t['max_ms']:.2f} ms; "
                  f"all {n} in p50 {t['all_in_p50_ms']:.2f} p99 {t['all_in_p99_ms']:.2f} ms; "
                  f"timer lag p99 {t['tick_lag_p99_ms']:.2f} max {t['tick_lag_max_ms']:.2f} "
                  f"ms; superseded {t['superseded']}", flush=True)
            d = s["diagnostics"]
            late_links = sum(d.get("link_emulator", {}).get("late", {}).values())
            late_robots = sum(v.get("late", {}).get("links", 0) for k, v in d.items()
                              if k.startswith("robot_") and k != "robot_sim")
            print(f"  {modes[0]} links: deliveries late at the link emulator {late_links}, "
                  f"samples a robot commanded before its links were in {late_robots}",
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
