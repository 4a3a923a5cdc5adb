"""Processes that die: the team keeps learning and loses nothing.

Each test runs the real stack (``formation-ilc launch``, lockstep, emulated links, noise and
delays on), kills one kind of process with SIGKILL during the run, and checks what the
user gets: the run completes, and its metrics equal the batch simulator's on the same
scenario and seed (to 1e-9) -- so the interrupted trial was run again with the same draws,
and no learned trial was lost or learned twice.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate
from formation_ilc.nodes.forkserver import FORK_ENV
from formation_ilc.system.shm import fastdds_files, in_use

from ..procs import find_child, processes, same_netns, stop_group

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

TOL = 1e-9
TRIALS = 7
SEED = 5


def start(env: dict[str, str], out: Path, *args: str) -> subprocess.Popen[str]:
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", *args, "--out", str(out),
            "--domain-id", env["ROS_DOMAIN_ID"], "--no-plots", "--timeout", "20"]
    return subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)


def wait_rows(proc: subprocess.Popen[str], metrics: Path, rows: int,
              timeout: float = 120.0) -> None:
    """Wait until metrics.csv holds ``rows`` trials (the header is one more line)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if metrics.exists() and len(metrics.read_text().splitlines()) > rows:
            return
        assert proc.poll() is None, proc.communicate()[0]
        time.sleep(0.05)  # polling a file, bounded by the deadline
    raise AssertionError(f"{metrics} did not reach {rows} rows")


def batch() -> np.ndarray:
    sc = load_scenario("paper-triangle3").with_options(seed=SEED)
    return simulate(sc, trials=TRIALS).metrics


def domain_procs(domain: str) -> list[int]:
    """Processes whose environment has this test's ROS_DOMAIN_ID (besides this one)."""
    return [pid for pid, cmd, env in processes()
            if f"ROS_DOMAIN_ID={domain}".encode() in env and "python" in cmd
            and same_netns(pid)]


VICTIMS = {"robot": "robot_id:=2", "simulator": "-m robot_sim.node",
           "leader": "-m virtual_leader.node", "link_emulator": "-m robot_sim.link_emulator"}
NODE = {"robot": "robot_2", "simulator": "robot_sim", "leader": "virtual_leader",
        "link_emulator": "link_emulator"}


#: the victims whose launcher starts each process as an interpreter of its own, not forked
#: from one import (the default for a small team): both ways start and stop (a restart is
#: an interpreter of its own either way)
SEPARATE = ("leader", "simulator")


@pytest.mark.parametrize("kind", list(VICTIMS))
def test_a_killed_node_is_restarted_and_nothing_is_lost(ros_env, tmp_path, kind):
    env = {**ros_env, FORK_ENV: "0" if kind in SEPARATE else "1"}
    proc = start(env, tmp_path, "paper-triangle3", "--trials", str(TRIALS),
                 "--seed", str(SEED))
    try:
        wait_rows(proc, tmp_path / "metrics.csv", 2)
        victim = find_child(ros_env["ROS_DOMAIN_ID"], VICTIMS[kind],
                            time.monotonic() + 10)
        os.kill(victim, signal.SIGKILL)
        out, _ = proc.communicate(timeout=180)
    finally:
        stop_group(proc)
    assert proc.returncode == 0, out
    assert ("processes (forked from one import);" in out) is (kind not in SEPARATE), out
    assert f"{NODE[kind]} exited with signal SIGKILL: starting it again" in out
    got = read_metrics(tmp_path / "metrics.csv")
    ref = batch()
    np.testing.assert_array_equal(got[:, 0], np.arange(TRIALS))
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["restarts"] == {NODE[kind]: 1}, out
    assert summary["trials_done"] == TRIALS
    # every event of the run is the leader's own: a restarted leader's, sealed with the
    # launch's key, are its predecessor's to it, and no node's forged count holds any
    diagnostics = json.loads((tmp_path / "diagnostics.json").read_text())
    assert diagnostics["virtual_leader"]["foreign_events"] == 0, diagnostics["virtual_leader"]
    assert "foreign_events" not in summary and "forged" not in summary, summary
    # the robots' memory on disk is the memory of the last trial, for every robot
    for r in range(1, 4):
        with np.load(tmp_path / "state" / f"robot_{r}.npz") as st:
            assert int(st["iterations"]) == TRIALS


