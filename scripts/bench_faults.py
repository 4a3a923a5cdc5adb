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

Liveness (``--liveness``), on the same run:

* a stuck phase: the simulator is stopped (SIGSTOP) in the middle of a trial; the time
  from the stop to the leader's first finding on the launcher's console ("has had no new
  sample"), then SIGCONT: the run must still finish equal to batch;
* a forged abort: a node outside the formation publishes an ``abort`` of the running slot
  with the next ``seq`` (the run id read from the latched configuration); the time from it
  to the next trial row (the leader re-asserts its schedule and the slot runs again);
* a chaos run (``--chaos SEEDS``): a random node (robot, simulator, link emulator, leader,
  recorder) SIGKILLed every 2-5 s (seeded), over ``--trials`` trials: status, kills, and
  the largest difference from batch.

Start-up kills (``--startup``): with a busy loop on every core, the launcher is SIGKILLed
1, 2, ... 8 s after it started (its nodes still importing, joining, compiling); every
process it had started by then is followed until it is gone: the slowest death after the
kill, and whether any outlived it by more than 30 s.

Forgeries (``--forged``): a second process (tests/stack/forger.py) joins the run with the
run id of the latched configuration and forges a burst of 72 schedule events the moment a
trial ends, and an abort of the slot just committed with the seq the leader gives its next
start: status, trials, the largest difference from batch, the foreign events the launcher
counted, and ``analyze``'s status on the recording.

Every process runs with localhost discovery and its own ROS_DOMAIN_ID.

  .venv/bin/python scripts/bench_faults.py [--trials 10] [--kinds robot leader ...]
  .venv/bin/python scripts/bench_faults.py --liveness [--chaos 3 --trials 30]
  .venv/bin/python scripts/bench_faults.py --startup [--delays 1 2 3 4 5 6 7 8]
  .venv/bin/python scripts/bench_faults.py --forged [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from procstat import children_of, gone

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
    # a column neither side has (contacts on a plant without bodies) is equal: nan before
    res["trials"], res["max_diff"] = _max_diff(metrics.parent, trials)
    # the leader's last report (a restarted leader's own): the starts and aborts it took
    # for another's; and the slots it aborted, as its log says each (a restarted leader
    # aborts the slot its predecessor left open as it starts)
    diag = out / "diagnostics.json"
    leader = (json.loads(diag.read_text()).get("virtual_leader") or {}) if diag.exists() else {}
    res["foreign"] = int(leader.get("foreign_events", -1))
    log = out / "logs" / "virtual_leader.log"
    said = log.read_text(errors="replace") if log.exists() else ""
    res["aborts"] = said.count(") aborted: ") + said.count("was open and is aborted")
    return res


def _launch(out: Path, domain: int, trials: int, *extra: str) -> subprocess.Popen[str]:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(domain))
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3",
            "--trials", str(trials), "--seed", "5", "--out", str(out), "--domain-id",
            str(domain), "--no-plots", "--record", str(out / "run.mcap"), *extra]
    return subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)


def _max_diff(out: Path, trials: int) -> tuple[int, float]:
    got = read_metrics(out / "metrics.csv")
    ref = simulate(load_scenario("paper-triangle3").with_options(seed=5), trials=trials).metrics
    if not len(got):
        return 0, float("nan")
    a, b = got[:, 1:], ref[:len(got), 1:]
    # a column neither has (contacts on a plant without bodies) is equal; one side only is not
    d = np.where(np.isnan(a) & np.isnan(b), 0.0, np.abs(a - b))
    return len(got), float(np.where(np.isnan(d), np.inf, d).max())


def _lines(proc: subprocess.Popen[str], into: list[tuple[float, str]]) -> None:
    """Read the launcher's console into ``into`` (time, line), in a thread."""
    import threading

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            into.append((time.monotonic(), line.rstrip()))

    threading.Thread(target=read, daemon=True).start()


