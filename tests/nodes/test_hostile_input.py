"""Hostile and broken input to every node: regression tests over topics for the faults users
reported, and property tests (hypothesis) that feed generated messages to each message
handler directly.

Properties, for every handler and every generated message: no exception escapes; a
message is either taken (the node's state moves, within its window) or counted once in the
node's drop counters; a message outside the node's trial window moves nothing (current
trial, sample). Each property test builds its node once and resets the state it checks
before every example, so an example does not depend on the ones before it.
"""

from __future__ import annotations

import json
import math
import struct
import time

import numpy as np
import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from hypothesis import example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from nav_msgs.msg import Odometry, Path  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import String  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.runconfig import make_config  # noqa: E402
from formation_ilc.model.simulate import Problem  # noqa: E402
from formation_ilc.protocol.learner import RobotLearner  # noqa: E402

from ..procs import spin_until, wait_emulator_ready  # noqa: E402

SCENARIO = "paper-triangle3"
#: examples per property: enough to hit every branch of a handler, small enough that all
#: the property tests of this file take well under 30 s
EXAMPLES = 120
FUZZ = settings(max_examples=EXAMPLES, deadline=None, database=None)

CFG = make_config(SCENARIO, seed=3, noise=False, delay=False, links="direct")
CLOCK = CFG.clock
T = CFG.scenario.samples
PB = Problem.from_scenario(CFG.scenario)


def dropped(node) -> int:
    return sum(node.drops.counts.values())


class Outcomes:
    """How often a property saw each outcome: a fuzz that only ever hit one branch of a
    handler would prove little, so each test asserts it saw both."""

    def __init__(self) -> None:
        self.n: dict[str, int] = {"taken": 0, "dropped": 0}

    def __call__(self, taken: bool) -> None:
        self.n["taken" if taken else "dropped"] += 1

    def check(self) -> None:
        assert self.n["taken"] > 0 and self.n["dropped"] > 0, self.n


# --------------------------------------------------------------------------- strategies

def _time(ns: int) -> Time:
    sec, nsec = divmod(ns, 1_000_000_000)
    return Time(sec=sec, nanosec=nsec)


#: labels at and next to the windows of the base states the tests reset nodes to (trial 0
#: at sample 1; trial 0 finished), anywhere near the grid, or off it by a little
grid_ns = st.builds(
    lambda ks, off: CLOCK.stamp_ns(*ks) + off,
    st.one_of(st.sampled_from([(0, 2), (1, 0), (0, 1), (0, 3), (1, 1), (0, T), (1, 4)]),
              st.tuples(st.integers(-1, 7), st.integers(-2, T + 22))),
    st.sampled_from([0, 0, 0, 0, 0, 0, 1, -1, CLOCK.dt_ns // 2]))
#: valid-looking labels mostly, and raw stamps anywhere in the message's range (negative
#: seconds, nanoseconds >= 1e9)
stamps = st.one_of(
    grid_ns.filter(lambda ns: -2**31 * 10**9 <= ns < 2**31 * 10**9).map(_time),
    grid_ns.filter(lambda ns: -2**31 * 10**9 <= ns < 2**31 * 10**9).map(_time),
    st.builds(lambda sec, nsec: Time(sec=sec, nanosec=nsec),
              st.integers(-2**31, 2**31 - 1), st.integers(0, 2**32 - 1)))
finite = st.floats(-1e3, 1e3, allow_nan=False)
special = st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -0.0])
frames = st.sampled_from(["map", "odom", "", "robot_2", "base_link"])


@st.composite
def poses(draw) -> PoseStamped:
    """A valid pose at a label of ``stamps``, then broken in one way or none."""
    m = ms.pose_to_msg((draw(finite), draw(finite), draw(finite)), 0, ms.WORLD_FRAME)
    m.header.stamp = draw(stamps)
    how = draw(st.sampled_from(["none"] * 5 + ["frame", "x", "y", "quat", "tilt"]))
    if how == "frame":
        m.header.frame_id = draw(frames)
    elif how in ("x", "y"):
        setattr(m.pose.position, how, draw(special))
    elif how == "quat":
        q = m.pose.orientation
        q.x, q.y, q.z, q.w = (draw(st.one_of(finite, special)) for _ in range(4))
    elif how == "tilt":
        m.pose.orientation.x = 0.1
    return m


@st.composite
def paths(draw, robot: int = 0) -> Path:
    """Mostly a real-looking trajectory of some trial, then broken in one way or none."""
    k = draw(st.integers(-1, 3))
    eta = PB.eta_d[robot].copy()
    stamps_ns = [CLOCK.stamp_ns(max(k, 0), s) for s in range(T + 1)]
    msg = ms.trajectory_to_path(eta, stamps_ns, ms.WORLD_FRAME)
    how = draw(st.sampled_from(["none"] * 4 + ["short", "long", "stamp", "nan", "frame",
                                              "negative", "empty", "path_frame"]))
    if how == "short":
        msg.poses = msg.poses[:-1]
    elif how == "long":
        msg.poses = [*msg.poses, msg.poses[-1]]
    elif how == "stamp":
        msg.poses[draw(st.integers(0, T))].header.stamp = draw(stamps)
    elif how == "nan":
        msg.poses[draw(st.integers(0, T))].pose.position.x = math.nan
    elif how == "frame":
        msg.poses[draw(st.integers(0, T))].header.frame_id = "odom"
    elif how == "negative":
        msg.poses[0].header.stamp = Time(sec=-1, nanosec=0)
    elif how == "empty":
        msg.poses = []
    elif how == "path_frame":
        msg.header.frame_id = draw(frames)
        for ps in msg.poses:
            ps.header.frame_id = msg.header.frame_id
    return msg


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10, 10**20), st.floats(),
              st.text(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=3),
                            st.dictionaries(st.text(max_size=6), inner, max_size=3)),
    max_leaves=8)
