#!/usr/bin/env python3
"""Benchmark of the live view: lockstep throughput with and without ``--live`` and a
connected Foxglove client.

Runs `formation-ilc launch` (real processes on localhost, own ROS_DOMAIN_ID each run)
alternately without and with ``--live PORT``; in the live runs Foxglove's own WebSocket
client (tests/stack/foxglove_client/client.js, node, its node_modules from ``npm ci``: pass
their folder with --node-modules) subscribes to every robot's pose, desired pose and
tracking error and the markers and decodes every message for the whole run. Prints each
run's lockstep samples/s (simulated samples over the wall time inside trials, the
launcher's own figure), the medians and their ratio: the live view's cost.

    python scripts/bench_live.py --node-modules DIR            # paper-hexagon6, 3 pairs
    python scripts/bench_live.py --node-modules DIR --pairs 5 --trials 4 --record
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CLIENT = Path(__file__).resolve().parent.parent / "tests" / "stack" / "foxglove_client"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def client(port: int, n: int, modules: str, stop: float, log: Path, niceness: int = 0
           ) -> subprocess.Popen | None:
    """Foxglove's client subscribed to the live view until the run ends (retries until
    the server listens and the client has subscribed); None if it never did before
    ``stop``."""
    topics = [f"robot_{i}/{k}" for i in range(1, n + 1)
              for k in ("pose", "desired_pose", "tracking_error")] + ["markers"]
    env = dict(os.environ, NODE_PATH=modules)
    nice = ["nice", "-n", str(niceness)] if niceness else []
    while time.monotonic() < stop:
        with log.open("w") as err:
            p = subprocess.Popen([*nice, "node", str(CLIENT / "client.js"),
                                  f"ws://127.0.0.1:{port}", "0", *topics], env=env,
                                 stdout=subprocess.PIPE, stderr=err, text=True)
        while p.poll() is None and time.monotonic() < stop:
            if "subscribed" in log.read_text():
                return p  # connected, subscribed, decoding until SIGTERM
            time.sleep(0.1)
        p.kill()
        p.wait()
        time.sleep(0.3)  # the server is not up yet
    return None


def run(args: argparse.Namespace, live: bool, domain: int, out: Path) -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", args.scenario, "--trials",
            str(args.trials), "--out", str(out), "--domain-id", str(domain), "--no-plots",
            "--timeout", "60"]
    if args.record:
        argv += ["--record", str(out / "run.mcap")]
    port = free_port()
    if live:
        argv += ["--live", str(port)]
    stack = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                             text=True)
    viewer = None
    if live and not args.no_client:
        viewer = client(port, args.robots, args.node_modules, time.monotonic() + 120,
                        out.parent / f"{out.name}-client.log", args.client_nice)
    stdout, _ = stack.communicate(timeout=1800)
    counts: dict[str, int] = {}
    if viewer is not None:
        viewer.terminate()  # it prints what it decoded
        last = (viewer.communicate(timeout=30)[0].strip().splitlines() or [""])[-1]
        counts = json.loads(last).get("counts", {}) if last.startswith("{") else {}
    if stack.returncode:
        return {"error": stdout[-800:]}
    s = json.loads((out / "summary.json").read_text())
    poses = sum(v for k, v in counts.items() if k.endswith("/pose"))
    return {"samples_per_s": s["timing"]["samples_per_s"], "viewer": viewer is not None,
            "poses": poses, "decoded": sum(counts.values()),
            "robot_samples": args.robots * (s["timing"]["samples"] + args.trials)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--node-modules", required=True, metavar="DIR",
                    help="node_modules of tests/stack/foxglove_client (npm ci there)")
    ap.add_argument("--scenario", default="paper-hexagon6")
    ap.add_argument("--robots", type=int, default=6, help="robots of the scenario")
    ap.add_argument("--trials", type=int, default=3)
    ap.add_argument("--pairs", type=int, default=3, help="runs without and with --live")
    ap.add_argument("--record", action="store_true", help="every run records too")
    ap.add_argument("--no-client", action="store_true",
                    help="live runs without a client: what serving alone costs")
    ap.add_argument("--client-nice", type=int, default=0, metavar="N",
                    help="run the client at niceness N (a viewer on this machine that "
                         "yields to the control loop; default 0)")
    ap.add_argument("--domain", type=int, default=30 + os.getpid() % 60)
    args = ap.parse_args()
    what = ("--live, no client" if args.no_client else "--live and a client" +
            (f" at niceness {args.client_nice}" if args.client_nice else ""))
    figures: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.pairs):
            for live in (False, True):
                r = run(args, live, args.domain, Path(tmp) / f"run{k}-{int(live)}")
                if "error" in r:
                    print(f"run failed: {r['error']}", file=sys.stderr)
                    return 1
                if live and not r["viewer"] and not args.no_client:
                    print("the client never connected", file=sys.stderr)
                    return 1
                figures[live].append(r["samples_per_s"])
                seen = (f"; the client decoded {r['decoded']} messages, {r['poses']} of the "
                        f"run's {r['robot_samples']} robot poses" if r.get("viewer") else "")
                print(f"pair {k} {what if live else 'plain'}: "
                      f"{r['samples_per_s']:7.1f} samples/s{seen}", flush=True)
    plain, live = statistics.median(figures[False]), statistics.median(figures[True])
    print(f"{args.scenario}, {args.trials} trials{', recorded' if args.record else ''}: "
          f"median {plain:.1f} samples/s plain, {live:.1f} with {what}; "
          f"ratio {live / plain:.3f} (cost {100 * (1 - live / plain):.1f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
