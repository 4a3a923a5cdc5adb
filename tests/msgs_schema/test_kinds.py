"""A topic's kind (``names.topic_kind``) and each kind's type and QoS
(``msgs_schema.kinds``): the names read back into what made them, every topic of a robot's
roster member of a kind the schema has, and the kinds agree with the recorded topics'
table."""

from __future__ import annotations

import numpy as np
import pytest

from formation_ilc.config.roster import Lineup, roster
from formation_ilc.core import names as nm

pytest.importorskip("rclpy")
import msgs_schema as ms  # noqa: E402


def test_a_topic_name_reads_back_into_what_made_it():
    assert nm.topic_kind(nm.pose_topic(2)) == ("pose", "robot_2", "")
    assert nm.topic_kind(nm.applied_topic(12)) == ("applied", "robot_12", "")
    assert nm.topic_kind(nm.link_topic(2, nm.LEADER)) == (nm.LINKS, "robot_2", "leader")
    assert nm.topic_kind(nm.link_topic(3, "robot_1")) == (nm.LINKS, "robot_3", "robot_1")
    assert nm.topic_kind(nm.clock_pong_topic(nm.LEADER)) == ("clock/pong", "leader", "")
    assert nm.topic_kind(nm.clock_ping_topic("bridge_2")) == ("clock/ping", "bridge_2", "")
    # shared topics are their own kind, though two begin with the leader's name
    for t in (nm.CONFIG, nm.REFERENCE, nm.TRIAL_EVENTS, nm.TEAM_POSES, nm.ROS_DIAGNOSTICS,
              nm.CLOCK, "/pioneer_1/cmd_vel"):
        assert nm.topic_kind(t) == (t, "", "")


def _robot_topics() -> set[str]:
    """Every topic any robot publishes or reads: a keystore's lineup (both links, both
    hearings, told commands, clock exchanges) of a graph where robot 1 hears the leader."""
    a = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]], dtype=float)
    r = roster(Lineup(3, plant="physics", adjacency=a, leader=np.array([1.0, 0, 0]))
               .for_keystore())
    return {t for m in r.by_role("robot") for t in (*m.publish, *m.subscribe)}


def test_every_topic_of_a_robot_is_of_a_kind_the_schema_has():
    topics = _robot_topics()
    kinds = {nm.topic_kind(t)[0] for t in topics}
    assert kinds == set(ms.KINDS), (kinds ^ set(ms.KINDS))
    assert ms.kind_of("pose").type.__name__ == "PoseStamped"
    with pytest.raises(ValueError, match="no topic kind 'odom'.*cmd_vel"):
        ms.kind_of("odom")


def test_the_kinds_offer_what_the_recorded_topics_table_says():
    """The recorded topics' table (types by name, offered QoS) and the kinds agree."""
    for topic, type_name, qos in ms.topic_table(3):
        kind = nm.topic_kind(topic)[0]
        if kind in ms.KINDS:
            k = ms.KINDS[kind]
            pkg = k.type.__module__.split(".")[0]
            assert type_name == f"{pkg}/msg/{k.type.__name__}", topic
            assert k.offered == qos, topic