small = st.integers(-1, 4)
trial_values = st.one_of(small, small, small, st.integers(), st.floats(), st.booleans(),
                         st.none(), st.text(max_size=3))


def jsons(fields: st.SearchStrategy) -> st.SearchStrategy:
    """Strings: junk text, any JSON, or objects with the protocol's fields varied."""
    structured = fields.map(lambda d: json.dumps(d, allow_nan=True))
    return st.one_of(
        structured, structured, structured, structured,
        st.text(max_size=40),
        json_values.map(json.dumps),
        st.just("[" * 5000),
    ).map(lambda s: String(data=s))


events = jsons(st.fixed_dictionaries(
    {"event": st.sampled_from(["start", "start", "end", "done", "abort", "halt", 1]),
     "trial": trial_values, "seq": st.one_of(st.integers(-1, 3), st.just("1"))},
    optional={"start_wall_ns": st.one_of(st.integers(-1, 2**63),
                                         st.just(time.time_ns() + 10**9)),
              "stamp_ns": st.integers()}))
readies = jsons(st.fixed_dictionaries(
    {"node": st.sampled_from(["robot_1", "robot_2", "robot_3", "robot_sim", "monitor",
                              "recorder", "link_emulator", "intruder", 7]),
     "trial": trial_values}))
hist = st.one_of(
    st.dictionaries(st.sampled_from(["robot_1", "leader"]),
                    st.dictionaries(st.sampled_from(["0", "1", "-1", "x", "²"]),
                                    st.one_of(st.integers(-1, 9), st.text(max_size=2)),
                                    max_size=2), max_size=2),
    json_values)
_reports = st.fixed_dictionaries(
    {"node": st.sampled_from(["robot_1", "robot_2", "robot_sim", "recorder", 5]),
     "trial": trial_values},
    optional={"delays": hist, "injected": hist, "dropped": json_values,
              "timing": st.dictionaries(st.text(max_size=4), json_values, max_size=2),
              "missed": json_values})
#: DiagnosticArrays: a report as the nodes send it (its fields varied), or statuses whose
#: key/value pairs are junk (not JSON, keys that nest under values, no node)
diags = st.one_of(
    _reports.map(lambda d: ms.diagnostics_to_msg(d, 0)),
    _reports.map(lambda d: ms.diagnostics_to_msg(d, 0)),
    st.lists(st.tuples(st.sampled_from(["node", "trial", "trial.x", "delays", "x"]),
                       st.text(max_size=12)), max_size=4).map(
        lambda kv: DiagnosticArray(status=[DiagnosticStatus(
            name="x", values=[KeyValue(key=k, value=v) for k, v in kv])])))
