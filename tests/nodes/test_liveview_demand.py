"""The live view takes a per-sample topic off the run only while something shows it: a
viewer subscribed to its channel, to a view topic computed from it, or a DDS reader of such
a view topic; the latched and per-trial topics it always takes (in-process, on the
EventsExecutor the node runs on, a fake server standing in for foxglove's, whose listener the
test drives as a viewer would)."""

from __future__ import annotations

import contextlib
import os
import time
from types import SimpleNamespace

import numpy as np
import pytest

import msgs_schema as ms
from formation_ilc.config.runconfig import RunConfig
from formation_ilc.config.scenario import load_scenario

if os.environ.get("FORMATION_ILC_REQUIRE_LIVE") != "1":
    pytest.importorskip("foxglove")  # the 'live' extra; CI requires it

pytestmark = pytest.mark.ros


class FakeServer:
    port = 0

    def __init__(self, listener):
        self.listener = listener
        self.times: list[int] = []

    def broadcast_time(self, ns: int) -> None:  # the time capability
        self.times.append(ns)


def _per_sample(n: int) -> set[str]:
    return {t for t, _, q in ms.topic_table(n) + ms.view_topic_table(n)
            if q.durability != ms.LATCHED_QOS.durability and t != ms.TRIAL_EVENTS}


def _spin_until(ex, cond, timeout=10.0):
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.05)
    return cond()


@contextlib.contextmanager
def _configured(context, observe: bool, preview: bool = False):
    """A live view on the EventsExecutor it runs on, beside a node ``other`` that has sent
    it paper-triangle3's configuration; yields (live, other, executor, cfg, server)."""
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from std_msgs.msg import String

    from formation_ilc.nodes.liveview import LiveViewNode

    servers: list[FakeServer] = []

    def start(listener):
        servers.append(FakeServer(listener))
        return servers[-1]

    live = LiveViewNode(start, observe=observe, preview=preview, context=context)
    other = Node("other", namespace=ms.NAMESPACE, context=context)
    ex = EventsExecutor(context=context)
    ex.add_node(live)
    ex.add_node(other)
    try:
        cfg = RunConfig(load_scenario("paper-triangle3"))
        other.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS).publish(
            ms.json_to_msg(cfg.to_json()))
        assert _spin_until(ex, lambda: servers), "the server never started"
        yield live, other, ex, cfg, servers[0]
    finally:
        ex.shutdown()
        live.destroy_node()
        other.destroy_node()


@pytest.mark.parametrize("observe", [True, False])
def test_subscriptions_follow_what_viewers_show(context, observe):
    with _configured(context, observe) as (live, _, ex, cfg, server):
        n = cfg.scenario.n
        per_sample = _per_sample(n)
        taken = set(live.subs)
        # with no viewer: every latched or per-trial topic, no per-sample one
        assert ms.TRIAL_EVENTS in taken and ms.DIAGNOSTICS in taken
        assert ms.trajectory_topic(2) in taken
        assert not taken & per_sample
        assert {ms.pose_topic(i) for i in (1, 2, 3)} <= set(live.channels)
        listener = server.listener

        def view(topic, change):
            ch = SimpleNamespace(topic=live.resolve_topic_name(topic), id=0)
            (listener.on_subscribe if change > 0 else listener.on_unsubscribe)(
                SimpleNamespace(id=1), ch)

        def per_sample_taken():
            return set(live.subs) & per_sample

        view(ms.cmd_vel_topic(3), +1)
        assert _spin_until(ex, lambda: per_sample_taken() == {ms.cmd_vel_topic(3)})
        view(ms.tracking_error_topic(2), +1)  # computed here, or forwarded
        want = ms.pose_topic(2) if observe else ms.tracking_error_topic(2)
        assert _spin_until(ex, lambda: per_sample_taken() >= {want})
        if observe:
            assert per_sample_taken() == {ms.cmd_vel_topic(3), ms.pose_topic(2)}
            view(ms.MARKERS, +1)  # the whole team's poses
            assert _spin_until(ex, lambda: per_sample_taken() == {
                ms.cmd_vel_topic(3), *(ms.pose_topic(i) for i in (1, 2, 3))})
            view(ms.MARKERS, -1)
        else:
            assert ms.pose_topic(2) not in per_sample_taken()
        view(ms.cmd_vel_topic(3), -1)
        view(ms.tracking_error_topic(2), -1)
        assert _spin_until(ex, lambda: not per_sample_taken())
        assert ms.TRIAL_EVENTS in live.subs  # the per-trial ones stay


