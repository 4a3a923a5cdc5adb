#!/usr/bin/env python3
"""Benchmark of the live view: lockstep throughput with and without ``--live`` and a
connected Foxglove client.

Runs `formation-ilc launch` (real processes on localhost, own ROS_DOMAIN_ID each run)
alternately without and with ``--live PORT``; in the live runs Foxglove's own WebSocket
client (tests/stack/foxglove_client/client.js, node, its node_modules from ``npm ci``: pass
their folder with --node-modules) subscribes to every robot's pose, desired pose and
tracking error and the markers and decodes every message for the whole run. Prints each
run's lockstep samples/s (simulated samples over the wall time inside trials, the
launcher's own figure), the medians and their ratio, and the median of each pair's ratio:
the live view's cost. Then the same for the **steady state**: the samples a second of wall
time from the end of trial ``--from-trial`` (its line on the launcher's console) to the
end of the run, in both kinds of run, once the client has subscribed: what a connected
viewer costs, without the bridge's and the client's start-up (about 1.6 s and 0.5 s of
CPU), which fall into the first trials of a short run.

    python -u scripts/bench_live.py --node-modules DIR   # paper-hexagon6, 6 pairs of 12 trials
    python scripts/bench_live.py --node-modules DIR --pairs 5 --trials 4 --from-trial 2 --record
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from procstat import cmdline, descendants, proc_cpu

CLIENT = Path(__file__).resolve().parent.parent / "tests" / "stack" / "foxglove_client"
#: the launcher's line for a trial whose metrics are in: "trial K/N  max position ..."
TRIAL_LINE = re.compile(r"^trial (\d+)/(\d+) ")


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


class CpuWatch(threading.Thread):
    """The CPU seconds the live view's process (below the launcher ``launcher_pid``) and
    the client used from the end of the run's first trial (its row in ``metrics``) to their
    exit, and the wall time between (read from /proc every 0.2 s): what they took while
    trials ran, start-up left out."""

    def __init__(self, launcher_pid: int, client_pid: int | None, metrics: Path):
        super().__init__(daemon=True)
        self.launcher_pid = launcher_pid
        self.client_pid = client_pid
        self.metrics = metrics
        self.seconds: dict[str, float] = {}
        self.wall = 0.0
        self._at_first: dict[str, float] | None = None
        self._first_t = 0.0
        self._done = threading.Event()

    def _liveview_pid(self) -> int | None:
        """This run's live view (another run's, on the machine, is not counted)."""
        return next((p for p in descendants([self.launcher_pid])
                     if b"formation_ilc.nodes.liveview" in cmdline(p)), None)

    def run(self) -> None:
        live = None
        last: dict[str, float] = {}
        while not self._done.wait(0.2):
            live = live or self._liveview_pid()
            for name, pid in (("live view", live), ("client", self.client_pid)):
                t = proc_cpu(pid) if pid is not None else None
                if t is not None:
                    last[name] = t
            if self._at_first is None and self.metrics.exists() and \
                    len(self.metrics.read_text().splitlines()) >= 2:
                self._at_first, self._first_t = dict(last), time.monotonic()
            if self._at_first is not None:
                self.wall = time.monotonic() - self._first_t
                self.seconds = {k: v - self._at_first.get(k, 0.0) for k, v in last.items()}

    def stop(self) -> None:
        self._done.set()
        self.join()


class Console(threading.Thread):
    """The launcher's console, read as it comes: when each trial's line came (its metrics
    are in, so the trial has ended)."""

    def __init__(self, proc: subprocess.Popen):
        super().__init__(daemon=True)
        self.proc = proc
        self.lines: list[str] = []
        #: trial number K of its line "trial K/N" -> time.monotonic() it came
        self.ended: dict[int, float] = {}

    def run(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line)
            m = TRIAL_LINE.match(line)
            if m:
                self.ended.setdefault(int(m[1]), time.monotonic())

    def steady(self, first: int, per_trial: float) -> float | None:
        """Samples a second of wall time from trial ``first``'s line to the last trial's
        (None: too few trials)."""
        last = max(self.ended, default=0)
        if first not in self.ended or last <= first:
            return None
        return (last - first) * per_trial / (self.ended[last] - self.ended[first])


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
    try:
        console = Console(stack)
        console.start()
        subscribed = None
        if live and not args.no_client:
            viewer = client(port, args.robots, args.node_modules, time.monotonic() + 120,
                            out.parent / f"{out.name}-client.log", args.client_nice)
            subscribed = time.monotonic()
        cpu = CpuWatch(stack.pid, viewer.pid if viewer is not None else None,
                       out / "metrics.csv")
        cpu.start()
        stack.wait(timeout=1800)
        console.join()
        stdout = "".join(console.lines)
        cpu.stop()
        counts: dict[str, int] = {}
        if viewer is not None:
            viewer.terminate()  # it prints what it decoded
            last = (viewer.communicate(timeout=30)[0].strip().splitlines() or [""])[-1]
            counts = json.loads(last).get("counts", {}) if last.startswith("{") else {}
    finally:  # a run that overran or a bench stopped by ^C leaves nothing behind
        for proc in (viewer, stack):
            if proc is not None and proc.poll() is None:
                proc.terminate()  # the launcher stops every node it started
                proc.wait(timeout=120)
    if stack.returncode:
        return {"error": stdout[-800:]}
    s = json.loads((out / "summary.json").read_text())
    poses = sum(v for k, v in counts.items() if k.endswith("/pose"))
    per_trial = s["timing"]["samples"] / max(s["trials_done"], 1)
    return {"samples_per_s": s["timing"]["samples_per_s"], "viewer": viewer is not None,
            "steady": console.steady(args.from_trial, per_trial),
            "late_client": subscribed is not None
            and subscribed > console.ended.get(args.from_trial, 0.0),
            "cpu": cpu.seconds, "cpu_wall": cpu.wall,
            "poses": poses, "decoded": sum(counts.values()),
            "robot_samples": args.robots * (s["timing"]["samples"] + args.trials)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--node-modules", required=True, metavar="DIR",
                    help="node_modules of tests/stack/foxglove_client (npm ci there)")
    ap.add_argument("--scenario", default="paper-hexagon6")
    ap.add_argument("--robots", type=int, default=6, help="robots of the scenario")
    ap.add_argument("--trials", type=int, default=12)
    ap.add_argument("--pairs", type=int, default=6, help="runs without and with --live")
    ap.add_argument("--record", action="store_true", help="every run records too")
    ap.add_argument("--no-client", action="store_true",
                    help="live runs without a client: what serving alone costs")
    ap.add_argument("--client-nice", type=int, default=0, metavar="N",
                    help="run the client at niceness N (a viewer on this machine that "
                         "yields to the control loop; default 0)")
    ap.add_argument("--from-trial", type=int, default=3, metavar="K",
                    help="the steady state counts from the end of trial K (1-based, as the "
                         "launcher prints it; default 3): a client that subscribes later is "
                         "named")
    ap.add_argument("--domain", type=int, default=30 + os.getpid() % 60)
    args = ap.parse_args()
    if not 1 <= args.from_trial < args.trials:
        ap.error(f"--from-trial {args.from_trial}: 1 <= K < --trials ({args.trials}) is "
                 f"required")
    what = ("--live, no client" if args.no_client else "--live and a client" +
            (f" at niceness {args.client_nice}" if args.client_nice else ""))
    figures: dict[bool, list[float]] = {False: [], True: []}
    steady: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.pairs):
            for live in (False, True):
                r = run(args, live, args.domain, Path(tmp) / f"run{k}-{int(live)}")
                if "error" in r:
                    kept = tempfile.mkdtemp(prefix="bench_live-failed-")
                    shutil.copytree(Path(tmp), kept, dirs_exist_ok=True)
                    print(f"run failed: {r['error']}\n(its folder, logs included, is kept "
                          f"in {kept})", file=sys.stderr)
                    return 1
                if live and not r["viewer"] and not args.no_client:
                    print("the client never connected", file=sys.stderr)
                    return 1
                if r["steady"] is None:
                    print(f"run {k} ({'live' if live else 'plain'}): no line for trial "
                          f"{args.from_trial} or after it on the launcher's console",
                          file=sys.stderr)
                    return 1
                figures[live].append(r["samples_per_s"])
                steady[live].append(r["steady"])
                if r["late_client"]:
                    print(f"pair {k}: the client subscribed after trial {args.from_trial} "
                          f"ended: its steady state starts too early", flush=True)
                seen = (f"; the client decoded {r['decoded']} messages, {r['poses']} of the "
                        f"run's {r['robot_samples']} robot poses" if r.get("viewer") else "")
                if r["cpu"]:
                    seen += (f"; CPU after trial 0 ({r['cpu_wall']:.1f} s): " + ", ".join(
                        f"{k} {v:.2f} s ({100 * v / r['cpu_wall']:.1f} % of a core)"
                        for k, v in r["cpu"].items()))
                print(f"pair {k} {what if live else 'plain'}: "
                      f"{r['samples_per_s']:7.1f} samples/s, steady {r['steady']:7.1f} "
                      f"samples/s of wall time{seen}", flush=True)
    print(f"{args.scenario}, {args.trials} trials{', recorded' if args.record else ''}, "
          f"{what}:")
    _summary("whole run, inside trials", figures)
    _summary(f"steady state, from the end of trial {args.from_trial}", steady)
    return 0


def _summary(title: str, figures: dict[bool, list[float]]) -> None:
    plain, live = statistics.median(figures[False]), statistics.median(figures[True])
    print(f"  {title}: median {plain:.1f} samples/s plain, {live:.1f} live; ratio "
          f"{live / plain:.3f} (cost {100 * (1 - live / plain):.1f} %)")
    # each pair's runs are minutes apart: their ratio leaves out the load that drifts over
    # a whole benchmark (on this kind of machine runs move by up to 40 %)
    ratios = sorted(b / a for a, b in zip(figures[False], figures[True], strict=True))
    paired = statistics.median(ratios)
    print(f"  {title}: median of the {len(ratios)} pairs' ratios {paired:.3f} (cost "
          f"{100 * (1 - paired):.1f} %; quartiles {_quartiles(ratios)})")


def _quartiles(xs: list[float]) -> str:
    if len(xs) < 4:
        return "need 4 pairs"
    q1, _, q3 = statistics.quantiles(xs, n=4)
    return f"{q1:.3f} to {q3:.3f}"


if __name__ == "__main__":
    sys.exit(main())