def test_a_recording_of_a_faulted_run_analyses_to_the_batch_metrics(ros_env, tmp_path):
    """The simulator is killed (its slot is aborted and the iteration runs again in a later
    slot), then the recorder (the run goes on into RUN.part1.mcap): `analyze RUN.mcap`
    reads both parts as one run and gets every trial, numbered by iteration, equal to
    batch; the restarted recorder still confirms the last trial to the launcher."""
    rec = tmp_path / "run.mcap"
    proc = start(ros_env, tmp_path, "paper-triangle3", "--trials", str(TRIALS),
                 "--seed", str(SEED), "--record", str(rec))
    try:
        wait_rows(proc, tmp_path / "metrics.csv", 2)
        os.kill(find_child(ros_env["ROS_DOMAIN_ID"], VICTIMS["simulator"],
                           time.monotonic() + 10), signal.SIGKILL)
        wait_rows(proc, tmp_path / "metrics.csv", 4)
        os.kill(find_child(ros_env["ROS_DOMAIN_ID"], "-m formation_ilc.nodes.recorder",
                           time.monotonic() + 10), signal.SIGKILL)
        out, _ = proc.communicate(timeout=180)
    finally:
        stop_group(proc)
    assert proc.returncode == 0, out
    assert "recorder exited with signal SIGKILL" in out and "run.part1.mcap" in out, out
    from formation_ilc.recordings.recording import load_recording, recording_parts

    parts = recording_parts(rec)
    assert [p.name for p in parts] == ["run.mcap", "run.part1.mcap"]
    r = load_recording(parts)
    ref = batch()
    np.testing.assert_array_equal(r.metrics[:, 0], np.arange(TRIALS))
    np.testing.assert_allclose(r.metrics[:, 1:], ref[:, 1:], rtol=0, atol=TOL)
    assert r.incomplete == []
    # the run had an aborted slot: iterations and slots differ from it on
    starts = [(e["trial"], e.get("slot", e["trial"])) for e in r.events
              if e["event"] == "start"]
    assert any(e["event"] == "abort" for e in r.events)
    assert max(slot for _, slot in starts) > TRIALS - 1
    # read alone, the first part misses the trials recorded after the kill
    alone = load_recording(rec)
    assert len(alone.metrics) < TRIALS
    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "analyze", str(rec),
                          "--no-plots", "--out", str(tmp_path / "analysis")],
                         env=ros_env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "and 1 more part (run.part1.mcap)" in res.stderr
    np.testing.assert_allclose(read_metrics(tmp_path / "analysis" / "metrics.csv"),
                               r.metrics, rtol=0, atol=0)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["restarts"] == {"robot_sim": 1, "recorder": 1}
    diagnostics = json.loads((tmp_path / "diagnostics.json").read_text())
    assert diagnostics["recorder"]["trial"] == TRIALS - 1


def launcher_shm(pid: int) -> set[str]:
    """The Fast DDS files process ``pid`` has mapped: its segments and port files."""
    with open(f"/proc/{pid}/maps") as fh:
        return {line.split()[-1] for line in fh if "/dev/shm/fastrtps_" in line}


