"""What the hostile-input tests share (tests/nodes/test_hostile_input.py,
tests/robot_sim/, tests/virtual_leader/): a run configuration, hypothesis strategies of
broken and hostile messages, the outcome counter that makes a property show each branch,
and an executor fixture.

Properties, for every handler and every generated message: no exception escapes; a
message is either taken (the node's state moves, within its window) or counted once in the
node's drop counters; a message outside the node's trial window moves nothing (current
trial, sample). Each property test builds its node once and resets the state it checks
before every example, so an example does not depend on the ones before it.
"""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue  # noqa: E402
from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from hypothesis import settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import String  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.runconfig import make_config  # noqa: E402
from formation_ilc.model.simulate import Problem  # noqa: E402
from formation_ilc.protocol.learner import RobotLearner  # noqa: E402

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

def robot_node(context, links: str = "direct"):
    from formation_ilc.nodes.robot import RobotNode

    params = [Parameter("robot_id", value=2), Parameter("scenario", value=SCENARIO),
              Parameter("links", value=links), Parameter("delay", value=False),
              Parameter("noise", value=False), Parameter("seed", value=3)]
    return RobotNode(context=context, parameter_overrides=params)


def base_learner(node, direct: bool, finished: bool, learned: bool = True) -> RobotLearner:
    """Robot 2 in trial 0 at sample 1 (``finished``: trial 0 done and learned, so trial 1
    is open; without ``learned``: done, robot_1's trajectory of it still awaited)."""
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
    if finished and learned:
        stamps_ns = np.array(lrn.trajectory_stamps(0))
        assert lrn.on_trajectory("robot_1", stamps_ns, PB.eta_d[0])
    return lrn


def window(lrn: RobotLearner) -> set[int]:
    """The trials robot 2 may take input of: the current one, the next once learned."""
    return {lrn.k, lrn.k + 1} if lrn.learned >= lrn.k else {lrn.k}
