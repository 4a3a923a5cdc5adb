"""One command per machine, tested as four machines on one: a run file written with
``run-file paper-triangle3 --host-per-robot`` run by four launchers (``launch RUN.yaml
--host ground``, ``--host r1``, ``r2``, ``r3``), each its own process tree and, as separate
machines, each in a mount namespace of its own with its own disk at the output path (no
folder in common: the ground station hands the run over the ROS graph). The run is
lockstep with emulated links, so its metrics equal the batch simulator's on the same seed
(to 1e-9); the r2 launcher is SIGKILLed during trial 3 (its robot dies with it) and started
again 5 s later on its own disk: the ground station names the host that left and came back,
the trial it interrupted runs again from the memory r2 kept, and the run ends with status 0
and the simulator's metrics."""

from __future__ import annotations

import json
import os
import shutil
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

from ..procs import stop_group

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

TRIALS = 6
SEED = 5


def launcher(env: dict[str, str], run_file: Path, host: str, log: Path, *extra: str,
             disk: Path | None = None, out: Path | None = None) -> subprocess.Popen:
    """Host ``host``'s launcher; with ``disk``, as a machine of its own: in a mount
    namespace of its own where ``disk`` is mounted at the run's output path ``out``."""
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", str(run_file), "--host", host,
            *extra]
    if disk is not None:
        disk.mkdir(parents=True, exist_ok=True)
        argv = ["unshare", "-m", "--propagation", "private", "sh", "-c",
                'mount --bind "$1" "$2" && shift 2 && exec "$@"', "_", str(disk), str(out),
                *argv]
    return subprocess.Popen(argv, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT,
                            start_new_session=True)


def own_disks_problem() -> str:
    """Why launchers cannot have disks of their own here ("" when they can)."""
    if os.geteuid() != 0:
        return "mount namespaces of their own need root (unshare -m, mount --bind)"
    if shutil.which("unshare") is None:
        return "no unshare (util-linux)"
    return ""


