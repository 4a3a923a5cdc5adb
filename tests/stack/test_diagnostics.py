"""Standard diagnostics during a run: a test node reads ``diagnostics`` as
diagnostic_msgs/DiagnosticArray while a realtime stack runs, finds every node's status, and
a robot held with SIGSTOP in the middle of a trial turns its status (the plant's, per robot:
a stopped robot cannot speak for itself) to WARN."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from typing import Any

import pytest

from formation_ilc.core.clock import SampleClock
from formation_ilc.protocol.health import WARN

from ..procs import find_child, stop_group
from .test_realtime import short_scenario

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]

rclpy = pytest.importorskip("rclpy")


def test_every_node_reports_and_a_stopped_robot_turns_warn(ros_env, tmp_path):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    import msgs_schema as ms

    ctx = Context()
    rclpy.init(context=ctx)
    # outside the formation's namespace: the launcher refuses to start beside its nodes
    node = rclpy.create_node("diag_reader", namespace="/watcher", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    seen: list = []
    poses: list[tuple[int, int]] = []
    node.create_subscription(DiagnosticArray, ms.absolute(ms.DIAGNOSTICS),
                             lambda m: seen.extend(m.status), ms.LATCHED_READER_QOS)
    # the standard stream, as the aggregator and rqt_robot_monitor read it: arrival time
    # of each status by name
    standard: dict[str, list[tuple[float, Any]]] = {}

    def on_standard(m: DiagnosticArray) -> None:
        for st in m.status:
            standard.setdefault(st.name, []).append((time.monotonic(), st))
    node.create_subscription(DiagnosticArray, ms.ROS_DIAGNOSTICS, on_standard,
                             ms.ROS_DIAGNOSTICS_QOS)
    # the label of each pose says its trial and sample (the run's default grid)
    grid = SampleClock.for_run(0.05, 120)
    node.create_subscription(PoseStamped, ms.absolute(ms.pose_topic(2)),
                             lambda m: poses.append(label(m)), ms.SAMPLE_QOS)

    def label(m: PoseStamped) -> tuple[int, int]:
        try:
            return grid.decode(ms.stamp_to_ns(m.header.stamp))
        except ValueError:
            return -1, -1
    scenario = short_scenario(tmp_path)
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", str(scenario),
            "--trials", "3", "--seed", "5", "--mode", "realtime", "--out",
            str(tmp_path / "run"), "--domain-id", ros_env["ROS_DOMAIN_ID"], "--no-plots"]
    proc = subprocess.Popen(argv, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    stopped_at = None
    victim = None
    run = {"mode": "realtime", "links": "emulated", "seed": 5, "noise": True, "delay": True,
           "scenario": str(scenario.resolve())}
    # what the run uses, as each node's parameters must read it (the robots and the plant
    # were given none of it: it came with the leader's configuration)
    expected_params: dict[str, dict[str, Any]] = {
        **{f"robot_{i}": {**run, "robot_id": i} for i in (1, 2, 3)},
        ms.LEADER_NODE: {**run, "trials": 3, "law": 9, "memory": "feedforward",
                         "nodes_expected": ["robot_1", "robot_2", "robot_3", ms.SIM_NODE,
                                            ms.LINKS_NODE, "monitor"]},
        ms.SIM_NODE: {"timeout": 30.0},
    }
    params_read: dict[str, dict[str, Any]] | None = None
    try:
        deadline = time.monotonic() + 300
        while proc.poll() is None:
            assert time.monotonic() < deadline, "the run did not end"
            ex.spin_once(timeout_sec=0.05)
            if victim is None and poses:
                victim = find_child(ros_env["ROS_DOMAIN_ID"], "robot_id:=2",
                                    time.monotonic() + 10)
            # early in trial 1, with most of the trial (and its deadlines) still ahead: a
            # pose from between trials or a re-sent one from trial 0 does not count
            inside = [s for k, s in poses if k == 1 and 1 <= s <= 60]
            poses.clear()
            if params_read is None and victim is not None and inside:
                # while trial 1 runs: every node's parameters over its parameter services
                params_read = {n: read_parameters(ex, node, n, list(want))
                               for n, want in expected_params.items()}
            if stopped_at is None and victim is not None and inside:
                os.kill(victim, signal.SIGSTOP)
                try:
                    time.sleep(0.4)  # a stop of a known length (8 samples), not a wait
                finally:
                    os.kill(victim, signal.SIGCONT)
                stopped_at = time.monotonic()
        out, _ = proc.communicate(timeout=60)
        for _ in range(20):  # what is still queued
            ex.spin_once(timeout_sec=0.05)
    finally:
        stop_group(proc)
        ex.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
    assert proc.returncode == 0, out
    assert stopped_at, "robot_2 was never stopped inside a trial"
    assert params_read is not None
    for name, want in expected_params.items():
        got = params_read[name]
        if name == ms.LEADER_NODE:
            assert sorted(got.pop("nodes_expected")) == sorted(want["nodes_expected"])
            want = {k: v for k, v in want.items() if k != "nodes_expected"}
        assert got == want, name
    names = {s.name for s in seen}
    for expected in ("robot_1", "robot_2", "robot_3", ms.SIM_NODE, ms.LINKS_NODE,
                     ms.LEADER_NODE):
        assert expected in names, names
    # every status is a standard one: a level, the node's report as key/value pairs
    assert all(s.level[0] in (0, 1, 2) and s.values for s in seen)
    robot2 = [s for s in seen if s.name == f"{ms.SIM_NODE}: robot_2"]
    assert robot2 and all(s.hardware_id == "robot_2" for s in robot2)
    warned = [s for s in robot2 if s.level[0] >= WARN]
    assert warned, [(s.level, s.message) for s in robot2]
    assert "samples missed" in warned[0].message and warned[0].hardware_id == "robot_2"
    # /diagnostics: every node's status named ``node: task``, with a hardware id and plain
    # values, about once a second all through the run (a live node never goes stale)
    for name in ("robot_1: learner", "robot_2: learner", "robot_3: learner",
                 f"{ms.SIM_NODE}: plant", f"{ms.LINKS_NODE}: links",
                 f"{ms.LEADER_NODE}: schedule"):
        got = standard.get(name)
        assert got and len(got) >= 5, (name, sorted(standard))
        assert all(st.hardware_id for _, st in got)
        gaps = sorted(b - a for (a, _), (b, _) in zip(got, got[1:], strict=False))
        median = gaps[len(gaps) // 2]
        assert 0.3 < median < 1.5, (name, median)  # the period, 1 s
        last = got[-1][1]
        values = {kv.key: kv.value for kv in last.values}
        assert values["node"] == name.split(":")[0]  # a name as text, no JSON quotes
        assert not any(v.startswith('"') for v in values.values()), values
    robots = [st for _, st in standard[f"{ms.SIM_NODE}: robot_2"]]
    assert all(st.hardware_id == "robot_2" for st in robots)


def read_parameters(ex: Any, node: Any, name: str, names: list[str]) -> dict[str, Any]:
    """The values of ``names`` of node ``/formation/NAME``, over its parameter services."""
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient

    client = AsyncParameterClient(node, f"/formation/{name}")
    deadline = time.monotonic() + 30
    while not client.services_are_ready():
        assert time.monotonic() < deadline, f"{name}: no parameter services"
        ex.spin_once(timeout_sec=0.05)
    fut = client.get_parameters(names)
    ex.spin_until_future_complete(fut, timeout_sec=30)
    assert fut.done(), f"{name}: parameters not read"
    values = [parameter_value_to_python(v) for v in fut.result().values]
    return {k: (list(v) if isinstance(v, (list, tuple)) else v) for k, v in zip(names, values,
                                                                                   strict=True)}