def stuck(trials: int, domain: int, out: Path, after: int, scale: float) -> dict:
    """SIGSTOP the simulator mid-trial; time to the leader's finding; SIGCONT."""
    proc = _launch(out, domain, trials, "--timeout", "20", "--watchdog-scale", str(scale))
    lines: list[tuple[float, str]] = []
    _lines(proc, lines)
    res: dict = {"case": f"stuck simulator (scale {scale})"}
    try:
        while rows(out / "metrics.csv") < after:
            time.sleep(0.02)
        pid = None
        while pid is None:
            pid = find(domain, "-m robot_sim.node")
        time.sleep(0.5)  # inside the next trial, most often
        os.kill(pid, signal.SIGSTOP)
        t_stop = time.monotonic()

        def findings() -> list[tuple[float, str]]:
            return [(t, ln) for t, ln in lines if t > t_stop and ln.startswith("virtual_leader:")]

        while not findings():
            if proc.poll() is not None or time.monotonic() - t_stop > 600:
                break
            time.sleep(0.05)
        found = findings()
        res["detect_s"] = found[0][0] - t_stop if found else float("nan")
        res["finding"] = found[0][1] if found else ""
        try:
            os.kill(pid, signal.SIGCONT)
        except ProcessLookupError:
            pass  # the run stopped it already
        proc.wait(timeout=900)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    res["status"] = proc.returncode
    res["trials"], res["max_diff"] = _max_diff(out, trials)
    return res


def forged_abort(trials: int, domain: int, out: Path, after: int) -> dict:
    """A forged abort of the running slot; time from it to the next trial row."""

    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import String

    import msgs_schema as ms

    proc = _launch(out, domain, trials, "--timeout", "20")
    res: dict = {"case": "forged abort"}
    rclpy.init()
    node = rclpy.create_node("forger", namespace="/forger")
    state: dict = {"run": "", "start": None}
    node.create_subscription(String, "/formation/config",
                             lambda m: state.update(run=json.loads(m.data)["run_id"]),
                             ms.LATCHED_QOS)
    node.create_subscription(String, "/formation/leader/trial_events",
                             lambda m: state.update(start=json.loads(m.data))
                             if json.loads(m.data).get("event") == "start" else None,
                             ms.SAMPLE_QOS)
    pub = node.create_publisher(String, "/formation/leader/trial_events", ms.SAMPLE_QOS)
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    try:
        while rows(out / "metrics.csv") < after or state["start"] is None or \
                state["start"]["trial"] < after or not state["run"]:
            ex.spin_once(timeout_sec=0.05)
        ev = state["start"]
        before = rows(out / "metrics.csv")
        pub.publish(String(data=json.dumps({"event": "abort", "trial": ev["trial"],
                                            "slot": ev["slot"], "seq": ev["seq"] + 1,
                                            "why": "forged", "run": state["run"]})))
        t0 = time.monotonic()
        while rows(out / "metrics.csv") <= before and proc.poll() is None:
            ex.spin_once(timeout_sec=0.05)
        res["recover_s"] = time.monotonic() - t0
        proc.wait(timeout=900)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        node.destroy_node()
        rclpy.shutdown()
    res["status"] = proc.returncode
    res["trials"], res["max_diff"] = _max_diff(out, trials)
    return res


def chaos(trials: int, domain: int, out: Path, seed: int) -> dict:
    """A random node SIGKILLed every 2-5 s (seeded) for the whole run."""
    import random

    rng = random.Random(seed)
    victims = ["robot_id:=1", "robot_id:=2", "robot_id:=3", "-m robot_sim.node",
               "-m robot_sim.link_emulator", "-m virtual_leader.node",
               "formation_ilc.nodes.recorder"]
    proc = _launch(out, domain, trials, "--timeout", "20", "--max-restarts", "1000")
    res: dict = {"case": f"chaos, seed {seed}", "kills": 0}
    t0 = time.monotonic()
    try:
        while rows(out / "metrics.csv") < 1 and proc.poll() is None:
            time.sleep(0.05)
        while proc.poll() is None:
            deadline = time.monotonic() + rng.uniform(2.0, 5.0)
            victim = rng.choice(victims)
            while time.monotonic() < deadline and proc.poll() is None:
                time.sleep(0.05)
            pid = find(domain, victim)
            if pid is not None and proc.poll() is None:
                os.kill(pid, signal.SIGKILL)
                res["kills"] += 1
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    res["status"] = proc.returncode
    res["wall_s"] = time.monotonic() - t0
    res["trials"], res["max_diff"] = _max_diff(out, trials)
    from formation_ilc.recordings.recording import load_recording, recording_parts

    rec = load_recording(recording_parts(out / "run.mcap"), keep=lambda k, n: False)
    res["recorded"] = trials - len(rec.missing)
    return res