@pytest.mark.parametrize("disks", ["shared", "own"])
def test_four_host_launchers_run_the_team_and_a_killed_host_rejoins(ros_env, tmp_path, disks):
    from formation_ilc.cli.commands import main

    if disks == "own" and own_disks_problem():
        pytest.skip(own_disks_problem())
    run_file = tmp_path / "run.yaml"
    out = tmp_path / "run"
    assert main(["run-file", "paper-triangle3", "--trials", str(TRIALS), "--seed", str(SEED),
                 "--no-plots", "--domain-id", ros_env["ROS_DOMAIN_ID"], "--out", str(out),
                 "--host-per-robot", "-o", str(run_file)]) == 0
    out.mkdir()
    # each machine's own disk, mounted at the output path in its own mount namespace only
    disk = {h: (tmp_path / "disks" / h if disks == "own" else None)
            for h in ("r1", "r2", "r3", "ground")}
    procs = {h: launcher(ros_env, run_file, h, tmp_path / f"{h}.log", disk=disk[h], out=out)
             for h in ("r1", "r2", "r3", "ground")}
    ground_out = disk["ground"] or out
    assert not list(out.iterdir())  # (this test's own view: nothing there)
    again = None
    try:
        metrics = ground_out / "metrics.csv"
        deadline = time.monotonic() + 120
        while not (metrics.exists() and len(metrics.read_text().splitlines()) > 2):
            assert procs["ground"].poll() is None, (tmp_path / "ground.log").read_text()
            assert time.monotonic() < deadline, "trial 3 never started"
            time.sleep(0.05)  # polling a file, bounded by the deadline
        os.kill(procs["r2"].pid, signal.SIGKILL)  # the launcher alone: its robot dies with it
        procs["r2"].wait()
        time.sleep(5.0)  # the machine is away for 5 s (the scenario)
        again = launcher(ros_env, run_file, "r2", tmp_path / "r2-again.log", disk=disk["r2"],
                         out=out)
        assert procs["ground"].wait(timeout=180) == 0, (tmp_path / "ground.log").read_text()
        for h in ("r1", "r3"):
            assert procs[h].wait(timeout=30) == 0, (tmp_path / f"{h}.log").read_text()
        assert again.wait(timeout=30) == 0, (tmp_path / "r2-again.log").read_text()
    finally:
        for p in [*procs.values(), *([again] if again is not None else [])]:
            stop_group(p)
    ground = (tmp_path / "ground.log").read_text()
    assert "not heard from host" in ground  # start-up names the hosts it waits for
    # the graph shows r2 gone and back, or (restarted within the DDS lease: the old
    # participant still in the graph) its robot says ready from a new launcher
    assert ("host r2: its members (robot_2) left the ROS graph" in ground
            and "host r2: back after" in ground) or (
        "host r2: its launcher was started again" in ground), ground
    rows = ground[ground.index("\nhosts:\n"):]
    assert "r1         robot_1: present throughout" in rows
    assert "r2         robot_2: left 1 time(s)" in rows
    assert "r3         robot_3: present throughout" in rows
    hosts = json.loads((ground_out / "summary.json").read_text())["hosts"]
    assert hosts["r2"]["left"] == 1 and hosts["r1"]["left"] == 0 and hosts["ground"]["ground"]
    # each host's logs and its robot's state in its own folder, on its own disk
    r2 = (disk["r2"] or out) / "hosts" / "r2"
    assert (r2 / "logs" / "robot_2.log").exists()
    assert (r2 / "state").is_dir()
    assert not (ground_out / "hosts" / "ground.json").exists()  # handed over the graph
    if disks == "own":
        assert not list(out.iterdir())  # nobody wrote into a folder in common
        assert not (disk["ground"] / "hosts" / "r2").exists()
        assert not (disk["r1"] / "hosts" / "r2").exists()
        assert not (disk["r2"] / "metrics.csv").exists()
    got = np.array(read_metrics(metrics))
    want = simulate(load_scenario("paper-triangle3").with_options(seed=SEED),
                    trials=TRIALS).metrics
    assert got.shape[0] == TRIALS
    np.testing.assert_allclose(got[:, 1:7], want[:, 1:7], rtol=0, atol=1e-9)


def test_a_host_that_never_starts_is_named_first_with_the_command_that_starts_it(
        ros_env, tmp_path):
    """r2's launcher never starts: the ground station's first error line names r2 and the
    command to run there (the leader's long finding named the host last), its start-up lines
    come when a count moves, not each second, and the run ends stuck (4)."""
    from formation_ilc.cli.commands import main

    run_file = tmp_path / "run.yaml"
    out = tmp_path / "run"
    assert main(["run-file", "paper-triangle3", "--trials", "2", "--no-plots",
                 "--watchdog-scale", "0.2", "--domain-id", ros_env["ROS_DOMAIN_ID"], "--out",
                 str(out), "--host-per-robot", "-o", str(run_file)]) == 0
    procs = {h: launcher(ros_env, run_file, h, tmp_path / f"{h}.log")
             for h in ("r1", "r3", "ground")}
    try:
        assert procs["ground"].wait(timeout=240) == 4, (tmp_path / "ground.log").read_text()
    finally:
        for p in procs.values():
            stop_group(p)
    ground = (tmp_path / "ground.log").read_text()
    errors = [line for line in ground.splitlines()
              if line.startswith("error:") or line.startswith("virtual_leader:")]
    assert errors and errors[0].startswith(
        f"error: host r2 (robot_2) never joined: start `formation-ilc launch {run_file} "
        f"--host r2` on it"), ground
    assert "r2         robot_2: never heard from" in ground
    startup = [line for line in ground.splitlines() if line.startswith("start-up [")]
    seconds = float(startup[-1].split("[", 1)[1].split(" s]", 1)[0])
    # (a line a second before: one line per second of start-up)
    assert len(startup) <= seconds / 10 + 12, startup
