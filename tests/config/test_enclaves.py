"""Permissions derived from a formation's graph (the roster's grants, formation_ilc.config
.enclaves' documents): least privilege per node, no ROS needed."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from formation_ilc.config.enclaves import (
    Grant,
    dds_topic,
    governance_xml,
    housekeeping,
    permissions_xml,
)
from formation_ilc.config.roster import Lineup, roster
from formation_ilc.core.names import ROS_DIAGNOSTICS, view_topics

NS = "/formation"


def grants_of(adj, leader, *, plant: str = "sim", **kw) -> dict[str, Grant]:
    """Every enclave's grant of the formation ``adj``, ``leader`` in NS, as the keystore
    makes them."""
    lineup = Lineup(len(adj), plant=plant, adjacency=adj, leader=leader, **kw)
    return roster(lineup.for_keystore()).grants(NS)


# robot 1 hears the leader; 2 <- 1; 3 <- 1, 2 (a_ij > 0: i receives from j)
ADJ = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0]], dtype=float)
LEADER = np.array([1.0, 0.0, 0.0])


@pytest.fixture
def grants():
    return grants_of(ADJ, LEADER)


def test_robot_publishes_only_its_own_topics(grants):
    # the clock exchanges (protocol.timesync): its questions if it hears a robot or the
    # leader (all three do), its answers if a robot hears it (robots 1 and 2)
    for i in (1, 2, 3):
        g = grants[f"{NS}/robot_{i}"]
        own = {f"{NS}/robot_{i}/{t}" for t in ("cmd_vel", "shared_pose", "trajectory",
                                               "clock/ping", "applied")}
        own |= {f"{NS}/robot_{i}/clock/pong"} if i in (1, 2) else set()
        # the report and the standard stream (/diagnostics, absolute)
        assert set(g.publish) == own | {f"{NS}/ready", f"{NS}/diagnostics", ROS_DIAGNOSTICS}
        others = [t for t in g.publish if "/robot_" in t and f"/robot_{i}/" not in t]
        assert others == []


def test_robot_reads_its_in_neighbours_and_the_leader_only_if_it_hears_it(grants):
    g3 = set(grants[f"{NS}/robot_3"].subscribe)
    for j in (1, 2):
        assert f"{NS}/robot_{j}/shared_pose" in g3 and f"{NS}/robot_{j}/trajectory" in g3
        assert f"{NS}/robot_3/links/robot_{j}" in g3
    assert f"{NS}/leader/reference" not in g3
    # every robot's pose (behind bridges) and the plant's team/poses: the safety filter
    # keeps it away from all of them, neighbours or not; reading is all it may do
    assert {f"{NS}/robot_{j}/pose" for j in (1, 2, 3)} <= g3
    assert f"{NS}/team/poses" in g3
    g2 = set(grants[f"{NS}/robot_2"].subscribe)
    assert f"{NS}/robot_3/shared_pose" not in g2  # 3 is not an in-neighbour of 2
    assert f"{NS}/robot_1/shared_pose" in g2
    g1 = set(grants[f"{NS}/robot_1"].subscribe)
    assert {f"{NS}/leader/reference", f"{NS}/robot_1/links/leader"} <= g1
    assert not any("shared_pose" in t for t in g1)


def test_only_the_plant_reads_cmd_vel_and_publishes_poses(grants):
    for path, g in grants.items():
        if path.endswith("robot_sim"):
            assert {f"{NS}/robot_{i}/cmd_vel" for i in (1, 2, 3)} <= set(g.subscribe)
            assert {f"{NS}/robot_{i}/pose" for i in (1, 2, 3)} <= set(g.publish)
            continue
        pub_poses = [t for t in g.publish if t.endswith("/pose")]
        assert pub_poses == [], path
        cmd = [t for t in g.publish if t.endswith("/cmd_vel")]
        assert cmd == ([f"{path}/cmd_vel"] if "/robot_" in path else []), path


def test_only_the_leader_publishes_config_reference_and_events(grants):
    leader_topics = {f"{NS}/config", f"{NS}/leader/reference", f"{NS}/leader/trial_events"}
    for path, g in grants.items():
        mine = leader_topics & set(g.publish)
        assert mine == (leader_topics if path.endswith("virtual_leader") else set()), path


def test_recorder_and_monitor_publish_only_protocol_topics(grants):
    # and the recorder the view topics of its observer (desired poses, errors, markers)
    view = {f"{NS}/{t}" for t in view_topics(3)}
    assert set(grants[f"{NS}/recorder"].publish) == {f"{NS}/ready", f"{NS}/diagnostics",
                                                     ROS_DIAGNOSTICS, *view}
    # the monitor is the ground station's: it may latch the e-stop
    assert set(grants[f"{NS}/monitor"].publish) == {f"{NS}/ready", f"{NS}/estop"}
    assert f"{NS}/robot_3/cmd_vel" in grants[f"{NS}/recorder"].subscribe


def test_only_the_ground_station_may_call_stop_and_only_the_leader_serves_it(grants):
    rq, rr = f"rq{NS}/stopRequest", f"rr{NS}/stopReply"
    for path, g in grants.items():
        calls = rq in g.dds_publish and rr in g.dds_subscribe
        serves = rq in g.dds_subscribe and rr in g.dds_publish
        assert calls == path.endswith("/monitor"), path
        assert serves == path.endswith("/virtual_leader"), path
        # every robot and bridge obeys the e-stop; only the ground station and the
        # leader latch it
        if path.rsplit("/", 1)[-1].split("_")[0] in ("robot", "bridge") and path[-1].isdigit():
            assert f"{NS}/estop" in g.subscribe, path
        assert (f"{NS}/estop" in g.publish) == path.endswith(("/monitor", "/virtual_leader"))


def test_link_emulator_serves_exactly_the_graph_links(grants):
    g = grants[f"{NS}/link_emulator"]
    links = {t for t in g.publish if "/links/" in t}
    assert links == {f"{NS}/robot_1/links/leader", f"{NS}/robot_2/links/robot_1",
                     f"{NS}/robot_3/links/robot_1", f"{NS}/robot_3/links/robot_2"}


def test_adding_a_robot_changes_only_the_grants_that_see_it(grants):
    adj = np.zeros((4, 4))
    adj[:3, :3] = ADJ
    adj[3, 2] = 1.0  # robot 4 <- robot 3
    bigger = grants_of(adj, np.append(LEADER, 0.0))
    assert set(bigger) - set(grants) == {f"{NS}/robot_4"}
    same = {p for p in grants if grants[p] == bigger[p]}
    assert same == {f"{NS}/virtual_leader"}
    # the robots already there change only by reading robot 4's pose and the command it
    # tells (their safety filter), and robot 3 by answering robot 4's clock questions
    # (protocol.timesync)
    for i in (1, 2, 3):
        old, new = grants[f"{NS}/robot_{i}"], bigger[f"{NS}/robot_{i}"]
        asks = {f"{NS}/robot_4/clock/ping"} if i == 3 else set()
        answers = {f"{NS}/robot_3/clock/pong"} if i == 3 else set()
        assert set(new.subscribe) - set(old.subscribe) == {f"{NS}/robot_4/pose",
                                                            f"{NS}/robot_4/applied"} | asks
        assert set(new.publish) - set(old.publish) == answers
        assert set(old.publish) <= set(new.publish) and set(old.subscribe) <= set(new.subscribe)


def test_pioneer_bridges_and_drivers(grants):
    g = grants_of(ADJ, LEADER, plant="pioneer", driver="rosaria")
    assert f"{NS}/robot_sim" not in g
    b2 = g[f"{NS}/bridge_2"]
    assert f"{NS}/robot_2/cmd_vel" in b2.subscribe and f"{NS}/robot_1/cmd_vel" not in b2.subscribe
    assert "/pioneer_2/cmd_vel" in b2.publish and "/pioneer_1/cmd_vel" not in b2.publish
    assert b2.dds_publish == ("rq/pioneer_2/enable_motorsRequest",)
    d2 = g[f"{NS}/driver_2"]
    assert d2.node_namespace == "/pioneer_2"
    assert d2.dds_subscribe == ("rq/pioneer_2/enable_motorsRequest",)
    assert "/pioneer_2/cmd_vel" in d2.subscribe


def test_housekeeping_names_the_nodes_own_services():
    pub, sub = housekeeping("/formation", "robot_2")
    assert "rr/formation/robot_2/get_parametersReply" in pub
    assert "rq/formation/robot_2/set_parametersRequest" in sub
    assert {"rt/rosout", "ros_discovery_info"} <= set(pub)
    assert not any("robot_1" in t for t in pub + sub)


def test_dds_topic_names():
    assert dds_topic("/formation/robot_1/pose") == "rt/formation/robot_1/pose"
    with pytest.raises(ValueError, match="absolute"):
        dds_topic("robot_1/pose")


def test_permissions_document(grants):
    from datetime import UTC, datetime

    g = grants[f"{NS}/robot_2"]
    text = permissions_xml(g, "CN=/formation/robot_2", datetime(2026, 1, 1, tzinfo=UTC),
                           datetime(2027, 1, 1, tzinfo=UTC))
    root = ET.fromstring(text)
    grant = root.find("permissions/grant")
    assert grant is not None and grant.get("name") == "/formation/robot_2"
    assert grant.findtext("subject_name") == "CN=/formation/robot_2"
    assert grant.findtext("validity/not_after") == "2027-01-01T00:00:00"
    assert grant.findtext("default") == "DENY"
    pub = [t.text for t in grant.findall("allow_rule/publish/topics/topic")]
    sub = [t.text for t in grant.findall("allow_rule/subscribe/topics/topic")]
    assert "rt/formation/robot_2/cmd_vel" in pub and "rt/formation/robot_1/cmd_vel" not in pub
    assert "rt/formation/robot_1/shared_pose" in sub
    assert "rt/formation/robot_3/shared_pose" not in sub


def test_governance_encrypts_and_refuses_strangers():
    root = ET.fromstring(governance_xml())
    rule = root.find("domain_access_rules/domain_rule")
    assert rule is not None
    assert rule.findtext("allow_unauthenticated_participants") == "false"
    assert rule.findtext("enable_join_access_control") == "true"
    # every RTPS message encrypted, a MAC per receiver: per message, not per topic (a
    # 24-robot team never finished the per-topic key exchanges; docs/security.md)
    assert rule.findtext("rtps_protection_kind") == "ENCRYPT_WITH_ORIGIN_AUTHENTICATION"
    # discovery and liveliness ride in those encrypted messages, without a second layer of
    # their own (its per-endpoint key exchanges took 24 secure robots past 40 s to start)
    assert rule.findtext("discovery_protection_kind") == "NONE"
    assert rule.findtext("liveliness_protection_kind") == "NONE"
    topic = rule.find("topic_access_rules/topic_rule")
    assert topic is not None and topic.findtext("topic_expression") == "*"
    assert topic.findtext("enable_write_access_control") == "true"
    assert topic.findtext("enable_read_access_control") == "true"
    assert topic.findtext("enable_discovery_protection") == "false"
    assert topic.findtext("enable_liveliness_protection") == "false"