twists = st.builds(
    lambda v, w, other: ms.u_to_twist((v, w)) if not other else
    Twist(linear=ms.u_to_twist((v, w)).linear,
          angular=type(Twist().angular)(x=other, z=w)),
    st.one_of(finite, finite, special), st.one_of(finite, finite, special),
    st.sampled_from([0.0, 0.0, 0.0, 1.0, math.nan]))


def _pose(k: int, s: int, robot: int = 0) -> PoseStamped:
    return ms.pose_to_msg(PB.eta_d[robot, s], CLOCK.stamp_ns(k, s), ms.WORLD_FRAME)


def _path(k: int, robot: int = 0) -> Path:
    return ms.trajectory_to_path(PB.eta_d[robot], [CLOCK.stamp_ns(k, s) for s in range(T + 1)],
                                 ms.WORLD_FRAME)


def clocks() -> st.SearchStrategy:
    return stamps.map(lambda t: Clock(clock=t))


def in_grid(t: Time) -> tuple[int, int] | None:
    """(trial, sample) of a stamp if it is a valid label, else None."""
    try:
        return CLOCK.decode(ms.stamp_to_ns(t))
    except ms.MalformedMessage:
        return None


# --------------------------------------------------------------------------- helpers

@pytest.fixture
def executor(context):
    ex = SingleThreadedExecutor(context=context)
    nodes: list = []
    yield ex, nodes
    ex.shutdown()
    for n in nodes:
        n.destroy_node()


def robot_node(context, links: str = "direct"):
    from formation_ilc.nodes.robot import RobotNode

    params = [Parameter("robot_id", value=2), Parameter("scenario", value=SCENARIO),
              Parameter("links", value=links), Parameter("delay", value=False),
              Parameter("noise", value=False), Parameter("seed", value=3)]
    return RobotNode(context=context, parameter_overrides=params)


def base_learner(node, direct: bool, finished: bool) -> RobotLearner:
    """Robot 2 in trial 0 at sample 1 (``finished``: trial 0 done and learned, so trial 1
    is open)."""
    lrn = RobotLearner(node.pb, 1, CLOCK, direct=direct)
    steps = T + 1 if finished else 2
    for s in range(steps):
        ns = CLOCK.stamp_ns(0, s)
        ev = lrn.on_pose(ns, PB.eta_d[1, s])
        if ev.last:
            lrn.finish_trial()
            break
        if direct:
            lrn.on_link_pose("robot_1", ns, PB.eta_d[0, s])
        else:
            lrn.on_link_tick("robot_1", ns, None)
        if s < steps - 1:
            lrn.command()
    if finished:
        stamps_ns = np.array(lrn.trajectory_stamps(0))
        assert lrn.on_trajectory("robot_1", stamps_ns, PB.eta_d[0])
    return lrn


def window(lrn: RobotLearner) -> set[int]:
    """The trials robot 2 may take input of: the current one, the next once learned."""
    return {lrn.k, lrn.k + 1} if lrn.learned >= lrn.k else {lrn.k}


# --------------------------------------------------------------------------- regressions

