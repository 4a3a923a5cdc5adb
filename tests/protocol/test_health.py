"""Standard diagnostics' levels by the documented thresholds, and reports as key/value
pairs without loss (formation_ilc.protocol.health)."""

from __future__ import annotations

import pytest

from formation_ilc.protocol.health import ERROR, OK, WARN, assess, flatten, statuses, unflatten


@pytest.mark.parametrize("report", [
    {"node": "robot_1", "trial": 2, "slot": 2, "commands": 120, "missed": 0,
     "delays": {"robot_2": {"0": 40, "1": 80}, "leader": {}}, "dropped": {"stale": 3},
     "dropped_by_topic": {"stale:robot_2/shared_pose": 3}},
    {"node": "virtual_leader", "trial": -1, "watchdog": {"count": 1, "what": "waits: x"},
     "timing": {"p50_ms": 1.25, "nan": float("inf")}, "initial_shifts": {"0": [1.0, 2, 3]}},
])
def test_a_report_survives_its_key_value_pairs(report):
    pairs = flatten(report)
    assert all(isinstance(k, str) and isinstance(v, str) for k, v in pairs)
    assert unflatten(pairs) == report


def test_pairs_that_are_not_a_report_are_refused():
    with pytest.raises(ValueError):
        unflatten([("trial", "not json")])
    with pytest.raises(ValueError):
        unflatten([("trial", "1"), ("trial.x", "2")])


@pytest.mark.parametrize("report, level, words", [
    ({"node": "robot_1", "trial": 0, "missed": 0, "dropped": {"stale": 9}}, OK, "ok"),
    ({"node": "robot_1", "trial": 0, "missed": 1}, WARN, "1 samples missed"),
    ({"node": "robot_sim", "trial": 0, "missed": {"robot_1": 0, "robot_2": 5}}, ERROR,
     "5 samples missed (robot_2 5)"),
    ({"node": "robot_1", "trial": 0, "dropped": {"malformed": 2}}, WARN, "2 malformed"),
    ({"node": "robot_1", "trial": 0, "late": {"links": 3}}, WARN, "3 late links"),
    ({"node": "robot_sim", "trial": 0, "timing": {"commands": 9, "p99_ms": 60.0}}, WARN,
     "p99 60 ms > 0.5 dT"),
    ({"node": "robot_sim", "trial": 0, "timing": {"commands": 9, "p99_ms": 120.0}}, ERROR,
     "p99 120 ms > dT"),
    ({"node": "bridge_1", "trial": 0, "clipped": 4, "return_timeouts": 1}, WARN,
     "4 commands clipped; 1 return time-outs"),
    ({"node": "virtual_leader", "trial": 0, "watchdog": {"count": 1, "what": "stuck"}}, WARN,
     "watchdog: stuck"),
    ({"node": "robot_2", "trial": 0, "filter": {"slot": 0, "changed": 30, "barrier": 30,
                                                "infeasible": 0, "stale": 140, "late": 0}},
     OK, "ok"),  # poses a sample old, as bridges on their own clocks hear each other
    ({"node": "robot_2", "trial": 0, "filter": {"slot": 0, "changed": 30, "barrier": 30,
                                                "infeasible": 0, "late": 12, "late_ms": 600}},
     WARN, "12 samples braked or flagged on poses more than a sample old (up to 600 ms)"),
])
def test_levels_follow_the_thresholds(report, level, words):
    lv, message = assess(report, dt=0.1, samples=40)
    assert lv == level and words in message


def test_the_plant_speaks_for_each_robot():
    st = statuses({"node": "robot_sim", "trial": 1, "missed": {"robot_1": 0, "robot_2": 2}},
                  0.1, 40)
    assert [(s.name, s.hardware_id, s.level) for s in st] == [
        ("robot_sim", "", WARN), ("robot_sim: robot_1", "robot_1", OK),
        ("robot_sim: robot_2", "robot_2", WARN)]
    assert st[2].values == {"robot": "robot_2", "trial": 1, "missed": 2}


def test_standard_names_hardware_and_plain_values():
    """The standard stream's form (``/diagnostics``): ``node: task`` as diagnostic_updater
    names a status, the robot (or the host) as hardware, values as ROS tools show them."""
    from formation_ilc.protocol.health import hardware_of, plain_value, task_name

    assert task_name("robot_2") == "robot_2: learner"
    assert task_name("bridge_1") == "bridge_1: bridge"
    assert task_name("virtual_leader") == "virtual_leader: schedule"
    assert task_name("robot_sim") == "robot_sim: plant"
    assert task_name("link_emulator") == "link_emulator: links"
    assert hardware_of("bridge_3", "host") == hardware_of("robot_3", "host") == "robot_3"
    assert hardware_of("virtual_leader", "host") == "host"
    pairs = dict(flatten({"node": "robot_1", "trial": 3, "ok": True, "why": "late 2",
                          "seq": [1, 2], "text": "3"}))
    assert {k: plain_value(v) for k, v in pairs.items()} == {
        "node": "robot_1", "trial": "3", "ok": "true", "why": "late 2", "seq": "[1,2]",
        "text": "3"}


def test_the_console_warns_of_a_filter_that_keeps_acting_and_why():
    from formation_ilc.protocol.health import filter_warnings

    falling = [300, 250, 200, 120, 60, 30, 10, 4, 2, 1, 0, 0]
    assert filter_warnings(falling, {}, 450) == []
    # the paper's triangle with noise, from poses: 115-150 a trial from trial 3 on
    stuck = [20, 90, 110, 130, 140, 125, 150, 118, 133, 141, 129, 137]
    (line,) = filter_warnings(stuck, {"robot_1": None}, 450)
    assert "kept acting" in line and "137" not in line and "over the last 6 trials" in line
    # a few commands a trial is no stall: fewer than one in 200
    assert filter_warnings([4, 2, 3, 2], {}, 900) == []
    totals = {"robot_2": {"infeasible": 3, "late": 0, "untold": 0},
              "robot_1": {"infeasible": 1, "late": 0, "untold": 7}, "robot_3": None}
    lines = filter_warnings([0, 0], totals, 450)
    assert len(lines) == 2
    assert "outside its guarantee" in lines[0] and "robot_1 1, robot_2 3" in lines[0]
    assert "told command" in lines[1] and "robot_1 7" in lines[1]


def test_a_filter_that_keeps_clipping_to_the_limits_is_told_apart_from_barriers():
    """Under noise the law learns a rougher command than the base can follow and the
    limits keep clipping it: the warning says so, not that robots are held apart; poses
    that missed their estimate's box are named by robot."""
    from formation_ilc.protocol.health import filter_warnings

    rising = [2, 9, 18, 30, 39, 50, 72, 92, 87, 101, 120, 117]
    clipped = {"robot_1": {"limits": 400, "barrier": 3, "box_missed": 0},
               "robot_2": {"limits": 380, "barrier": 0, "box_missed": 2}}
    kept, missed = filter_warnings(rising, clipped, 980)
    assert "kept acting" in kept and "limits clipping the learned command (780" in kept
    assert "a barrier moved 3" in kept
    assert "off the position its told commands allow" in missed and "robot_2 2" in missed
    held = {"robot_1": {"limits": 40, "barrier": 300}}
    (line,) = filter_warnings(rising, held, 980)
    assert "held near its bounds" in line
