"""The virtual leader's node (virtual_leader.node) in-process and as a process: the endpoints
its start waits for, its repeated start, its wall-clock start and reference, the team it
waits for alone, hostile input to its handlers, and its one-line refusals (its decisions
themselves: tests/protocol/test_leader.py).
"""

from __future__ import annotations

import contextlib
import json
import subprocess
import sys
import time

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import PoseStamped  # noqa: E402
from hypothesis import example, given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import String  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from tests.hostile import CLOCK, FUZZ, SCENARIO, Outcomes, _time, clocks, dropped, in_grid, readies  # noqa: E402

from ..procs import spin_until  # noqa: E402


@contextlib.contextmanager
def leader_and_tester(context, mode: str):
    """A leader of paper-triangle3 (one trial, direct links, ``mode``), a tester node
    beside it, and the executor of both; all three ended afterwards."""
    from virtual_leader.node import LeaderNode

    leader = LeaderNode(context=context, parameter_overrides=[
        Parameter("scenario", value="paper-triangle3"), Parameter("trials", value=1),
        Parameter("links", value="direct"), Parameter("mode", value=mode)])
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(leader)
    ex.add_node(tester)
    try:
        yield leader, tester, ex
    finally:
        ex.shutdown()
        leader.destroy_node()
        tester.destroy_node()


def read_events(leader, tester, on_event=lambda m: None) -> None:
    """A reader of the trial events in the tester for each node the leader waits for (the
    leader's start waits until its writer matched them all, and its own); ``on_event``
    gets what the first one reads."""
    tester.create_subscription(String, ms.TRIAL_EVENTS, on_event, ms.SAMPLE_QOS)
    for _ in leader.expected[1:]:
        tester.create_subscription(String, ms.TRIAL_EVENTS, lambda m: None, ms.SAMPLE_QOS)


def all_ready(leader) -> None:
    """Every node the leader waits for says ready for trial 0."""
    from formation_ilc.protocol.schedule import Ready

    for node in leader.expected:
        leader._on_ready(ms.json_to_msg(Ready(node, 0, "boot").to_json()))


def test_leader_names_the_endpoints_its_start_waits_for(context):
    """Every node is ready, but no robot reads the reference yet: what the leader says it
    waits for names the topic and the count (it said "nobody" before), and the names go
    once the readers are there."""
    with leader_and_tester(context, "realtime") as (leader, tester, ex):
        leader._gate.cancel()  # no start: what it waits for is the question
        all_ready(leader)
        assert not leader.core.sched.explain_wait(leader.core.refused)  # every node is ready
        waits = leader.core.start_waits_for()
        ref = f"{ms.NAMESPACE}/{ms.REFERENCE}"
        assert f"{ref}: 0 of 1 readers" in waits  # robot 1 sees the leader
        assert "/clock: 0 of 1 writers" in waits  # no plant yet
        # the events' writer has matched only the leader's own reader: a start now would
        # not reach the followers its writer has not matched yet
        events = f"{ms.NAMESPACE}/{ms.TRIAL_EVENTS}"
        n = len(leader.expected) + 1
        assert f"{events}: 1 of {n} readers" in waits
        # the readers come: each phrase goes with its endpoint
        tester.create_subscription(PoseStamped, ms.REFERENCE, lambda m: None, ms.SAMPLE_QOS)
        read_events(leader, tester)
        spin_until(ex, lambda: leader.core.start_waits_for() == ["/clock: 0 of 1 writers"])
        assert leader.core.start_waits_for() == ["/clock: 0 of 1 writers"]