def test_a_forged_later_trial_pose_does_not_hijack_the_link_emulator(context, executor):
    """Reported: one well-formed PoseStamped on robot_2/shared_pose labelled with a later
    trial made the link emulator jump to that trial and drop all real traffic as stale.
    Now it is dropped as ``future`` and the real traffic keeps flowing."""
    from robot_sim.link_emulator import LinkEmulator

    cfg = make_config(SCENARIO, seed=9)
    ex, nodes = executor
    emu = LinkEmulator(context=context)
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    nodes += [emu, tester]
    ex.add_node(emu)
    ex.add_node(tester)
    got: list[int] = []
    sub = tester.create_subscription(
        Path, ms.link_topic(2, "robot_1"),
        lambda m: got.append(ms.msg_to_link_tick(m)[0]), ms.SAMPLE_QOS)
    cfg_pub = tester.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS)
    cfg_pub.publish(ms.json_to_msg(cfg.to_json()))
    spin_until(ex, lambda: emu.configured)
    shared = [tester.create_publisher(PoseStamped, ms.shared_pose_topic(j + 1), ms.SAMPLE_QOS)
              for j in range(3)]
    ref = tester.create_publisher(PoseStamped, ms.REFERENCE, ms.SAMPLE_QOS)
    events = tester.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
    spin_until(ex, lambda: all(p.get_subscription_count() >= 1 for p in [*shared, ref, events])
               and sub.get_publisher_count() >= 1)
    wait_emulator_ready(ex, tester, emu)
    pb = Problem.from_scenario(cfg.scenario)
    events.publish(ms.json_to_msg({"event": "start", "trial": 0, "slot": 0, "seq": 0}))
    spin_until(ex, lambda: emu.links.active)

    def sample(t: int) -> None:
        ns = cfg.clock.stamp_ns(0, t)
        for j in range(3):
            shared[j].publish(ms.pose_to_msg(pb.eta_d[j, t], ns, ms.WORLD_FRAME))
        ref.publish(ms.pose_to_msg(cfg.scenario.reference[t], ns, ms.WORLD_FRAME))

    sample(0)
    spin_until(ex, lambda: len(got) == 1)
    # the forgery: a well-formed pose of trial 7, and one of the next trial mid-trial
    for k in (7, 1):
        shared[1].publish(ms.pose_to_msg(pb.eta_d[1, 0], cfg.clock.stamp_ns(k, 0),
                                         ms.WORLD_FRAME))
    spin_until(ex, lambda: emu.drops.counts["future"] == 2)
    assert emu.links.k == 0
    for t in range(1, 5):
        sample(t)
    spin_until(ex, lambda: len(got) == 5)
    assert got == [cfg.clock.stamp_ns(0, t) for t in range(5)]
    assert emu.drops.by_topic["future:robot_2/shared_pose"] == 2
    assert sum(emu.drops.counts.values()) == 2


def test_stray_trajectories_do_not_evict_a_real_one(context, executor):
    """Met in CI: two malformed trajectories from a second writer of robot_1/trajectory,
    taken by the launcher's monitor in the same instant as robot_1's real one, evicted it
    from a reader history as deep as the writers' (2): that trial's metrics never came
    and the launch waited for them. Readers of trajectories keep more than that."""
    from formation_ilc.nodes.monitor import MonitorNode

    ex, nodes = executor
    mon = MonitorNode(CFG, lambda k, row: None, true_state=False, context=context)
    real = rclpy.create_node("robot_1", namespace=ms.NAMESPACE, context=context)
    stray = rclpy.create_node("stray", namespace=ms.NAMESPACE, context=context)
    nodes += [mon, real, stray]
    ex.add_node(mon)  # only the monitor takes messages
    pubs = [n.create_publisher(Path, ms.trajectory_topic(1), ms.TRAJECTORY_QOS)
            for n in (real, stray)]
    spin_until(ex, lambda: mon.path_subs[0].get_publisher_count() >= 2
               and all(p.get_subscription_count() >= 1 for p in pubs))
    mon.slots.started, mon.slots.iteration_of = 1, {0: 0, 1: 1}
    short = _path(1)
    short.poses = short.poses[:3]
    pubs[0].publish(_path(1))
    pubs[1].publish(short)
    pubs[1].publish(short)
    time.sleep(0.5)  # all three wait in the reader's history before the monitor takes any
    spin_until(ex, lambda: dropped(mon) == 2 and mon.slots.eta.get(1))
    assert list(mon.slots.eta[1]) == [0]
    assert mon.drops.by_topic == {"malformed:robot_1/trajectory": 2}


