"""A robot node publishes and reads exactly its member of the run's roster
(``config.roster``): read from the live graph, for each kind of run (links emulated or
direct, lockstep or realtime with clock exchanges, a safety filter that hears the plant's
team/poses or each robot, told commands or not); and a member's topic the node has no
writer or reader for stops it, named. In process: the robots take the run's configuration
from a test node's latched ``config``, as from the leader."""

from __future__ import annotations

from dataclasses import replace

import pytest

pytestmark = pytest.mark.ros

rclpy = pytest.importorskip("rclpy")
from rclpy.executors import SingleThreadedExecutor  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.roster import Lineup, roster  # noqa: E402
from formation_ilc.config.runconfig import RunConfig, make_config  # noqa: E402
from formation_ilc.config.safety import SafetySettings  # noqa: E402

from ..procs import spin_until  # noqa: E402

#: what rclpy makes for every node (not the roster's to say)
HOUSEKEEPING = {"/rosout", "/parameter_events"}

CASES = {
    "lockstep-emulated": dict(mode="lockstep", links="emulated"),
    "lockstep-direct": dict(mode="lockstep", links="direct"),
    "realtime-direct-team-told": dict(mode="realtime", links="direct",
                                      safety=SafetySettings(sensing="team",
                                                            motion="commands")),
    "realtime-emulated-peers": dict(mode="realtime", links="emulated",
                                    safety=SafetySettings(sensing="peers", motion="poses")),
}


def _config(case: str) -> RunConfig:
    kw = dict(CASES[case])
    safety = kw.pop("safety", None)
    cfg = make_config("paper-triangle3", noise=False, run_id="topics", **kw)
    return replace(cfg, safety=safety)


def _graph(node, who) -> tuple[set[str], set[str]]:
    """What node ``who`` publishes and reads, as the graph (``node``'s view) has it."""
    ns = who.get_namespace()
    pub = {t for t, _ in node.get_publisher_names_and_types_by_node(who.get_name(), ns)}
    sub = {t for t, _ in node.get_subscriber_names_and_types_by_node(who.get_name(), ns)}
    return pub - HOUSEKEEPING, sub - HOUSEKEEPING


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_robot_node_publishes_and_reads_its_roster_member_s_topics(context, case):
    from formation_ilc.nodes.robot import RobotNode

    cfg = _config(case)
    members = roster(Lineup.of_run(cfg)).by_role("robot")
    tester = rclpy.create_node("topics_tester", namespace=ms.NAMESPACE, context=context)
    ex = SingleThreadedExecutor(context=context)
    ex.add_node(tester)
    robots = []
    try:
        tester.create_publisher(ms.kind_of(ms.CONFIG).type, ms.CONFIG,
                                ms.LATCHED_QOS).publish(ms.json_to_msg(cfg.to_json()))
        robots = [RobotNode(m.robot, context=context) for m in members]
        for r in robots:
            ex.add_node(r)
        spin_until(ex, lambda: all(r.configured for r in robots), timeout=60)
        want = {m.name: ({ms.absolute(t) for t in m.publish},
                         {ms.absolute(t) for t in m.subscribe}) for m in members}
        spin_until(ex, lambda: {r.get_name(): _graph(tester, r) for r in robots} == want,
                   timeout=20)
        # the check has teeth: with a filter the robots hear each other, told or not
        heard = {t for r in robots for t in _graph(tester, r)[1]}
        assert (ms.absolute(ms.TEAM_POSES) in heard) == ("team" in case)
        assert (ms.absolute(ms.applied_topic(1)) in heard) == ("told" in case)
        assert (ms.absolute(ms.clock_pong_topic(ms.LEADER)) in heard) == ("realtime" in case)
    except AssertionError:
        got = {r.get_name(): _graph(tester, r) for r in robots}
        for m in members:
            mine = got.get(m.name, (set(), set()))
            print(m.name, "publishes, not in the roster:",
                  sorted(mine[0] - {ms.absolute(t) for t in m.publish}),
                  "| in the roster, not published:",
                  sorted({ms.absolute(t) for t in m.publish} - mine[0]),
                  "| reads, not in the roster:",
                  sorted(mine[1] - {ms.absolute(t) for t in m.subscribe}),
                  "| in the roster, not read:",
                  sorted({ms.absolute(t) for t in m.subscribe} - mine[1]))
        raise
    finally:
        ex.shutdown()
        for r in robots:
            r.destroy_node()
        tester.destroy_node()


@pytest.mark.parametrize(("side", "topic"), [
    ("subscribe", "robot_2/odom"),  # a kind no robot reads
    ("subscribe", ms.link_topic(2, "robot_3")),  # a link the graph does not have
    ("publish", ms.cmd_vel_topic(1)),  # another robot's command
    ("publish", ms.TEAM_POSES)])  # the plant's
def test_a_topic_the_robot_has_no_handler_for_is_refused_by_name(context, monkeypatch,
                                                                  side, topic):
    import formation_ilc.nodes.robot as robot_node

    def with_extra(lineup):
        r = roster(lineup)
        return replace(r, members=tuple(
            replace(m, **{side: (*getattr(m, side), topic)}) if m.name == "robot_2" else m
            for m in r.members))

    monkeypatch.setattr(robot_node, "roster", with_extra)
    robot = robot_node.RobotNode(2, context=context)  # waits for a configuration
    try:
        with pytest.raises(ValueError, match=f"robot_2: its roster member .*{topic}"):
            robot.configure(_config("lockstep-emulated"))
    finally:
        robot.destroy_node()