def test_launcher_killed_leaves_no_node_and_resume_finishes_the_run(ros_env, tmp_path):
    proc = start(ros_env, tmp_path, "paper-triangle3", "--trials", str(TRIALS),
                 "--seed", str(SEED))
    try:
        wait_rows(proc, tmp_path / "metrics.csv", 3)
        assert len(domain_procs(ros_env["ROS_DOMAIN_ID"])) >= 6  # launcher + 6 nodes
        # the launcher is a ROS host (its monitor): its own Fast DDS files, which nobody
        # removes when it is SIGKILLed
        own = {p for p in launcher_shm(proc.pid) if "_port" not in p}
        assert own, "the launcher mapped no Fast DDS segment"
        os.kill(proc.pid, signal.SIGKILL)  # the launcher only: its nodes must follow
        proc.wait(timeout=10)
        deadline = time.monotonic() + 15
        while domain_procs(ros_env["ROS_DOMAIN_ID"]) and time.monotonic() < deadline:
            time.sleep(0.1)  # bounded by the deadline
        left = domain_procs(ros_env["ROS_DOMAIN_ID"])
    finally:
        stop_group(proc, signal.SIGKILL)
    killed = time.monotonic()
    assert not left, f"node processes outlived their launcher: {left}"
    # the SIGKILLed launcher's own segments stay behind (named at random per process, they
    # pile up when nobody removes them; port files and their semaphores are named by domain
    # and participant and reused by the next run, so they do not): the next launch on this
    # machine removes them. That may be another test's launch, running beside this one.
    leftovers = own - in_use()
    done = len(read_metrics(tmp_path / "metrics.csv"))
    assert 3 <= done < TRIALS
    time.sleep(max(0.0, 3.0 - (time.monotonic() - killed)))  # older than the 2 s margin

    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch", "--resume",
                          str(tmp_path), "--no-plots"], env=ros_env, capture_output=True,
                         text=True, timeout=180, start_new_session=True)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "resuming" in res.stdout
    still = (leftovers & fastdds_files()) - in_use()  # a live process may reuse a name
    assert not still, (sorted(leftovers), sorted(still))
    got = read_metrics(tmp_path / "metrics.csv")
    np.testing.assert_array_equal(got[:, 0], np.arange(TRIALS))
    np.testing.assert_allclose(got[:, 1:], batch()[:, 1:], rtol=0, atol=TOL)
    # resuming a finished run is a no-op that says so
    again = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch", "--resume",
                            str(tmp_path)], env=ros_env, capture_output=True, text=True,
                           timeout=120)
    assert again.returncode == 0 and "nothing to resume" in again.stdout


def test_a_launcher_killed_while_its_nodes_start_takes_every_one_with_it(ros_env, tmp_path):
    """Reported: killed while its nodes were still importing, the launcher left all 7
    running 15 s later (they set the parent-death signal only once their imports were
    done). Now each node process is started through the runner that sets it first
    (``formation_ilc.system.lifetime``): killed the moment its nodes appear, the launcher
    takes every one with it (scripts/bench_faults.py --startup measures how fast)."""
    from ..procs import gone

    proc = start(ros_env, tmp_path, "paper-triangle3", "--trials", "3")
    try:
        started = _nodes_started(proc, 3)
        assert len(started) >= 3, "the launcher started no node"
        assert not (tmp_path / "metrics.csv").exists() or \
            len((tmp_path / "metrics.csv").read_text().splitlines()) <= 1  # still starting
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        deadline = time.monotonic() + 30
        while any(not gone(p) for p in started) and time.monotonic() < deadline:
            time.sleep(0.05)  # bounded by the deadline
        left = [p for p in started if not gone(p)]
    finally:
        stop_group(proc, signal.SIGKILL)
    for p in left:
        os.kill(p, signal.SIGKILL)
    assert not left, f"node processes outlived their launcher killed at start-up: {left}"


def test_a_launcher_stopped_by_sigterm_while_its_nodes_start_says_one_line(ros_env, tmp_path):
    """Before: a SIGTERM while the monitor's callbacks ran was raised inside rclpy, which
    printed a FATAL stack before the launcher's one line. Now the handler stops the run
    from the launcher's loop: status 130, "interrupted", no stack, no node left."""
    from ..procs import gone

    proc = start(ros_env, tmp_path, "paper-triangle3", "--trials", "3")
    try:
        started = _nodes_started(proc, 3)
        os.kill(proc.pid, signal.SIGTERM)
        out, _ = proc.communicate(timeout=120)
    finally:
        stop_group(proc, signal.SIGKILL)
    assert proc.returncode == 130, out
    assert "interrupted: stopping every node" in out
    assert "FATAL" not in out and "Traceback" not in out, out
    assert all(gone(p) for p in started)