def test_a_negative_stamp_is_recorded_and_counted_not_fatal(context, executor, tmp_path):
    """Reported: one PoseStamped with sec = -1 (or 3e9, which arrives negative) killed the
    recorder inside the MCAP writer. Now it is recorded with the receive time as its
    publish time and counted."""
    from rclpy.serialization import serialize_message

    from formation_ilc.nodes.recorder import RecorderNode
    from formation_ilc.recordings.mcap_io import ReadReport, read_messages

    ex, nodes = executor
    out = tmp_path / "run.mcap"
    rec = RecorderNode(out, context=context)
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    nodes += [tester]
    ex.add_node(rec)
    ex.add_node(tester)
    cfg_pub = tester.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS)
    cfg_pub.publish(ms.json_to_msg(CFG.to_json()))
    spin_until(ex, lambda: rec.cfg is not None)
    pose = tester.create_publisher(PoseStamped, ms.pose_topic(1), ms.SAMPLE_QOS)
    spin_until(ex, lambda: pose.get_subscription_count() >= 1)
    good = ms.pose_to_msg((1.0, 2.0, 0.5), CLOCK.stamp_ns(0, 3), ms.WORLD_FRAME)
    neg = ms.pose_to_msg((1.0, 2.0, 0.5), 0, ms.WORLD_FRAME)
    neg.header.stamp.sec = -1
    # sec = 3e9 does not fit an int32: on the wire it is the same 4 bytes as -1294967296
    raw = bytearray(serialize_message(good))
    struct.pack_into("<I", raw, 4, 3_000_000_000)
    t0 = time.time_ns()
    for m in (good, neg, bytes(raw), good):
        pose.publish(m)
    # the config, the four poses, and the observer's desired pose and error of the two
    # valid ones (the invalid stamps are no sample: nothing observed)
    spin_until(ex, lambda: rec.writer.count >= 9)
    assert rec.invalid_stamps[ms.pose_topic(1)] == 2
    rec.destroy_node()
    report = ReadReport()
    msgs = [m for m in read_messages(out, report=report) if m.topic.endswith("robot_1/pose")]
    assert len(msgs) == 4 and not report.damaged and not report.cut_short
    assert msgs[0].publish_time == CLOCK.stamp_ns(0, 3)
    for m in msgs[1:3]:  # invalid stamps: logged with the receive time
        assert m.publish_time == m.log_time >= t0
    assert bytes(msgs[2].data) == bytes(raw)  # recorded as received
    errors = [m for m in read_messages(out) if m.topic.endswith("robot_1/tracking_error")]
    assert [m.publish_time for m in errors] == [CLOCK.stamp_ns(0, 3)] * 2


# --------------------------------------------------------------------------- properties

def test_fuzz_robot_pose_and_direct_link_handlers(context):
    node = robot_node(context, "direct")
    seen = Outcomes()
    try:
        @FUZZ
        @example(msg=_pose(0, 2, 1), finished=False, which="own")  # the next sample
        @example(msg=_pose(1, 0, 1), finished=True, which="own")   # the next trial, open
        @example(msg=_pose(1, 0, 1), finished=False, which="own")  # not open yet
        @example(msg=_pose(0, 2), finished=False, which="robot_1")
        @given(msg=poses(), finished=st.booleans(), which=st.sampled_from(
            ["own", "robot_1", "robot_3", "leader"]))
        def prop(msg, finished, which):
            lrn = node.learner = base_learner(node, True, finished)
            before = (lrn.k, lrn.t, lrn.learned, dropped(node))
            allowed = window(lrn)
            newest = lrn.inbox["robot_1"].newest_ns
            if which == "own":
                node._on_pose(msg)
                moved = (lrn.k, lrn.t) != before[:2]
            else:
                node._on_link_pose(msg, which)
                moved = lrn.inbox["robot_1"].newest_ns != newest
                assert (lrn.k, lrn.t) == before[:2]  # a link never moves the robot's sample
            assert moved != (dropped(node) == before[3] + 1)
            label = in_grid(msg.header.stamp)
            if moved:
                assert label is not None and label[0] in allowed
                assert which in ("own", "robot_1")  # robot 3 and the leader are no in-links
            if label is None or label[0] not in allowed:
                assert not moved
            seen(moved)
        prop()
        seen.check()
    finally:
        node.destroy_node()