def test_a_dds_reader_of_a_computed_view_topic_gets_it(context):
    """rviz (or any DDS reader) subscribed to robot_1's tracking error: the live view takes
    robot_1's poses and publishes the errors, with no WebSocket viewer at all."""
    from geometry_msgs.msg import PoseStamped, Vector3Stamped
    from std_msgs.msg import String

    from formation_ilc.nodes.liveview import RECHECK
    from formation_ilc.protocol.schedule import TrialEvent

    with _configured(context, True) as (live, other, ex, cfg, _):
        assert _spin_until(ex, lambda: live.observer is not None)
        assert ms.pose_topic(1) not in live.subs
        got: list[Vector3Stamped] = []
        other.create_subscription(Vector3Stamped, ms.tracking_error_topic(1), got.append,
                                  ms.VIEW_QOS)
        assert _spin_until(ex, lambda: ms.pose_topic(1) in live.subs, timeout=5 * RECHECK + 5)
        assert ms.pose_topic(2) not in live.subs
        events = other.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
        poses = other.create_publisher(PoseStamped, ms.pose_topic(1), ms.SAMPLE_QOS)
        clock = cfg.clock
        eta = cfg.scenario.desired.eta[0, 5] + [0.3, 0.4, 0.0]
        start = TrialEvent(ms.START, 0, 0, 1, run=cfg.run_id)

        last = [0.0]

        def sent():  # again every 0.2 s until the error is in (the first may come before
            if time.monotonic() - last[0] > 0.2:  # the observer's publisher matched)
                last[0] = time.monotonic()
                events.publish(ms.json_to_msg(start.to_json()))
                poses.publish(ms.pose_to_msg(eta, clock.stamp_ns(0, 5), ms.WORLD_FRAME))
            return bool(got)

        assert _spin_until(ex, sent, timeout=10)
        assert got[0].vector.x == pytest.approx(0.5, abs=1e-9)  # |(0.3, 0.4)|


def test_a_per_sample_channel_forwards_at_most_its_rate(context):
    from formation_ilc.nodes.liveview import LiveViewNode

    live = LiveViewNode(lambda listener: FakeServer(listener), rate=20.0, context=context)
    every = LiveViewNode(lambda listener: FakeServer(listener), rate=0.0, context=context,
                         namespace="/other")
    try:
        taken = []
        end = time.monotonic() + 0.5
        while time.monotonic() < end:
            taken += [t for t in ("robot_1/pose", "robot_2/pose") if live._take(t)]
            time.sleep(0.001)
        # 0.5 s at 20 a second: at most 11 per channel, each channel on its own
        assert 1 <= taken.count("robot_1/pose") <= 11
        assert 1 <= taken.count("robot_2/pose") <= 11
        time.sleep(0.06)
        assert live._take("robot_1/pose") and not live._take("robot_1/pose")
        time.sleep(0.06)  # one period (0.05 s) later it forwards again
        assert live._take("robot_1/pose")
        assert all(every._take("robot_1/pose") for _ in range(100))
    finally:
        live.destroy_node()
        every.destroy_node()


class Logged:
    """Stands for a foxglove channel: what the bridge logged on it."""

    def __init__(self):
        self.got: list[bytes] = []

    def log(self, data, log_time=None):
        self.got.append(bytes(data))