def startup_kill(delay: float, domain: int, out: Path, busy: int) -> dict:
    """SIGKILL the launcher ``delay`` s after it started, with ``busy`` busy loops; follow
    every process it had started until each is gone (at most 60 s)."""
    loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"])
             for _ in range(busy)]
    res: dict = {"delay": delay}
    try:
        proc = _launch(out, domain, 10)
        seen: set[int] = set()
        t0 = time.monotonic()
        while time.monotonic() - t0 < delay:
            seen |= children_of(proc.pid)
            time.sleep(0.01)
        seen |= children_of(proc.pid)
        started = [p for p in seen if not gone(p)]
        os.kill(proc.pid, signal.SIGKILL)
        t_kill = time.monotonic()
        proc.wait()
        deaths: dict[int, float] = {}
        alive = set(started)
        while alive and time.monotonic() - t_kill < 60:
            for p in list(alive):
                if gone(p):
                    deaths[p] = time.monotonic() - t_kill
                    alive.discard(p)
            time.sleep(0.005)
        for p in alive:
            try:
                os.kill(p, signal.SIGKILL)
            except ProcessLookupError:
                pass
        res.update(processes=len(started), slowest=max(deaths.values(), default=0.0),
                   left=len(alive),
                   over_5s=sum(1 for t in deaths.values() if t > 5.0) + len(alive))
    finally:
        for lp in loops:
            lp.kill()
            lp.wait()
    return res


def startup(a: argparse.Namespace, domain: int) -> None:
    print(f"launcher SIGKILLed during start-up (paper-triangle3, recorded), {a.busy} busy "
          f"loop(s); load {os.getloadavg()[0]:.1f}")
    print(f"{'after [s]':>9s} {'processes':>9s} {'slowest death [s]':>17s} "
          f"{'over 5 s':>8s} {'left at 60 s':>12s}")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for i, delay in enumerate(a.delays):
            r = startup_kill(delay, domain + i, Path(tmp) / f"k{i}", a.busy)
            worst = max(worst, r["slowest"])
            print(f"{delay:9.1f} {r['processes']:9d} {r['slowest']:17.2f} {r['over_5s']:8d} "
                  f"{r['left']:12d}", flush=True)
    print(f"slowest node death after the launcher: {worst:.2f} s (bound 5 s); load "
          f"{os.getloadavg()[0]:.1f}")


def forged(trials: int, domain: int, out: Path, burst_at: int, abort_at: int) -> dict:
    """A run with a second process forging events (tests/stack/forger.py)."""
    forger = Path(__file__).resolve().parents[1] / "tests" / "stack" / "forger.py"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_DOMAIN_ID=str(domain))
    proc = _launch(out, domain, trials, "--timeout", "20")
    second = subprocess.Popen([sys.executable, str(forger), "--burst-at", str(burst_at),
                               "--abort-committed", str(abort_at)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                              start_new_session=True)
    t0 = time.monotonic()
    try:
        text, _ = proc.communicate(timeout=900)
        said, _ = second.communicate(timeout=60)
    finally:
        for p in (proc, second):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGKILL)
    res: dict = {"status": proc.returncode, "wall_s": time.monotonic() - t0,
                 "forged": [ln for ln in said.splitlines() if ln.startswith("{")]}
    res["trials"], res["max_diff"] = _max_diff(out, trials)
    try:

        summary = json.loads((out / "summary.json").read_text())
        res["foreign"] = summary.get("foreign_events", {}).get("count", 0)
    except (OSError, ValueError):
        res["foreign"] = None
    an = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "analyze",
                         str(out / "run.mcap"), "--out", str(out / "an"), "--no-plots"],
                        env=env, capture_output=True, text=True)
    res["analyze"] = an.returncode
    res["tail"] = text.strip().splitlines()[-1:] if res["status"] else []
    return res


def forgeries(a: argparse.Namespace, domain: int) -> None:
    print(f"paper-triangle3, {a.trials} trials, lockstep, emulated links, noise and delays, "
          f"recorded; a second process forges a burst of 72 events as trial 2 ends and an "
          f"abort of trial 4's slot once it is committed; load {os.getloadavg()[0]:.1f}")
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(a.repeat):
            r = forged(a.trials, domain + i, Path(tmp) / f"f{i}", 2, 4)
            print(f"run {i + 1}: status {r['status']}, {r['trials']} trials, max |run - "
                  f"batch| {r['max_diff']:.3g}, foreign events refused {r['foreign']}, "
                  f"forgeries {len(r['forged'])}, analyze status {r['analyze']}, "
                  f"{r['wall_s']:.0f} s {r['tail']}", flush=True)


