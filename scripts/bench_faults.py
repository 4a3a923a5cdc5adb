#!/usr/bin/env python3
"""Kill one process of a running formation and measure the recovery (docs/reliability.md).

For each kind of process (a robot, the simulator, the leader, the link emulator, the
recorder, and the launcher itself, resumed with ``launch --resume``) it runs
``formation-ilc launch`` on a lockstep scenario with noise and delays, SIGKILLs that process
after a few trials, and prints:

* time to recover: from the kill to the next trial row in metrics.csv;
* the whole run's wall time against the same run without a fault;
* the largest difference of the run's metrics from the batch simulator (0 up to round-off:
  nothing learned was lost or learned twice).

Every process runs with localhost discovery and its own ROS_DOMAIN_ID.

  .venv/bin/python scripts/bench_faults.py [--trials 10] [--kinds robot leader ...]
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate

KINDS = {"robot": "robot_id:=2", "simulator": "-m robot_sim.node",
         "leader": "-m virtual_leader.node", "link_emulator": "-m robot_sim.link_emulator",
         "recorder": "formation_ilc.nodes.recorder", "launcher": None}


def rows(path: Path) -> int:
    try:
        return max(0, len(path.read_text().splitlines()) - 1)
    except OSError:
        return 0


def find(domain: int, needle: str) -> int | None:
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            env = Path(f"/proc/{pid}/environ").read_bytes().split(b"\0")
        except OSError:
            continue
        if needle in cmd and f"ROS_DOMAIN_ID={domain}".encode() in env:
            return int(pid)
    return None


def run(kind: str | None, trials: int, domain: int, out: Path, after: int) -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(domain))
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3",
            "--trials", str(trials), "--seed", "5", "--out", str(out), "--domain-id",
            str(domain), "--no-plots", "--record", str(out / "run.mcap")]
    t0 = time.monotonic()
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    metrics = out / "metrics.csv"
    res: dict = {"kind": kind or "none"}
    try:
        if kind is not None:
            while rows(metrics) < after:
                if proc.poll() is not None:
                    raise RuntimeError(proc.communicate()[0])
                time.sleep(0.02)
            if kind == "launcher":
                pid: int | None = proc.pid
            else:
                pid = None
                while pid is None:
                    pid = find(domain, KINDS[kind])
            assert pid is not None
            before = rows(metrics)
            os.kill(pid, signal.SIGKILL)
            t_kill = time.monotonic()
            if kind == "launcher":
                proc.wait()
                while find(domain, "--ros-args") is not None and \
                        time.monotonic() - t_kill < 30:
                    time.sleep(0.02)
                res["nodes_gone_s"] = time.monotonic() - t_kill
                res["left"] = find(domain, "--ros-args") is not None
                proc = subprocess.Popen(
                    [sys.executable, "-m", "formation_ilc.cli", "launch", "--resume", str(out),
                     "--no-plots"], env=env, stdout=subprocess.PIPE,
                    stderr=subprocess.STDOUT, text=True, start_new_session=True)
            while rows(metrics) <= before and proc.poll() is None:
                time.sleep(0.02)
            res["recover_s"] = time.monotonic() - t_kill
        text, _ = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    res["status"] = proc.returncode
    res["wall_s"] = time.monotonic() - t0
    res["restarts"] = text.count("starting it again")
    got = read_metrics(metrics)
    sc = load_scenario("paper-triangle3").with_options(seed=5)
    ref = simulate(sc, trials=trials).metrics
    res["trials"] = len(got)
    res["max_diff"] = float(np.abs(got[:, 1:] - ref[:len(got), 1:]).max()) if len(got) else \
        float("nan")
    return res


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=10)
    p.add_argument("--after", type=int, default=3, help="kill after this many trials")
    p.add_argument("--kinds", nargs="+", choices=list(KINDS), default=list(KINDS))
    a = p.parse_args()
    domain = 30 + os.getpid() % 60
    print(f"paper-triangle3, {a.trials} trials, lockstep, emulated links, noise and delays, "
          f"recorded; SIGKILL after {a.after} trials")
    print(f"{'killed':>14s} {'status':>6s} {'trials':>6s} {'restarts':>8s} "
          f"{'recover [s]':>11s} {'run [s]':>8s} {'max |run - batch|':>18s}")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in [None, *a.kinds]:
            r = run(kind, a.trials, domain, Path(tmp) / (kind or "none"), a.after)
            rec = f"{r['recover_s']:11.2f}" if "recover_s" in r else f"{'-':>11s}"
            print(f"{r['kind']:>14s} {r['status']:6d} {r['trials']:6d} {r['restarts']:8d} "
                  f"{rec} {r['wall_s']:8.1f} {r['max_diff']:18.3g}"
                  + ("  (nodes outlived the launcher!)" if r.get("left") else "")
                  + (f"  (its nodes ended {r['nodes_gone_s']:.2f} s after it)"
                     if "nodes_gone_s" in r and not r.get("left") else ""),
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