def test_leader_sends_a_start_again_while_its_slot_does_not_move(context):
    """A follower whose reader matched after the start went out never gets it (the events
    topic keeps nothing for a late reader), and a lockstep trial would wait for it until the
    plant's time-out: while the slot has no new sample for RESEND_S / 2 the leader sends the
    same start again (same seq), and stops once a sample comes."""
    from rosgraph_msgs.msg import Clock

    from formation_ilc.protocol.plant import RESEND_S

    with leader_and_tester(context, "lockstep") as (leader, tester, ex):
        events: list[dict] = []
        read_events(leader, tester, lambda m: events.append(ms.msg_to_json(m)))
        clock_pub = tester.create_publisher(Clock, ms.CLOCK, ms.CLOCK_QOS)
        all_ready(leader)
        starts = lambda: [e for e in events if e["event"] == "start"]  # noqa: E731
        spin_until(ex, lambda: len(starts()) >= 1, timeout=30)
        first = starts()[0]
        assert first["slot"] == 0 and leader.core.sched.running
        # nobody sends sample 0: the same start goes out again, and again
        spin_until(ex, lambda: len(starts()) >= 3, timeout=6 * RESEND_S)
        assert all(e == first for e in starts())
        assert leader.core.repeat.count >= 2
        # the plant's first sample: the slot moves, the repeats stop until it stalls again
        clock_pub.publish(ms.clock_msg(first["stamp_ns"]))
        spin_until(ex, lambda: leader.core.t == 0)
        assert leader.core.repeat.due == leader.core.last_change + leader.core.repeat.every
        n = leader.core.repeat.count
        # an abort ends the slot: nothing is repeated after it
        leader.core.sched.begin_abort("test")
        leader.core.aborted("test")
        assert (leader.core.repeat.event is None
                and leader.core.repeat.again(time.monotonic() + 99) is None)
        assert leader.core.repeat.count == n