def liveness(a: argparse.Namespace, domain: int) -> None:
    print(f"paper-triangle3, {a.trials} trials, lockstep, emulated links, noise and delays, "
          f"recorded")
    with tempfile.TemporaryDirectory() as tmp:
        r = stuck(a.trials, domain, Path(tmp) / "stuck", a.after, a.scale)
        print(f"{r['case']}: first finding {r['detect_s']:.1f} s after SIGSTOP; after SIGCONT "
              f"status {r['status']}, {r['trials']} trials, max |run - batch| "
              f"{r['max_diff']:.3g}\n  {r['finding']}", flush=True)
        r = forged_abort(a.trials, domain + 1, Path(tmp) / "forged", a.after)
        print(f"{r['case']}: next trial row {r['recover_s']:.2f} s after it; status "
              f"{r['status']}, {r['trials']} trials, max |run - batch| {r['max_diff']:.3g}",
              flush=True)
        for seed in range(a.chaos):
            r = chaos(a.trials, domain + 2 + seed, Path(tmp) / f"chaos{seed}", seed)
            print(f"{r['case']}: {r['kills']} kills, status {r['status']}, {r['trials']} "
                  f"trials ({r['recorded']} complete in the recording), "
                  f"{r['wall_s']:.0f} s, max |run - batch| {r['max_diff']:.3g}", flush=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--trials", type=int, default=10)
    p.add_argument("--after", type=int, default=3, help="kill after this many trials")
    p.add_argument("--kinds", nargs="+", choices=list(KINDS), default=list(KINDS))
    p.add_argument("--liveness", action="store_true",
                   help="a stuck phase, a forged abort and --chaos runs instead of the kills")
    p.add_argument("--chaos", type=int, default=0, metavar="SEEDS",
                   help="with --liveness: chaos runs, one per seed 0..SEEDS-1")
    p.add_argument("--scale", type=float, default=0.5,
                   help="with --liveness: --watchdog-scale of the stuck-phase run")
    p.add_argument("--startup", action="store_true",
                   help="SIGKILL the launcher during start-up, under busy loops")
    p.add_argument("--delays", type=float, nargs="+", default=[1, 2, 3, 4, 5, 6, 7, 8],
                   help="with --startup: seconds after the launcher's start")
    p.add_argument("--busy", type=int, default=os.cpu_count() or 2,
                   help="with --startup: busy loops beside the run (default: one a core)")
    p.add_argument("--forged", action="store_true",
                   help="a forged events burst and a forged abort from a second process")
    p.add_argument("--repeat", type=int, default=1, help="with --forged: runs")
    a = p.parse_args()
    domain = 30 + os.getpid() % 60
    if a.liveness:
        liveness(a, domain)
        return 0
    if a.startup:
        startup(a, domain)
        return 0
    if a.forged:
        forgeries(a, domain)
        return 0
    print(f"paper-triangle3, {a.trials} trials, lockstep, emulated links, noise and delays, "
          f"recorded; SIGKILL after {a.after} trials")
    print(f"{'killed':>14s} {'status':>6s} {'trials':>6s} {'restarts':>8s} "
          f"{'recover [s]':>11s} {'run [s]':>8s} {'max |run - batch|':>18s} "
          f"{'foreign':>7s} {'aborts':>6s}")
    with tempfile.TemporaryDirectory() as tmp:
        for kind in [None, *a.kinds]:
            r = run(kind, a.trials, domain, Path(tmp) / (kind or "none"), a.after)
            rec = f"{r['recover_s']:11.2f}" if "recover_s" in r else f"{'-':>11s}"
            print(f"{r['kind']:>14s} {r['status']:6d} {r['trials']:6d} {r['restarts']:8d} "
                  f"{rec} {r['wall_s']:8.1f} {r['max_diff']:18.3g} {r['foreign']:7d} "
                  f"{r['aborts']:6d}"
                  + ("  (nodes outlived the launcher!)" if r.get("left") else "")
                  + (f"  (its nodes ended {r['nodes_gone_s']:.2f} s after it)"
                     if "nodes_gone_s" in r and not r.get("left") else ""),
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