def test_ctrl_c_during_a_run_says_how_to_go_on_and_the_resume_finishes_it(ros_env, tmp_path):
    """SIGINT (Ctrl-C) once a trial is in: status 130, and the command that goes on; that
    command finishes the run."""
    proc = start(ros_env, tmp_path, "paper-triangle3", "--trials", "40", "--seed", str(SEED))
    try:
        wait_rows(proc, tmp_path / "metrics.csv", 1)
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole group
        out, _ = proc.communicate(timeout=120)
    finally:
        stop_group(proc, signal.SIGKILL)
    assert proc.returncode == 130, out
    hint = f"to go on: formation-ilc launch --resume {tmp_path}"
    assert hint in out, out
    assert "Traceback" not in out, out
    done = len((tmp_path / "metrics.csv").read_text().splitlines()) - 1
    assert 1 <= done < 40
    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch", "--resume",
                          str(tmp_path), "--no-plots"], env=ros_env, capture_output=True,
                         text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    assert len((tmp_path / "metrics.csv").read_text().splitlines()) == 41


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""

def _nodes_started(proc, n: int) -> set[int]:
    """The node processes (started through the lifetime runner) below launcher ``proc``,
    once there are ``n`` of them or 120 s have passed."""
    from ..procs import children_of

    started: set[int] = set()
    deadline = time.monotonic() + 120
    while len(started) < n and time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()[0]
        started |= {p for p in children_of(proc.pid)
                    if b"formation_ilc.system.lifetime" in _cmdline(p)}
        time.sleep(0.01)  # polling the process table, bounded by the deadline
    return started



def test_resume_refuses_a_folder_that_is_not_a_run(ros_env, tmp_path):
    res = subprocess.run([sys.executable, "-m", "formation_ilc.cli", "launch", "--resume",
                          str(tmp_path)], env=ros_env, capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 2
    assert f"--resume {tmp_path}: no run.yaml or run.json there" in res.stderr


def test_a_second_formation_on_the_same_domain_and_namespace_is_refused(ros_env, tmp_path):
    trials = 60  # the first run must still be going when the second one looks
    first = start(ros_env, tmp_path / "a", "paper-triangle3", "--trials", str(trials),
                  "--seed", str(SEED))
    try:
        wait_rows(first, tmp_path / "a" / "metrics.csv", 1)
        second = subprocess.run(
            [sys.executable, "-m", "formation_ilc.cli", "launch", "paper-triangle3",
             "--trials", "3", "--out", str(tmp_path / "b"), "--domain-id",
             ros_env["ROS_DOMAIN_ID"], "--no-plots"],
            env=ros_env, capture_output=True, text=True, timeout=120)
        out, _ = first.communicate(timeout=180)
    finally:
        stop_group(first)
    assert second.returncode == 2, second.stdout + second.stderr
    probe = "another formation runs on ROS_DOMAIN_ID" in second.stderr
    if probe:
        # it names what it saw of the first one (discovery within the probe may be partial)
        seen = re.search(r"in namespace /formation \(([^)]*)\)", second.stderr)
        assert seen, second.stderr
        names = seen.group(1).split(", ")
        assert names and all(n.startswith("/formation/") for n in names), names
    else:
        # discovery took longer than the launcher's probe (a loaded machine): the second
        # leader, which waits longer before trial 0, refuses instead, on the first run's
        # configuration or on its config writer, whichever it sees first
        assert ("publishes its configuration on /formation/config" in second.stderr
                or "another formation's leader publishes on /formation/config"
                in second.stderr), second.stderr
    # the first run was not disturbed
    assert first.returncode == 0, out
    got = read_metrics(tmp_path / "a" / "metrics.csv")
    ref = simulate(load_scenario("paper-triangle3").with_options(seed=SEED), trials=trials)
    np.testing.assert_allclose(got[:, 1:], ref.metrics[:, 1:], rtol=0, atol=TOL)
    diag = json.loads((tmp_path / "a" / "diagnostics.json").read_text())
    if probe:  # it never saw the second one (else its nodes ran a moment: other runs'
        # events and readies were dropped as foreign, their poses as stale)
        assert all(sum(d.get("dropped", {}).values()) == 0 for d in diag.values()), diag