def test_fuzz_robot_link_tick_and_trajectory_handlers(context):
    node = robot_node(context, "emulated")
    ticks, trajs = Outcomes(), Outcomes()
    try:
        @FUZZ
        @example(tick=_time(CLOCK.stamp_ns(0, 2)), pose=_pose(0, 1), extra=False,
                 finished=False)
        @example(tick=_time(CLOCK.stamp_ns(7, 2)), pose=None, extra=False, finished=True)
        @given(tick=stamps, pose=st.one_of(st.none(), poses()), extra=st.booleans(),
               finished=st.booleans())
        def prop_tick(tick, pose, extra, finished):
            lrn = node.learner = base_learner(node, False, finished)
            before = (lrn.k, lrn.t, dropped(node), set(lrn.inbox["robot_1"].ticks))
            msg = Path()
            msg.header.stamp = tick
            msg.poses = [] if pose is None else [pose] * (2 if extra else 1)
            node._on_link_tick(msg, "robot_1")
            moved = set(lrn.inbox["robot_1"].ticks) != before[3]
            assert moved != (dropped(node) == before[2] + 1)
            assert (lrn.k, lrn.t) == before[:2]
            label = in_grid(tick)
            if label is None or label[0] not in window(lrn):
                assert not moved
            ticks(moved)

        @FUZZ
        @example(msg=_path(0), finished=False, sender="robot_1")
        @example(msg=_path(1), finished=True, sender="robot_1")
        @example(msg=_path(2), finished=True, sender="robot_1")
        @given(msg=paths(robot=0), finished=st.booleans(),
               sender=st.sampled_from(["robot_1", "robot_1", "robot_3"]))
        def prop_traj(msg, finished, sender):
            lrn = node.learner = base_learner(node, False, finished)
            before = (lrn.k, lrn.t, lrn.learned, dropped(node), len(lrn.trajs))
            allowed = window(lrn)
            node._on_trajectory(msg, sender)
            moved = (lrn.learned, len(lrn.trajs)) != (before[2], before[4])
            assert moved != (dropped(node) == before[3] + 1)
            assert (lrn.k, lrn.t) == before[:2]
            if moved:
                k = CLOCK.decode(ms.stamp_to_ns(msg.poses[0].header.stamp))[0]
                assert k in allowed and sender == "robot_1"
            trajs(moved)

        prop_tick()
        prop_traj()
        ticks.check()
        trajs.check()
    finally:
        node.destroy_node()


def test_fuzz_link_emulator_handlers(context):
    from robot_sim.link_emulator import LinkEmulator

    cfg = make_config(SCENARIO, seed=3, mode="realtime")
    emu = LinkEmulator(context=context)
    emu.follow_config(cfg)
    seen = Outcomes()
    try:
        @FUZZ
        @example(msg=_pose(0, 2), to="shared", done=False)
        @example(msg=_pose(1, 0), to="reference", done=True)
        @example(msg=_pose(1, 0), to="reference", done=False)
        @example(msg=Clock(clock=_time(CLOCK.stamp_ns(0, 3))), to="shared", done=False)
        @given(msg=st.one_of(poses(), clocks(), st.builds(String, data=st.text(max_size=20))),
               to=st.sampled_from(["shared", "reference"]), done=st.booleans())
        def prop(msg, to, done):
            lk = emu.links
            lk.follower.slot = lk.follower.trial = 0  # slot 0 (iteration 0) started
            lk.begin()
            lk.reported = done  # the trial delivered: the next slot may come (held)
            lk.early = []
            lk.clock_t = 2
            lk.next_t = 2
            before = (lk.k, dropped(emu))
            if isinstance(msg, Clock):
                emu._on_clock(msg)
                label = in_grid(msg.clock)
                taken = lk.clock_t != 2 or lk.k != 0 or bool(lk.early)
            elif isinstance(msg, String):
                emu._on_config(msg)  # a second configuration: counted, nothing moves
                label, taken = None, False
            else:
                snap = [list(x) for x in lk.shared] + [list(lk.ref)]
                (emu._on_reference(msg) if to == "reference" else emu._on_shared(msg, 1))
                label = in_grid(msg.header.stamp)
                taken = (lk.k != 0 or bool(lk.early)
                         or [list(x) for x in lk.shared] + [list(lk.ref)] != snap)
            assert taken != (dropped(emu) == before[1] + 1)
            allowed = {0, 1} if done else {0}
            if label is None or label[0] not in allowed:
                assert lk.k == 0 and not taken
            seen(taken)
        prop()
        seen.check()
    finally:
        emu.destroy_node()


