"""The link emulator (robot_sim.link_emulator) in-process: what it delivers is the batch
simulator's delay stream, and hostile input neither hijacks nor crashes it."""

from __future__ import annotations

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from geometry_msgs.msg import PoseStamped  # noqa: E402
from hypothesis import example, given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_msgs.msg import String  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.runconfig import make_config  # noqa: E402
from formation_ilc.model.simulate import Problem  # noqa: E402
from tests.hostile import (  # noqa: E402
    CLOCK,
    FUZZ,
    SCENARIO,
    Outcomes,
    _pose,
    _time,
    clocks,
    dropped,
    in_grid,
    poses,
)

from ..procs import spin_until, wait_emulator_ready  # noqa: E402


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


def test_link_emulator_delivers_the_batch_simulators_delay_stream(context):
    """Per link and tick, one message holding the pose labelled t - tau (tau from the delay
    stream of the trial) with its original label, or no pose while t - tau < 0."""
    from nav_msgs.msg import Path
    from std_msgs.msg import String

    from formation_ilc.config.runconfig import make_config
    from robot_sim.link_emulator import LinkEmulator

    cfg = make_config("paper-triangle3", seed=9)
    sc, clock = cfg.scenario, cfg.clock
    pb = Problem.from_scenario(sc)
    emu = LinkEmulator(context=context)
    tester = rclpy.create_node("tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(emu)
    ex.add_node(tester)
    try:
        got: dict[str, list[tuple[int, int | None]]] = {}

        def on_tick(msg: Path, link: str) -> None:
            tick, pose = ms.msg_to_link_tick(msg)
            got.setdefault(link, []).append(
                (tick, None if pose is None else ms.stamp_to_ns(pose.header.stamp)))

        links = [(2, "robot_1"), (3, "robot_1"), (1, ms.LEADER)]
        subs = [tester.create_subscription(Path, ms.link_topic(i, sender),
                                           lambda m, k=f"{sender}->{i}": on_tick(m, k),
                                           ms.SAMPLE_QOS) for i, sender in links]
        cfg_pub = tester.create_publisher(String, ms.CONFIG, ms.LATCHED_QOS)
        cfg_pub.publish(ms.json_to_msg(cfg.to_json()))
        spin_until(ex, lambda: emu.configured)
        shared = [tester.create_publisher(PoseStamped, ms.shared_pose_topic(j + 1),
                                          ms.SAMPLE_QOS) for j in range(pb.n)]
        ref = tester.create_publisher(PoseStamped, ms.REFERENCE, ms.SAMPLE_QOS)
        events = tester.create_publisher(String, ms.TRIAL_EVENTS, ms.SAMPLE_QOS)
        spin_until(ex, lambda: all(p.get_subscription_count() >= 1
                                   for p in [*shared, ref, events])
                   and all(sub.get_publisher_count() >= 1 for sub in subs))
        wait_emulator_ready(ex, tester, emu)
        ticks = 8
        # a hostile pose labelled with a later trial: dropped, it moves nothing
        shared[1].publish(ms.pose_to_msg(pb.eta_d[1, 0], clock.stamp_ns(5, 0),
                                         ms.WORLD_FRAME))
        events.publish(ms.json_to_msg({"event": ms.START, "trial": 0, "slot": 0, "seq": 0}))
        for t in range(ticks):  # lockstep: sample t+1 exists once tick t is delivered
            ns = clock.stamp_ns(0, t)
            for j in range(pb.n):
                shared[j].publish(ms.pose_to_msg(pb.eta_d[j, t], ns, ms.WORLD_FRAME))
            ref.publish(ms.pose_to_msg(sc.reference[t], ns, ms.WORLD_FRAME))
            spin_until(ex, lambda t=t: all(len(got.get(f"{s}->{i}", [])) == t + 1
                                           for i, s in links))
        tau, tau0 = sc.uncertainty.draw_delays(sc.seed, 0, pb.n, pb.src.shape[1], pb.samples)
        for i, sender in links:
            r = i - 1
            d = tau0[r] if sender == ms.LEADER else tau[r, list(pb.src[r]).index(0)]
            want = [(clock.stamp_ns(0, t),
                     clock.stamp_ns(0, t - int(d[t])) if t - int(d[t]) >= 0 else None)
                    for t in range(ticks)]
            assert got[f"{sender}->{i}"] == want, sender
        assert any(p is None for _, p in got["robot_1->2"])  # the early ticks carry nothing
        assert emu.links.k == 0 and emu.drops.counts["future"] == 1
    finally:
        ex.shutdown()
        emu.destroy_node()
        tester.destroy_node()
