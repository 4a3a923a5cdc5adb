"""The launcher's start-up lines (formation_ilc.cli.launch.StartupProgress), without ROS: a
line at least every second until the first trial starts, sooner when a count moves, whom
it waits for once start-up takes long, and the times that go into summary.json."""

from __future__ import annotations

from formation_ilc.cli.launch import StartupProgress

NODES = ["robot_1", "robot_2", "robot_sim", "monitor"]


def lines(p: StartupProgress, steps):
    out = []
    for now, found, ready, started in steps:
        line = p.update(now, set(found), set(ready), started)
        if line is not None:
            out.append((now, line))
    return out


def test_a_line_at_least_every_second_until_the_first_trial_then_none():
    p = StartupProgress(NODES, t0=10.0)
    got = lines(p, [(10.0 + 0.05 * i, (), (), False) for i in range(61)])  # 3 s, nothing
    times = [t for t, _ in got]
    assert times[0] == 10.0
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    assert gaps and max(gaps) <= 1.0 + 1e-9  # never silent for longer than a second
    assert got[0][1] == "start-up [0.0 s]: 0 of 4 nodes found, 0 ready"
    assert p.active
    done = p.update(13.5, set(NODES), set(NODES), True)
    assert done == "start-up done [3.5 s]: 4 nodes ready, the first trial starts"
    assert not p.active
    assert p.update(14.0, set(), set(), False) is None
    assert p.update(20.0, set(), set(), True) is None


def test_a_count_that_moves_is_shown_soon_once_for_changes_close_together():
    p = StartupProgress(NODES, t0=0.0)
    assert p.update(0.0, set(), set(), False) is not None
    assert p.update(0.1, {"robot_1"}, set(), False) is None  # within a quarter second
    line = p.update(0.3, {"robot_1", "robot_2"}, {"robot_1"}, False)
    assert line == "start-up [0.3 s]: 2 of 4 nodes found, 1 ready"
    assert p.update(0.5, {"robot_1", "robot_2"}, {"robot_1"}, False) is None  # no change
    # names outside the team (another node on the domain) are not counted
    line = p.update(1.3, {"robot_1", "robot_2", "teleop"}, {"robot_1", "x"}, False)
    assert line == "start-up [1.3 s]: 2 of 4 nodes found, 1 ready"  # a second on


def test_after_a_while_it_names_whom_it_waits_for_and_records_the_times():
    team = [f"robot_{i}" for i in range(1, 10)] + ["robot_sim"]
    p = StartupProgress(team, t0=0.0, name_after=5.0)
    assert "waiting for" not in (p.update(4.0, set(team), {"robot_sim"}, False) or "")
    assert p.found_at == 4.0 and p.ready_at is None
    line = p.update(6.0, set(team), {"robot_sim", "robot_2"}, False)
    assert line == ("start-up [6.0 s]: 10 of 10 nodes found, 2 ready; waiting for robot_1, "
                    "robot_3, robot_4, robot_5, robot_6, robot_7 and 2 more")
    line = p.update(8.0, set(team), set(team), False)
    assert line is not None and line.endswith("waiting for the leader to start the first trial")
    assert p.ready_at == 8.0
    p.update(9.0, set(team), set(team), True)
    assert p.summary() == {"all_found_s": 4.0, "all_ready_s": 8.0, "first_start_s": 9.0}
