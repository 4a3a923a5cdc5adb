"""The shipped params files, started as their headers say (one process each, no launcher),
run one team to the end; a node started from other values is named by the leader, with
both values, and the leader stops (issue 30)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from ..procs import stop_group

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

PARAMS = Path(__file__).resolve().parents[2] / "params"

#: the team of virtual_leader.yaml's header: (module, ROS arguments)
TEAM = [
    ("virtual_leader.node", ["--params-file", str(PARAMS / "virtual_leader.yaml")]),
    ("robot_sim.node", ["--params-file", str(PARAMS / "robot_sim.yaml")]),
    ("formation_ilc.nodes.robot", ["-r", "__node:=robot_1", "--params-file",
                                   str(PARAMS / "robot.yaml")]),
    ("formation_ilc.nodes.robot", ["--params-file", str(PARAMS / "team.yaml")]),
    ("formation_ilc.nodes.robot", ["--params-file", str(PARAMS / "team.yaml"), "-p",
                                   "robot_id:=3"]),
]


def start(ros_env: dict[str, str], tmp_path: Path, leader_extra: list[str]
          ) -> list[subprocess.Popen]:
    procs = []
    for i, (module, args) in enumerate(TEAM):
        extra = leader_extra if i == 0 else []
        log = (tmp_path / f"{i}.log").open("w")
        procs.append(subprocess.Popen([sys.executable, "-m", module, "--ros-args", *args,
                                       *extra], env=ros_env, stdout=log,
                                      stderr=subprocess.STDOUT, text=True,
                                      start_new_session=True))
    return procs


def test_the_shipped_params_files_run_one_team_to_the_end(ros_env, tmp_path):
    # the leader's file runs 20 trials; 2 here (-p wins over the file), and its process
    # ends after the last one, as a launch file has it
    procs = start(ros_env, tmp_path, ["-p", "trials:=2", "-p", "exit_when_done:=true"])
    try:
        code = procs[0].wait(timeout=300)
        log = (tmp_path / "0.log").read_text()
        assert code == 0, log
        assert "done: 2 trials" in log
        assert "disagree" not in log
        for i, p in enumerate(procs[1:], 1):
            assert p.poll() is None, (tmp_path / f"{i}.log").read_text()  # all ran through
    finally:
        for p in procs:
            stop_group(p)


def test_a_robot_that_runs_other_links_than_the_leader_is_named_and_the_leader_stops(
        ros_env, tmp_path):
    """The case of the issue: the leader's file said emulated links, the robots' direct.
    The leader used to wait for the link emulator forever; now the first robot's ready
    names the difference and the leader stops with status 2."""
    t0 = time.monotonic()
    procs = start(ros_env, tmp_path, ["-p", "links:=emulated"])
    try:
        code = procs[0].wait(timeout=120)
        took = time.monotonic() - t0
        log = (tmp_path / "0.log").read_text()
        assert code == 2, log
        line = next(ln for ln in log.splitlines() if "disagree" in ln
                    and ln.startswith("virtual_leader:"))
        assert "links: robot_" in line and " runs direct, virtual_leader emulated" in line
        print(f"named {took:.1f} s after the five processes were started")
    finally:
        for p in procs:
            stop_group(p)
