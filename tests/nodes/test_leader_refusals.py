"""The leader refuses what no run can have, with one line and status 2 (not restarted),
before it publishes anything: ``trials:=-5`` said "done" at once and never exited; a
damaged or impossible ``leader.json`` (a launcher would restart a traceback)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros]


def leader(*params: str, env=None) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, "-m", "virtual_leader.node", "--ros-args",
            "-p", "scenario:=paper-triangle3", *[a for p in params for a in ("-p", p)]]
    return subprocess.run(argv, capture_output=True, text=True, timeout=120, env=env)


@pytest.mark.parametrize("param, why", [
    ("trials:=-5", "parameter trials: -5 is outside 0 .. inf (number of trials; 0 keeps the "
                   "scenario's)"),
    ("gap:=0", "parameter gap: 0 is outside 1 .. inf (samples between two trials on the "
               "label grid)"),
    ("timeout:=-1.0", "parameter timeout: -1.0 is outside 0.001 .. 1e+06 (lockstep: how long "
                      "the plant waits for a robot's command before it stops)"),
])
def test_impossible_parameters_are_one_line_and_status_2(ros_env, param, why):
    res = leader(param, env=ros_env)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert lines == [f"formation-ilc-leader: {why}"]


def test_an_impossible_state_file_is_one_line_naming_it(ros_env, tmp_path):
    (tmp_path / "leader.json").write_text(json.dumps(
        {"committed": 999, "slot": 999, "seq": 999, "open": False}))
    res = leader("trials:=10", f"state_dir:={tmp_path}", env=ros_env)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(
        f"formation-ilc-leader: {tmp_path}/leader.json: impossible schedule state: "
        f"committed 999 is not in 0..10"), res.stderr
    assert "Traceback" not in res.stderr