def test_fuzz_simulator_handlers(context):
    from robot_sim.node import SimNode

    sim = SimNode(context=context)
    sim.follow_config(CFG)
    seen = Outcomes()
    try:
        @FUZZ
        @example(msg=ms.u_to_twist((0.2, 0.1)), r=1, state="in_trial")
        @example(msg=ms.u_to_twist((0.2, 0.1)), r=1, state="between")
        @example(msg=ms.json_to_msg({"event": "start", "trial": 1, "seq": 1}), r=0,
                 state="between")
        @example(msg=ms.json_to_msg({"event": "start", "trial": 1, "seq": 1}), r=0,
                 state="not_ready")
        @example(msg=ms.json_to_msg({"event": "start", "trial": 2, "seq": 1}), r=0,
                 state="between")
        @given(msg=st.one_of(events, twists), r=st.integers(0, 2),
               state=st.sampled_from(["between", "in_trial", "not_ready"]))
        def prop(msg, r, state):
            plant, f = sim.plant, sim.plant.follower
            f.slot, f.trial, f.seen = 0, 0, 0
            # "in_trial": ready for the next trial, but inside this one
            plant.in_trial, f.ready = state == "in_trial", state != "not_ready"
            plant.pending = {0, 1, 2} if plant.in_trial else set()
            plant.t = 5
            before = dropped(sim)
            if isinstance(msg, Twist):
                sim._on_cmd(msg, r)
                assert plant.k == 0
                assert dropped(sim) in (before, before + 1)
                if dropped(sim) == before:  # taken: inside a trial, a finite planar command
                    assert state == "in_trial" and r not in plant.pending
                    assert plant.u[r, 5].tolist() == [msg.linear.x, msg.angular.z]
                seen(dropped(sim) == before)
                return
            sim._on_event(msg)
            if plant.k != 0:  # only the start of the next slot, between trials, once ready
                ev = json.loads(msg.data)
                assert (ev["event"], ev["trial"], state) == ("start", 1, "between")
                assert ev["seq"] > 0
                assert dropped(sim) == before
            elif dropped(sim) == before:
                # not counted: end, done, an abort (answered), or the leader's repeat of the
                # start taken (slot 0, seq 0)
                ev = json.loads(msg.data)
                assert ev["event"] in ("end", "done", "abort") or (
                    ev["event"] == "start" and ev.get("slot", ev["trial"]) == 0
                    and ev["seq"] == 0)
            else:
                assert dropped(sim) == before + 1
            seen(plant.k != 0)
        prop()
        seen.check()
    finally:
        sim.destroy_node()


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


def test_fuzz_monitor_handlers(context):
    from formation_ilc.nodes.monitor import MonitorNode

    rows: list[int] = []
    mon = MonitorNode(CFG, lambda k, row: rows.append(k), context=context)
    seen = Outcomes()
    try:
        @FUZZ
        @example(msg=_path(1), true=False)
        @example(msg=_path(2), true=True)
        @example(msg=ms.diagnostics_to_msg({"node": "robot_2", "trial": 1, "delays": {}}, 0),
                 true=False)
        @example(msg=ms.diagnostics_to_msg({"node": "robot_2", "trial": 2}, 0), true=False)
        @example(msg=ms.json_to_msg({"event": "end", "trial": 1}), true=False)
        @given(msg=st.one_of(paths(robot=0), diags, events), true=st.booleans())
        def prop(msg, true):
            sl = mon.slots
            sl.started, sl.start_seq, sl.eta, sl.xi = 1, -1, {}, {}
            sl.rows.clear()
            sl.rows[0] = np.zeros(1)
            sl.iteration_of, sl.aborted = {0: 0, 1: 1}, set()
            mon.diagnostics = {"robot_1": {"node": "robot_1", "trial": 0}}
            before = dropped(mon)
            if isinstance(msg, Path):
                mon._on_traj(msg, 0, true)
                taken = bool(sl.eta or sl.xi)
                if taken:  # a trajectory of the trial in progress
                    assert list(sl.xi if true else sl.eta) == [1]
            else:
                diag = mon.diagnostics["robot_1"]
                n_events = len(mon.events)
                (mon._on_diag if isinstance(msg, DiagnosticArray) else mon._on_event)(msg)
                taken = (len(mon.events) != n_events or mon.diagnostics["robot_1"] is not diag
                         or len(mon.diagnostics) > 1)
                assert sl.started in (1, 2)
                for d in mon.diagnostics.values():  # what the launcher reads is sound
                    assert isinstance(d["trial"], int) and d["trial"] <= sl.started
            assert taken != (dropped(mon) == before + 1)
            seen(taken)
        prop()
        seen.check()
        assert rows == []  # no trial completed from one robot's trajectory
    finally:
        mon.destroy_node()