def test_wallclock_leader_agrees_the_start_and_publishes_the_reference_on_its_wall_timer(
        context, tmp_path):
    import yaml
    from geometry_msgs.msg import PoseStamped

    from virtual_leader.node import LeaderNode

    data = yaml.safe_load(load_scenario("paper-triangle3").text)
    data.update(dt=0.05, samples=10, name="triangle3-wall")
    scen = tmp_path / "s.yaml"
    scen.write_text(yaml.safe_dump(data, sort_keys=False))
    margin = 0.3
    leader = LeaderNode(context=context, parameter_overrides=[
        Parameter("scenario", value=str(scen)), Parameter("mode", value="wallclock"),
        Parameter("links", value="direct"), Parameter("trials", value=1),
        Parameter("start_margin", value=margin),
        Parameter("nodes_expected", value=["tester"])])
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(leader)
    ex.add_node(tester)
    try:
        events: list[tuple[int, dict]] = []
        refs: list[tuple[int, int]] = []  # (arrival wall ns, label ns)
        tester.create_subscription(String, ms.TRIAL_EVENTS, lambda m: events.append(
            (time.time_ns(), ms.msg_to_json(m))), ms.SAMPLE_QOS)
        tester.create_subscription(PoseStamped, ms.REFERENCE, lambda m: refs.append(
            (time.time_ns(), ms.stamp_to_ns(m.header.stamp))), ms.SAMPLE_QOS)
        ready = tester.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        # the tester's readers matched too: a reference sent before its reader matched is
        # not delivered (volatile), and the test waited for 11 of 10 (CI of 27 Nov)
        spin_until(ex, lambda: ready.get_subscription_count() >= 1
                   and leader.ref_pub.get_subscription_count() >= 1
                   and leader.event_pub.get_subscription_count() >= 2)  # tester and leader
        ready.publish(ms.json_to_msg({"node": "tester", "trial": 0}))
        clock = leader.cfg.clock
        spin_until(ex, lambda: any(e["event"] == ms.END for _, e in events)
                   and any(clock.decode(label) == (0, 10) for _, label in refs), timeout=10)
        last = clock.stamp_ns(0, 10)
        sent, start = next((t, e) for t, e in events if e["event"] == ms.START)
        t0 = start["start_wall_ns"]
        # the agreed start is the margin ahead of the event
        assert 0 < t0 - sent <= margin * 1e9 + 5e7
        assert t0 % clock.dt_ns == 0  # slot 0 (the start's remainder by dT names the slot)
        # every sample's reference went out once, in order, or was counted missed: a timer
        # that fell behind past a sample (a loaded machine, CI's three test processes on
        # two cores) skips it rather than sending it late, and says so
        labels = [label for _, label in refs]
        assert labels == sorted(set(labels)) and labels[-1] == last
        assert set(labels) <= {clock.stamp_ns(0, s) for s in range(11)}
        assert len(labels) + leader.core.missed_references == 11
        # most went out (a timer that sent only the last, or none on time, fails this);
        # how many a loaded machine skips is its load's, not the leader's: 3 and 4 of 11 in
        # CI runs beside other work, against a bound of 2 that failed them
        assert leader.core.missed_references < 11 / 2, labels
        late = []
        for arrival, label in refs:
            s = clock.decode(label)[1]
            due = t0 + s * clock.dt_ns
            # stamped with the wall time of its sample, from which the label follows
            assert label == due and clock.decode(label) == (0, s)
            assert arrival >= due, s  # never before its sample's wall time
            late.append(arrival - due)
        # on the wall timer, sample by sample, not in a burst at the end: the typical sample
        # is out within two samples of its time (a burst at the end would make it about half
        # the trial, 5 dT), and the arrivals spread over at least half the samples' span. A
        # bound on the median, not on every sample, and not a fraction of dT: a loaded
        # machine delays wake-ups by tens of ms (44 ms median at load 15, against dT 50 ms)
        assert sorted(late)[len(late) // 2] < 2 * clock.dt_ns, [x / 1e6 for x in late]
        span = clock.decode(refs[-1][1])[1] - clock.decode(refs[0][1])[1]
        assert refs[-1][0] - refs[0][0] >= 0.5 * span * clock.dt_ns, [x / 1e6 for x in late]
        # the leader neither follows nor needs /clock in wall-clock trials
        assert leader.count_subscribers(ms.CLOCK) == 0
    finally:
        leader.destroy_node()
        tester.destroy_node()


def test_wallclock_leader_waits_for_robots_and_bridges_by_default(context):
    from virtual_leader.node import LeaderNode

    leader = LeaderNode(context=context, parameter_overrides=[
        Parameter("scenario", value="paper-triangle3"), Parameter("mode", value="wallclock"),
        Parameter("links", value="direct")])
    try:
        assert leader.expected == ["robot_1", "robot_2", "robot_3", "bridge_1", "bridge_2",
                                   "bridge_3"]
    finally:
        leader.destroy_node()


def test_fuzz_leader_handlers(context):
    from virtual_leader.node import LeaderNode

    params = [Parameter("scenario", value=SCENARIO), Parameter("trials", value=4)]
    leader = LeaderNode(context=context, parameter_overrides=params)
    leader._gate.cancel()  # the schedule itself is not under test here
    seen = Outcomes()
    try:
        @FUZZ
        @example(msg=Clock(clock=_time(CLOCK.stamp_ns(1, 4))))
        @example(msg=Clock(clock=_time(CLOCK.stamp_ns(1, 5))))
        @example(msg=ms.json_to_msg({"node": "robot_2", "trial": 2}))
        @example(msg=ms.json_to_msg({"node": "robot_2", "trial": 3}))
        @given(msg=st.one_of(readies, clocks()))
        def prop(msg):
            leader.k, leader.t, leader.ended = 1, 3, 0
            leader.ready = {n: 1 for n in leader.expected}
            before = (dict(leader.ready), leader.t, leader.ended, dropped(leader))
            if isinstance(msg, Clock):
                leader._on_clock(msg)
                label = in_grid(msg.clock)
                if label is None or label != (1, 4):  # lockstep: sample 4 of trial 1 only
                    assert (leader.t, leader.ended) == before[1:3]
                taken = leader.t != before[1]
            else:
                leader._on_ready(msg)
                changed = {n: v for n, v in leader.ready.items() if before[0][n] != v}
                for n, v in changed.items():  # ready for trial 2 at most, or the whole run
                    assert v == 2 or (n in ("monitor", "recorder") and v == 4)
                taken = bool(changed) or (
                    dropped(leader) == before[3] and leader.ready == before[0])
            assert taken != (dropped(leader) == before[3] + 1)
            seen(taken)
        prop()
        seen.check()
    finally:
        leader.destroy_node()


# ----------------------------------------------------------------------------------------
# The leader refuses what no run can have, with one line and status 2 (not restarted),
# before it publishes anything: ``trials:=-5`` said "done" at once and never exited; a
# damaged or impossible ``leader.json`` (a launcher would restart a traceback).

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
    assert lines == [f"formation-ilc-virtual-leader: {why}"]


def test_an_impossible_state_file_is_one_line_naming_it(ros_env, tmp_path):
    (tmp_path / "leader.json").write_text(json.dumps(
        {"committed": 999, "slot": 999, "seq": 999, "open": False}))
    res = leader("trials:=10", f"state_dir:={tmp_path}", env=ros_env)
    assert res.returncode == 2, res.stdout + res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(
        f"formation-ilc-virtual-leader: {tmp_path}/leader.json: impossible schedule state: "
        f"committed 999 is not in 0..10"), res.stderr
    assert "Traceback" not in res.stderr