@pytest.mark.parametrize("observe", [True, False])
def test_the_plants_preview_feeds_the_pose_channels_and_the_view(context, observe):
    """With the plant's preview (``--preview``), a viewer of any robot's pose or of a view
    topic makes the bridge take one topic, the preview, and no robot's pose: each robot's
    pose channel gets the bytes the plant sent on robot_i/pose, the markers come from each
    preview, and the trial errors from the robots' trajectories (always taken). With a
    recorder (``observe`` False) the bridge computes them too, for its viewers only."""
    from geometry_msgs.msg import Vector3Stamped
    from nav_msgs.msg import Path
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    from formation_ilc.protocol.schedule import TrialEvent

    with _configured(context, observe, preview=True) as (live, other, ex, cfg, server):
        sc = cfg.scenario
        n, per_sample = sc.n, _per_sample(sc.n)
        assert live.sampled and live.observer is not None and live.observer.sampled
        assert ms.PREVIEW not in live.subs and not set(live.subs) & per_sample
        assert ms.trajectory_topic(1) in live.subs
        logged = {t: Logged() for t in [*(ms.pose_topic(i) for i in range(1, n + 1)),
                                         ms.MARKERS, ms.tracking_error_topic(2),
                                         ms.trial_error_topic(1)]}
        live.channels.update(logged)
        ch = SimpleNamespace(topic=live.resolve_topic_name(ms.pose_topic(2)), id=0)
        server.listener.on_subscribe(SimpleNamespace(id=1), ch)
        assert _spin_until(ex, lambda: ms.PREVIEW in live.subs)
        assert not set(live.subs) & per_sample  # no robot's pose stream at all
        clock, eta_d = cfg.clock, sc.desired.eta
        events = other.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
        preview = other.create_publisher(Path, ms.PREVIEW, ms.PREVIEW_QOS)
        trajs = [other.create_publisher(Path, ms.trajectory_topic(i), ms.TRAJECTORY_QOS)
                 for i in range(1, n + 1)]
        stamp = clock.stamp_ns(0, 6)
        eta = eta_d[:, 6] + [0.0, 0.3, 0.0]
        team = ms.wire.pose_set_bytes(stamp, [ms.wire.raw_pose(e, stamp) for e in eta])

        def previewed():  # best effort, and the first may come before the reader matched
            preview.publish(team)
            time.sleep(0.06)  # past the channels' rate
            return all(logged[ms.pose_topic(i)].got for i in range(1, n + 1))

        assert _spin_until(ex, previewed, timeout=10)
        for i in range(1, n + 1):
            assert logged[ms.pose_topic(i)].got[0] == ms.wire.pose_bytes(eta[i - 1], stamp)
        err = deserialize_message(logged[ms.tracking_error_topic(2)].got[0], Vector3Stamped)
        assert err.vector.x == pytest.approx(0.3, abs=1e-12)
        assert logged[ms.MARKERS].got  # the whole team came in one message
        # trial 0's errors, once every robot's trajectory of slot 0 is in
        events.publish(ms.json_to_msg(TrialEvent(ms.START, 0, 0, 1, run=cfg.run_id).to_json()))
        stamps = [clock.stamp_ns(0, s) for s in range(sc.samples + 1)]
        off = np.zeros(3)
        off[0] = 0.5
        for i, pub in enumerate(trajs):
            pub.publish(ms.trajectory_to_path(eta_d[i] + (off if i == 0 else 0.0), stamps,
                                              ms.WORLD_FRAME))
        assert _spin_until(ex, lambda: logged[ms.trial_error_topic(1)].got)
        peak = deserialize_message(logged[ms.trial_error_topic(1)].got[0], Vector3Stamped)
        assert (peak.vector.x, peak.vector.z) == (pytest.approx(0.5, abs=1e-12), 0.0)
        server.listener.on_unsubscribe(SimpleNamespace(id=1), ch)
        assert _spin_until(ex, lambda: ms.PREVIEW not in live.subs)


def test_a_late_viewer_gets_the_current_trials_start_and_every_nodes_parameters(context):
    """What a viewer that joins mid-run is given at once: of the trial events only the
    current trial's start (kept as a latched channel's last message is), and the
    parameters of every node of the namespace (read through their parameter services)."""
    from std_msgs.msg import String

    with _configured(context, observe=False) as (live, other, ex, _cfg, _server):
        pub = other.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
        assert _spin_until(ex, lambda: pub.get_subscription_count() >= 1)
        for event, trial in ((ms.START, 0), (ms.END, 0), (ms.START, 1)):
            pub.publish(ms.json_to_msg({"event": event, "trial": trial}))
        kept = live.latched[ms.TRIAL_EVENTS]

        def last_trial():
            if not kept:
                return None
            return ms.msg_to_json(ms.deserialize(next(iter(kept.values())), String))["trial"]

        assert _spin_until(ex, lambda: last_trial() == 1)
        pub.publish(ms.json_to_msg({"event": ms.END, "trial": 1}))  # an end keeps the start
        _spin_until(ex, lambda: False, timeout=0.3)
        assert len(kept) == 1 and last_trial() == 1
        other.declare_parameter("answer", 42)
        name = f"{ms.NAMESPACE}/other.answer"
        assert _spin_until(ex, lambda: any(p.name == name for p in live.parameters([])),
                           timeout=15)
        (got,) = live.parameters([name])
        assert got.get_value() == 42
        # the run's own, under the leader, from the start
        assert live.parameters([f"{ms.NAMESPACE}/virtual_leader.seed"])