def test_monitor_takes_the_leaders_repeated_start_as_no_event(context):
    """The leader repeats a start while its slot does not move: the monitor neither counts
    it as dropped nor lists it among the run's events (the launcher's backstop takes a new
    event for progress), and a replay of an older start is still refused."""
    from formation_ilc.nodes.monitor import MonitorNode

    mon = MonitorNode(CFG, lambda k, row: None, context=context)
    try:
        start = ms.json_to_msg({"event": "start", "trial": 0, "slot": 0, "seq": 0})
        mon._on_event(start)
        mon._on_event(start)
        mon._on_event(start)
        assert [e["event"] for e in mon.events] == ["start"] and dropped(mon) == 0
        mon._on_event(ms.json_to_msg({"event": "abort", "trial": 0, "slot": 0, "seq": 1}))
        mon._on_event(ms.json_to_msg({"event": "start", "trial": 0, "slot": 1, "seq": 2}))
        mon._on_event(start)  # the first slot's start, replayed: refused
        assert len(mon.events) == 3 and dropped(mon) == 1
    finally:
        mon.destroy_node()


def test_fuzz_bridge_handlers(context):
    from formation_ilc.nodes.pioneer_bridge import BridgeNode

    params = [Parameter("robot_id", value=1), Parameter("scenario", value=SCENARIO),
              Parameter("driver_ns", value="/pioneer_1")]
    bridge = BridgeNode(context=context, parameter_overrides=params)
    seen = Outcomes()
    try:
        @FUZZ
        @example(msg=ms.json_to_msg({"event": "start", "trial": 1,
                                     "start_wall_ns": time.time_ns() + 10**9}),
                 phase="idle", ready=True)
        @example(msg=ms.json_to_msg({"event": "start", "trial": 1,
                                     "start_wall_ns": time.time_ns() + 10**11}),
                 phase="idle", ready=True)
        @example(msg=ms.u_to_twist((0.2, 0.1)), phase="return", ready=True)
        @given(msg=st.one_of(events, twists, st.builds(Odometry)), phase=st.sampled_from(
            ["idle", "trial", "return"]), ready=st.booleans())
        def prop(msg, phase, ready):
            core = bridge.core
            core.follower.slot, core.phase, core.schedule = 0, phase, None
            # ready: said ready for trial 1 (since trial 0 started), else only for trial 0
            core.ready_sent, core.follower.ready = (1 if ready else 0), ready
            core.robot_cmd = (0.0, 0.0)
            before = dropped(bridge)
            if isinstance(msg, Twist):
                bridge._on_cmd(msg)
                taken = dropped(bridge) == before
                if taken:
                    assert phase == "trial"
            elif isinstance(msg, Odometry):
                bridge._on_odom(msg)  # a default Odometry is a valid pose at 0
                taken = True
            else:
                bridge._on_event(msg)
                taken = core.k != 0
                if taken:
                    ev = json.loads(msg.data)
                    assert (ev["event"], ev["trial"], phase, ready) == ("start", 1, "idle",
                                                                        True)
                    assert abs(ev["start_wall_ns"] - time.time_ns()) < 61e9
                else:
                    taken = dropped(bridge) == before  # an end or done event: not for us
            assert taken != (dropped(bridge) == before + 1)
            seen(dropped(bridge) == before)
        prop()
        seen.check()
    finally:
        bridge.destroy_node()
