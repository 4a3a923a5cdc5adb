"""The launcher summarises what its nodes warned of, one line per process."""

from __future__ import annotations

from formation_ilc.cli.report import log_warnings


def test_warnings_are_counted_per_process_with_the_one_said_most_often(tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "robot_2.log").write_text(
        "[INFO] [1700000000.1] [formation.robot_2]: ready\n"
        + "".join(f"[WARN] [1700000000.{i}] [formation.robot_2]: link 1->2 late by {i} ms\n"
                  for i in range(5))
        + "[ERROR] [1700000001.0] [formation.robot_2]: lost the leader\n")
    (logs / "bridge_1.log").write_text(
        "[WARN] [1700000000.5] [formation.bridge_1]: odometry stale for 0.4 s\n")
    (logs / "virtual_leader.log").write_text("[INFO] [1700000000.1] [x]: all good\n")
    lines = log_warnings(logs)
    assert lines[0] == f"node warnings, in {logs}/NAME.log:"
    assert lines[1] == ("  robot_2: 6 line(s); most often (5x, WARN): link 1->2 late by "
                        "0 ms")
    assert lines[2].startswith("  bridge_1: 1 line(s); most often (1x, WARN): odometry")
    assert len(lines) == 3
    assert log_warnings(tmp_path / "none") == []
    assert len(log_warnings(logs, limit=1)) == 2
    assert log_warnings(logs, limit=1)[0].startswith("node warnings (and 1 more)")
