"""Least-privilege DDS permissions of every node of a formation, derived from its graph.

A secure formation (``formation-ilc keystore``, ``launch --secure``) runs each node in an
SROS2 enclave whose signed permissions list the topics it may publish and subscribe; with
``Enforce`` Fast DDS refuses any other writer or reader at creation, and its peers refuse
a participant without a certificate of the formation's CA. The permissions come from the
scenario's communication graph (``adjacency[i, j] > 0``: robot i receives from robot j;
``leader[i] > 0``: robot i hears the leader):

* robot i publishes only its own ``cmd_vel``, ``shared_pose`` and ``trajectory``; it reads
  its own ``pose`` and ``links/*``, its in-neighbours' ``shared_pose`` and ``trajectory``,
  the leader's ``reference`` (if it hears the leader), ``config`` and ``trial_events``;
* the plant (``robot_sim``, or robot i's Pioneer bridge) publishes the poses and reads the
  ``cmd_vel`` of the robots it drives;
* the leader alone publishes ``config``, ``reference`` and ``trial_events``;
* the link emulator reads shared poses and the reference and publishes the emulated links;
* the recorder and the launcher's monitor read; like every node they publish on the
  protocol's shared ``ready`` and ``diagnostics`` topics.

Every node also gets its ROS housekeeping: ``rosout``, ``parameter_events``, its own
parameter and type-description services, and ``ros_discovery_info``.

Topic names are the caller's (``msgs_schema`` is the one place that names a topic and
imports ROS, so :class:`TopicNames` carries its names into this ROS-free module). This
module is pure: grants and XML text; ``formation_ilc.store.keystore`` signs and writes them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from xml.sax.saxutils import escape

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core.names import (
    FAKE_DRIVER_NODE,
    LEADER_NODE,
    LINKS_NODE,
    LIVEVIEW_NODE,
    MONITOR_NODE,
    RECORDER_NODE,
    SIM_NODE,
    bridge_name,
    robot_name,
)

__all__ = ["TopicNames", "DriverTopics", "Grant", "ENCLAVE_NODES", "formation_grants",
           "enclave_path", "dds_topic", "housekeeping", "permissions_xml", "governance_xml",
           "DOMAIN_MAX"]

#: the ROS domain ids a keystore serves (every id ROS 2 allows on Linux)
DOMAIN_MAX = 232
#: services every rclpy node offers under its own name
_NODE_SERVICES = ("describe_parameters", "get_parameter_types", "get_parameters",
                  "list_parameters", "set_parameters", "set_parameters_atomically",
                  "get_type_description")


@dataclass(frozen=True)
class TopicNames:
    """The schema's topic names (``msgs_schema``): relative to the formation's namespace,
    except ``clock``, which the caller resolves (``/clock``, or remapped into a namespace)."""

    config: str
    reference: str
    trial_events: str
    ready: str
    diagnostics: str
    clock: str
    pose: Callable[[int], str]
    cmd_vel: Callable[[int], str]
    shared_pose: Callable[[int], str]
    link: Callable[[int, str], str]
    trajectory: Callable[[int], str]
    true_trajectory: Callable[[int], str]
    #: every topic the recorder subscribes to, for n robots
    recorded: Callable[[int], Sequence[str]]
    leader: str = "leader"
    #: the observer's topics for n robots (desired poses, errors, markers): the recorder
    #: publishes them, or the live view when nothing records
    view: Callable[[int], Sequence[str]] = lambda n: ()
    #: the plant's preview of the team's poses for the live view ("": none)
    preview: str = ""
    #: every robot's pose of a sample for the robots' safety filters ("": none)
    team_poses: str = ""


@dataclass(frozen=True)
class DriverTopics:
    """A Pioneer driver's topics (``msgs_schema.DriverSpec``) in the namespace
    ``namespace`` (``{i}`` is the robot's number)."""

    namespace: str
    cmd: str
    odom: str
    motors: str
    motors_kind: str

    def ns(self, i: int) -> str:
        return self.namespace.replace("{i}", str(int(i))).rstrip("/") or ""

    def name(self, i: int, topic: str) -> str:
        return f"{self.ns(i)}/{topic}"


@dataclass(frozen=True)
class Grant:
    """What one node may do: its enclave, its node name and namespace, and the ROS topic
    names (absolute) it may publish and subscribe; services as DDS names (rq/, rr/)."""

    enclave: str
    node: str
    node_namespace: str
    publish: tuple[str, ...]
    subscribe: tuple[str, ...]
    dds_publish: tuple[str, ...] = ()
    dds_subscribe: tuple[str, ...] = ()
    #: the node name its ROS housekeeping (services) runs under; ``*``: any node in
    #: ``node_namespace`` (a driver whose node name is the driver's own)
    service_node: str = ""


#: enclave name -> what it is, for messages and docs
ENCLAVE_NODES = {
    LEADER_NODE: "the virtual leader",
    SIM_NODE: "the kinematic simulator (plant)",
    LINKS_NODE: "the link emulator",
    RECORDER_NODE: "the recorder",
    LIVEVIEW_NODE: "the live view (Foxglove WebSocket on 127.0.0.1)",
    MONITOR_NODE: "the launcher's monitor",
    "robot_i": "robot i's controller",
    "bridge_i": "robot i's Pioneer bridge (plant)",
    "driver_i": "robot i's Pioneer driver",
}


#: robot i's Pioneer driver runs in this enclave (its node name is the driver's own)
DRIVER_ENCLAVE_PREFIX = "driver_"


def driver_enclave(i: int) -> str:
    """The enclave of robot ``i``'s driver: ``driver_i`` (a real driver's, or the fake
    one's, whatever its node name)."""
    return f"{DRIVER_ENCLAVE_PREFIX}{int(i)}"


def enclave_path(namespace: str, name: str) -> str:
    """``/formation/robot_1``: the enclave of node ``name`` of the formation in
    ``namespace``."""
    return f"{namespace.rstrip('/')}/{name}"


def _abs(namespace: str, topic: str) -> str:
    return topic if topic.startswith("/") else f"{namespace.rstrip('/')}/{topic}"


def _grant(namespace: str, name: str, publish: Sequence[str], subscribe: Sequence[str], *,
           node_namespace: str | None = None, dds_publish: Sequence[str] = (),
           dds_subscribe: Sequence[str] = (), service_node: str = "") -> Grant:
    def absolute(names: Sequence[str]) -> tuple[str, ...]:
        return tuple(sorted({_abs(namespace, t) for t in names}))
    return Grant(enclave_path(namespace, name), name, node_namespace or namespace,
                 absolute(publish), absolute(subscribe), tuple(sorted(set(dds_publish))),
                 tuple(sorted(set(dds_subscribe))), service_node or name)


def _robot(t: TopicNames, namespace: str, i: int, senders: list[int], hears_leader: bool,
           n: int = 0) -> Grant:
    """Robot i (1-based): its own topics out; its pose, its links and its in-neighbours'
    shared poses and trajectories in (emulated and direct links both); for its safety
    filter every other robot's pose (behind bridges) and the plant's ``team/poses``."""
    sub = [t.pose(i), t.config, t.trial_events]
    sub += [t.pose(j) for j in range(1, n + 1) if j != i]
    if t.team_poses:
        sub.append(t.team_poses)
    sub += [t.link(i, robot_name(j)) for j in senders]
    sub += [t.shared_pose(j) for j in senders] + [t.trajectory(j) for j in senders]
    if hears_leader:
        sub += [t.link(i, t.leader), t.reference]
    pub = [t.cmd_vel(i), t.shared_pose(i), t.trajectory(i), t.ready, t.diagnostics]
    return _grant(namespace, robot_name(i), pub, sub)


def _pioneer(t: TopicNames, namespace: str, i: int, d: DriverTopics) -> list[Grant]:
    """Robot i's bridge (the plant contract for one robot) and its driver."""
    cmd, odom, motors = d.name(i, d.cmd), d.name(i, d.odom), d.name(i, d.motors)
    bridge_pub = [t.pose(i), t.ready, t.diagnostics, cmd]
    bridge_sub = [t.cmd_vel(i), t.trial_events, t.config, odom]
    driver_pub, driver_sub = [odom, f"{d.ns(i)}/{FAKE_DRIVER_NODE}/truth"], [cmd]
    rq = rr = ""
    if d.motors_kind == "p2os_motor_state":
        bridge_pub.append(motors)
        driver_sub.append(motors)
    else:  # a service: requests from the bridge, replies from the driver
        rq, rr = f"rq{motors}Request", f"rr{motors}Reply"
    return [_grant(namespace, bridge_name(i), bridge_pub, bridge_sub,
                   dds_publish=[rq] if rq else [], dds_subscribe=[rr] if rr else []),
            _grant(namespace, driver_enclave(i), driver_pub, driver_sub,
                   node_namespace=d.ns(i) or "/", dds_publish=[rr] if rr else [],
                   dds_subscribe=[rq] if rq else [], service_node="*")]


def formation_grants(adjacency: NDArray[np.float64], leader: NDArray[np.float64],
                     topics: TopicNames, namespace: str, *,
                     pioneer: DriverTopics | None = None) -> dict[str, Grant]:
    """Every node's grant, by enclave path, for the graph (``adjacency``, ``leader``).

    With ``pioneer`` the plant is one bridge and one driver per robot (``--plant pioneer``);
    otherwise the kinematic simulator. The link emulator's grant is always made (emulated
    links); a run with direct links does not start it.
    """
    a = np.asarray(adjacency, dtype=float)
    w = np.asarray(leader, dtype=float)
    n = a.shape[0]
    t = topics
    senders = [[int(j) + 1 for j in np.flatnonzero(a[i] > 0)] for i in range(n)]
    robots = range(1, n + 1)
    grants = [_robot(t, namespace, i, senders[i - 1], bool(w[i - 1] > 0), n) for i in robots]
    grants.append(_grant(namespace, LEADER_NODE,
                         [t.config, t.reference, t.trial_events, t.diagnostics],
                         # its own events too: it re-asserts against a start or abort
                         # it did not send (a buggy node's, or a lossy link's replay)
                         [t.ready, t.config, t.clock, t.trial_events]))
    links_pub = [t.link(i, robot_name(j)) for i in robots for j in senders[i - 1]]
    links_pub += [t.link(i, t.leader) for i in robots if w[i - 1] > 0]
    links_sub = [t.shared_pose(j) for j in robots]  # it reads every robot's, leaves too
    grants.append(_grant(namespace, LINKS_NODE, [*links_pub, t.ready, t.diagnostics],
                         [*links_sub, t.reference, t.trial_events, t.config, t.clock]))
    if pioneer is None:
        grants.append(_grant(
            namespace, SIM_NODE,
            [*(t.pose(i) for i in robots), *(t.true_trajectory(i) for i in robots), t.clock,
             t.ready, t.diagnostics, *([t.preview] if t.preview else []),
             *([t.team_poses] if t.team_poses else [])],
            [*(t.cmd_vel(i) for i in robots), t.trial_events, t.config]))
    else:
        for i in robots:
            grants += _pioneer(t, namespace, i, pioneer)
    grants.append(_grant(namespace, RECORDER_NODE, [t.ready, t.diagnostics, *t.view(n)],
                         list(t.recorded(n))))
    # the live view reads what the recording holds and serves it on 127.0.0.1
    grants.append(_grant(namespace, LIVEVIEW_NODE, list(t.view(n)),
                         [*t.recorded(n), *t.view(n), *([t.preview] if t.preview else [])]))
    grants.append(_grant(namespace, MONITOR_NODE, [t.ready],
                         [*(t.trajectory(i) for i in robots),
                          *(t.true_trajectory(i) for i in robots), t.diagnostics,
                          # readies: it answers a forged 'down' of itself by saying ready
                          t.trial_events, t.ready]))
    return {g.enclave: g for g in grants}


def dds_topic(ros_name: str) -> str:
    """The DDS topic of an absolute ROS topic name: ``/a/b`` -> ``rt/a/b``."""
    if not ros_name.startswith("/"):
        raise ValueError(f"not an absolute ROS topic name: {ros_name!r}")
    return "rt" + ros_name


def housekeeping(node_namespace: str, node: str) -> tuple[list[str], list[str]]:
    """(publish, subscribe) DDS topics of any rclpy node ``node`` in ``node_namespace``:
    rosout, parameter events, its own services, the ROS graph's discovery topic."""
    fq = f"{node_namespace.rstrip('/')}/{node}"
    pub = ["rt/rosout", "rt/parameter_events", "ros_discovery_info"]
    pub += [f"rr{fq}/{s}Reply" for s in _NODE_SERVICES]
    sub = ["rt/parameter_events", "ros_discovery_info"]
    sub += [f"rq{fq}/{s}Request" for s in _NODE_SERVICES]
    return pub, sub


def _stamp(t: datetime) -> str:
    return t.strftime("%Y-%m-%dT%H:%M:%S")


def permissions_xml(grant: Grant, subject: str, not_before: datetime, not_after: datetime
                    ) -> str:
    """The DDS-Security permissions document of one enclave (default DENY).

    ``subject`` is the identity certificate's subject (RFC 4514, e.g. ``CN=/formation/
    robot_1``); the validity is the certificate's, in UTC.
    """
    hk_pub, hk_sub = housekeeping(grant.node_namespace, grant.service_node or grant.node)
    pub = [dds_topic(x) for x in grant.publish] + list(grant.dds_publish) + hk_pub
    sub = [dds_topic(x) for x in grant.subscribe] + list(grant.dds_subscribe) + hk_sub

    def topics(names: list[str]) -> str:
        return "".join(f"\n            <topic>{escape(x)}</topic>"
                       for x in sorted(set(names)))

    return f"""<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" \
xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/\
omg_shared_ca_permissions.xsd">
  <permissions>
    <grant name="{escape(grant.enclave)}">
      <subject_name>{escape(subject)}</subject_name>
      <validity>
        <not_before>{_stamp(not_before)}</not_before>
        <not_after>{_stamp(not_after)}</not_after>
      </validity>
      <allow_rule>
        <domains>
          <id_range>
            <min>0</min>
            <max>{DOMAIN_MAX}</max>
          </id_range>
        </domains>
        <publish>
          <topics>{topics(pub)}
          </topics>
        </publish>
        <subscribe>
          <topics>{topics(sub)}
          </topics>
        </subscribe>
      </allow_rule>
      <default>DENY</default>
    </grant>
  </permissions>
</dds>
"""


def governance_xml() -> str:
    """The formation's governance: authenticated participants only, every reader and
    writer checked against the permissions, and every RTPS message between participants
    encrypted, with a MAC for each receiver (``ENCRYPT_WITH_ORIGIN_AUTHENTICATION``: a
    participant cannot pass off a message as another's); discovery and liveliness
    encrypted too.

    The encryption is per message, not per topic (``data_protection_kind`` NONE): per-topic
    keys are exchanged for every matched reader and writer (over two thousand exchanges in
    a 24-robot team, each sent to every participant), and such a team on two cores never
    finished them; with per-message keys, one exchange per pair of participants, it starts
    (docs/security.md). What it gives up: a team member that captures traffic not meant for
    it can decrypt it (its permissions still keep it from reading or writing the topic)."""
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<dds xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" \
xsi:noNamespaceSchemaLocation="http://www.omg.org/spec/DDS-SECURITY/20170901/\
omg_shared_ca_governance.xsd">
  <domain_access_rules>
    <domain_rule>
      <domains>
        <id_range>
          <min>0</min>
          <max>{DOMAIN_MAX}</max>
        </id_range>
      </domains>
      <allow_unauthenticated_participants>false</allow_unauthenticated_participants>
      <enable_join_access_control>true</enable_join_access_control>
      <discovery_protection_kind>ENCRYPT</discovery_protection_kind>
      <liveliness_protection_kind>ENCRYPT</liveliness_protection_kind>
      <rtps_protection_kind>ENCRYPT_WITH_ORIGIN_AUTHENTICATION</rtps_protection_kind>
      <topic_access_rules>
        <topic_rule>
          <topic_expression>*</topic_expression>
          <enable_discovery_protection>true</enable_discovery_protection>
          <enable_liveliness_protection>true</enable_liveliness_protection>
          <enable_read_access_control>true</enable_read_access_control>
          <enable_write_access_control>true</enable_write_access_control>
          <metadata_protection_kind>NONE</metadata_protection_kind>
          <data_protection_kind>NONE</data_protection_kind>
        </topic_rule>
      </topic_access_rules>
    </domain_rule>
  </domain_access_rules>
</dds>
"""
