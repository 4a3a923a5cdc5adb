"""Names of the distributed stack: nodes, topics, frames. The one place that spells them.

A node's name is what it says ready as, what its diagnostics carry, what the leader's
schedule waits for and what the launcher calls its process and log file
(``formation_ilc.config.roster``). A topic's name is what every node, the launcher, the
recordings and the keystore's permissions use. This module needs no ROS: code that needs a
name (the launcher's plan, the roster, the keystore's grants, the recordings) imports it
from here; ``msgs_schema`` re-exports every name beside the message types, QoS profiles and
converters, which do need ROS.

Names are relative: a node resolves them in its namespace (``NAMESPACE`` by default;
``--ros-args -r __ns:=/team2`` moves one node, ``formation-ilc launch --namespace /team2`` a
whole formation), so several formations share a ROS domain. ``/clock`` is the ROS
convention's absolute name; a namespaced launch remaps it into the namespace too
(``namespace_remaps``). Robots are 1-based in names (``robot_1``); the topic table with the
types and QoS is ``msgs_schema``'s docstring.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from formation_ilc.core.clock import Malformed

__all__ = ["NAMESPACE", "CLOCK", "LEADER_NODE", "SIM_NODE", "LINKS_NODE", "MONITOR_NODE",
           "RECORDER_NODE", "FAKE_DRIVER_NODE", "PHYSICS_NODE", "BASES_NODE", "BASE_TRUTH",
           "LIVEVIEW_NODE", "ROBOT_PREFIX", "BRIDGE_PREFIX", "robot_name",
           "robot_number", "bridge_name", "fake_driver_name", "robots_process_name",
           "namespace_remaps", "namespace_problem", "driver_ns_problem",
           # topics and frames
           "CONFIG", "REFERENCE", "TRIAL_EVENTS", "READY", "DIAGNOSTICS", "ROS_DIAGNOSTICS",
           "LEADER", "HOSTS_RUN", "HOSTS_NAMESPACE", "STOP_SERVICE", "ESTOP", "service_dds_topics",
           "WORLD_FRAME", "TF", "TF_STATIC", "LEADER_FRAME_ID", "odom_frame", "base_frame",
           "robot_description_topic", "pose_topic", "cmd_vel_topic", "applied_topic",
           "shared_pose_topic",
           "link_topic",
           "whereabouts_topic",
           "clock_ping_topic", "clock_pong_topic", "trajectory_topic", "true_trajectory_topic",
           "absolute", "relative", "clock_topic",
           "recorded_topics", "MARKERS", "desired_pose_topic", "desired_path_topic",
           "tracking_error_topic", "trial_error_topic", "view_topics", "PREVIEW", "TEAM_POSES",
           "SHARED_TOPICS", "LINKS", "topic_kind",
           # drivers
           "DriverSpec", "DRIVERS"]

#: the default namespace of every node of a formation
NAMESPACE = "/formation"
#: the ROS convention's absolute clock topic: the one name a namespaced formation remaps
CLOCK = "/clock"

# --------------------------------------------------------------------------- nodes

#: the virtual leader (reference, schedule, run configuration)
LEADER_NODE = "virtual_leader"
#: the kinematic simulator, the plant of simulated runs
SIM_NODE = "robot_sim"
#: the physics plant (PyBullet, every robot in one world)
PHYSICS_NODE = "physics_sim"
#: physics robots behind a base's interface (cmd_vel in, odometry out), for runs of the
#: base bridges without robots
BASES_NODE = "physics_bases"
#: each physics base's true pose (PoseStamped, world frame), relative to the base's
#: namespace: the simulator's ground truth, for the bridges' true trajectories
BASE_TRUTH = "truth"
#: the link emulator (emulated links)
LINKS_NODE = "link_emulator"
#: the launcher's monitor (metrics from the wire)
MONITOR_NODE = "monitor"
#: the recorder (MCAP)
RECORDER_NODE = "recorder"
#: the live view's bridge to Foxglove viewers (``launch --live``)
LIVEVIEW_NODE = "liveview"
#: a fake Pioneer driver (tests and runs without robots); one per robot, in the driver's
#: namespace, so the node name is the same for every robot
FAKE_DRIVER_NODE = "fake_pioneer"

ROBOT_PREFIX = "robot_"
#: a hardware bridge's node name is ``bridge_<id>`` (what it says ready as)
BRIDGE_PREFIX = "bridge_"


def robot_name(i: int) -> str:
    """Name of robot ``i`` (1-based): ``robot_i``; also its node name and topic prefix."""
    return f"{ROBOT_PREFIX}{int(i)}"


def robot_number(name: str) -> int:
    """1-based robot number of ``robot_i``; Malformed if ``name`` is not one (ASCII digits,
    no leading zero, at least 1)."""
    digits = name[len(ROBOT_PREFIX):]
    if not (name.startswith(ROBOT_PREFIX) and digits.isascii() and digits.isdigit()
            and digits[0] != "0"):
        raise Malformed(f"not a robot name: {name!r}")
    return int(digits)


def bridge_name(i: int) -> str:
    """Node name of robot ``i``'s hardware bridge: ``bridge_i``."""
    return f"{BRIDGE_PREFIX}{int(i)}"


def fake_driver_name(i: int) -> str:
    """The launcher's process (and log) name of robot ``i``'s fake driver."""
    return f"{FAKE_DRIVER_NODE}_{int(i)}"


def robots_process_name(first: int, last: int) -> str:
    """The launcher's process (and log) name of a container of robots first..last."""
    return f"robots_{int(first)}-{int(last)}"


_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def namespace_problem(namespace: str) -> str | None:
    """Why ``namespace`` is no absolute ROS namespace (``/a/b_2``: tokens of letters,
    digits and underscores, not starting with a digit), or None."""
    if not namespace.startswith("/"):
        return "an absolute ROS namespace starts with /"
    if namespace == "/":
        return None
    bad = [t for t in namespace[1:].split("/") if not _TOKEN.fullmatch(t)]
    if bad:
        return (f"{bad[0]!r} is no ROS name (letters, digits and underscores, not starting "
                f"with a digit)")
    return None


def driver_ns_problem(pattern: str) -> str | None:
    """Why ``pattern`` (robot i's driver namespace, ``{i}`` replaced by the robot number)
    names no valid namespace for every robot, or None."""
    if "{i}" not in pattern:
        return "needs {i} (one namespace per robot)"
    why = namespace_problem(pattern.replace("{i}", "1"))
    return None if why is None else f"robot 1's namespace {pattern.replace('{i}', '1')!r}: {why}"


def namespace_remaps(namespace: str | None) -> list[str]:
    """ROS arguments that put a node into ``namespace``, /clock included (nothing for the
    default one)."""
    if namespace is None or namespace == NAMESPACE:
        return []
    return ["-r", f"__ns:={namespace}", "-r", f"{CLOCK}:={namespace}{CLOCK}"]


# --------------------------------------------------------------------------- topics

CONFIG = "config"
#: the ground station's run description for the other hosts' launchers (latched JSON:
#: the run's id, domain, namespace, key and, once it ended, its status)
HOSTS_RUN = "hosts/run"
#: the namespace, below the formation's, of the other hosts' launchers' own node
HOSTS_NAMESPACE = "hosts"
REFERENCE = "leader/reference"
TRIAL_EVENTS = "leader/trial_events"
READY = "ready"
DIAGNOSTICS = "diagnostics"
#: the standard diagnostics stream ROS tools read (diagnostic_aggregator, rqt_robot_monitor):
#: every node's statuses about once a second, ``node: task`` names, plain values; absolute,
#: remappable with ``-r /diagnostics:=TOPIC``
ROS_DIAGNOSTICS = "/diagnostics"
#: the stop button: a std_srvs/srv/Trigger service of the leader (``/formation/stop``).
#: A call stops every robot (the leader latches ``ESTOP``) and ends the run with status 7
#: (``formation_ilc.system.exits.STOPPED``)
STOP_SERVICE = "stop"
#: the e-stop: std_msgs/Bool, latched. True: every bridge sends its driver zero and holds
#: it, every robot commands zero, whoever published it and whether the leader lives;
#: False releases the bridges (a run the leader ended stays ended)
ESTOP = "estop"


def service_dds_topics(service: str) -> tuple[str, str]:
    """The DDS topics of an absolute service name: its requests' and its replies'
    (``rq/formation/stopRequest``, ``rr/formation/stopReply``), as DDS-Security grants
    name them."""
    return f"rq{service}Request", f"rr{service}Reply"


#: the leader as a sender: link names ``leader->robot_i``, the emulated link
#: ``robot_i/links/leader``
LEADER = "leader"
#: REP-105 world-fixed frame of every pose and path
WORLD_FRAME = "map"
#: the frames, tf2's topics (tf2_msgs/msg/TFMessage; absolute, as tf2 has them): one tree
#: with ``WORLD_FRAME`` at its root, per robot ``robot_i/odom`` under it and
#: ``robot_i/base_link`` under that (REP-105), and the virtual leader's reference frame
TF = "/tf"
TF_STATIC = "/tf_static"
#: the virtual leader's frame: the reference r(t), under ``WORLD_FRAME``
LEADER_FRAME_ID = "leader"


def odom_frame(i: int) -> str:
    """Robot ``i``'s odometry frame (REP-105 ``odom``): ``robot_i/odom``."""
    return f"{robot_name(i)}/odom"


def base_frame(i: int) -> str:
    """Robot ``i``'s body frame (REP-105 ``base_link``): ``robot_i/base_link``."""
    return f"{robot_name(i)}/base_link"


def pose_topic(i: int) -> str:
    """Measured pose of robot ``i`` (plant -> robot)."""
    return f"{robot_name(i)}/pose"


def robot_description_topic(i: int) -> str:
    """Robot ``i``'s body as URDF (std_msgs/String, latched; its link ``robot_i/base_link``,
    ``config.urdf``), from the plant that drives it: what viewers draw the robot from."""
    return f"{robot_name(i)}/robot_description"


def whereabouts_topic(i: int) -> str:
    """Where robot ``i``'s bridge has it between trials, while it drives back to its start
    pose and once it stands there (bridge -> the other bridges, for their returns' safety
    filter); never read by a robot node."""
    return f"{robot_name(i)}/whereabouts"


def cmd_vel_topic(i: int) -> str:
    """Robot ``i``'s command (robot -> plant)."""
    return f"{robot_name(i)}/cmd_vel"


def applied_topic(i: int) -> str:
    """The command robot ``i`` applied over a sample (stamp = the sample's label), for the
    other robots' safety filters (``safety.motion: commands``: its speed, told)."""
    return f"{robot_name(i)}/applied"


def shared_pose_topic(i: int) -> str:
    """Robot ``i``'s labelled output, for its neighbours (stamp = send label St)."""
    return f"{robot_name(i)}/shared_pose"


#: the kind of an emulated link's topic (``topic_kind``)
LINKS = "links"


def link_topic(i: int, sender: str) -> str:
    """Emulated link ``sender -> robot_i``: one message per tick (0 or 1 pose)."""
    return f"{robot_name(i)}/{LINKS}/{sender}"


def clock_ping_topic(node: str) -> str:
    """Node ``node``'s questions for the clocks it estimates (``robot_2``, ``bridge_2``):
    sensor_msgs/TimeReference, each naming the clock it asks (``protocol.timesync``). Every
    node publishes only topics of its own name: the enclaves' permissions say who asked."""
    return f"{node}/clock/ping"


def clock_pong_topic(node: str) -> str:
    """Node ``node``'s answers to the questions for its clock (``robot_1``, ``leader``),
    each naming the node that asked."""
    return f"{node}/clock/pong"


def trajectory_topic(i: int) -> str:
    """Robot ``i``'s whole-trial measured output, sent at trial end."""
    return f"{robot_name(i)}/trajectory"


def true_trajectory_topic(i: int) -> str:
    """A simulator's ground truth (true state) of robot ``i`` for one trial, for metrics."""
    return f"{robot_name(i)}/true_trajectory"


def absolute(topic: str, namespace: str = NAMESPACE) -> str:
    """The full name of a topic in ``namespace`` (absolute names stay as they are)."""
    if topic.startswith("/"):
        return topic
    ns = namespace.rstrip("/")
    return f"{ns}/{topic}"


def relative(name: str, namespace: str = NAMESPACE) -> str:
    """The schema's name of a full topic name in ``namespace`` (inverse of ``absolute``)."""
    prefix = namespace.rstrip("/") + "/"
    return name[len(prefix):] if name.startswith(prefix) else name


def clock_topic(namespace: str) -> str:
    """Where the formation's ``/clock`` is: the launcher remaps it into any namespace but
    the default one (``namespace_remaps``)."""
    return CLOCK if namespace == NAMESPACE else f"{namespace.rstrip('/')}{CLOCK}"


def recorded_topics(n: int) -> list[str]:
    """Every recorded topic of a run of ``n`` robots, in the order of the schema's table
    (``msgs_schema.topic_table`` gives each its type and QoS).

    The recorder subscribes to exactly these; the batch simulator records on them too. Two
    kinds of message are left out because they repeat others bit for bit: the shared poses
    (``shared_pose_topic``: a robot re-sends its measured pose unchanged, label included)
    and the emulated links' per-tick messages (``link_topic``: shared poses and the
    reference, forwarded). The delays the links carried are in each robot's diagnostics.
    """
    names = [CONFIG, REFERENCE, TRIAL_EVENTS, READY, DIAGNOSTICS, CLOCK, ESTOP, TF, TF_STATIC]
    for i in range(1, n + 1):
        names += [pose_topic(i), cmd_vel_topic(i), trajectory_topic(i),
                  true_trajectory_topic(i), robot_description_topic(i)]
    return names


# --------------------------------------------------------------------------- view topics
# What the formation should be, for the live view and the recording: published by one
# observer (``formation_ilc.nodes.observer``: in the recorder, or in the live view's bridge
# when nothing records); the robots are untouched. Types: ``msgs_schema.view_topic_table``.

#: the 3D view's markers (outline, links, labels, errors)
MARKERS = "markers"


def desired_pose_topic(i: int) -> str:
    """eta_d of robot ``i`` at each sample (stamped with its label)."""
    return f"{robot_name(i)}/desired_pose"


def desired_path_topic(i: int) -> str:
    """eta_d of robot ``i`` over a whole trial, at its start (latched)."""
    return f"{robot_name(i)}/desired_path"


def tracking_error_topic(i: int) -> str:
    """Robot ``i``'s position and heading error at each sample."""
    return f"{robot_name(i)}/tracking_error"


def trial_error_topic(i: int) -> str:
    """Robot ``i``'s largest errors of each trial."""
    return f"{robot_name(i)}/trial_error"


def view_topics(n: int) -> list[str]:
    """The observer's topics for ``n`` robots, in the order of
    ``msgs_schema.view_topic_table``."""
    names = [MARKERS]
    for i in range(1, n + 1):
        names += [desired_pose_topic(i), desired_path_topic(i), tracking_error_topic(i),
                  trial_error_topic(i)]
    return names


#: the plant's preview of the team for viewers (every robot's pose of a sample in one
#: message, at most ``msgs_schema.PREVIEW_HZ`` a second, only while read); not recorded
PREVIEW = "preview/poses"
#: every robot's measured pose of a sample in one message, for the robots' safety filters
#: (``core.safety``): what a motion-capture system gives, once per sample from the plant
#: (the simulator, the physics plant) when the run has a filter with ``sensing: team``.
#: Pose i is robot i + 1's, each stamped with the sample's label as on robot_i/pose
TEAM_POSES = "team/poses"


# --------------------------------------------------------------------------- kinds

#: the topics of no node's name: each is its own kind (``topic_kind``)
SHARED_TOPICS = frozenset({CONFIG, REFERENCE, TRIAL_EVENTS, READY, DIAGNOSTICS,
                           ROS_DIAGNOSTICS, ESTOP, CLOCK, TF, TF_STATIC, MARKERS, PREVIEW,
                           TEAM_POSES, HOSTS_RUN})


def topic_kind(topic: str) -> tuple[str, str, str]:
    """What the relative name ``topic`` is, as (kind, node, sender), the inverse of the
    topic functions above. A topic of a node's own name is the part after that name, and
    the node: ``robot_2/pose`` -> ('pose', 'robot_2', ''), ``leader/clock/pong`` ->
    ('clock/pong', 'leader', ''); an emulated link is ``LINKS`` with its receiver and its
    sender: ``robot_2/links/leader`` -> ('links', 'robot_2', 'leader'); a shared topic
    (``SHARED_TOPICS``: ``config``, ``leader/reference``) or an absolute one (a driver's)
    is its own kind, of no node: ('config', '', '')."""
    if topic in SHARED_TOPICS or topic.startswith("/") or "/" not in topic:
        return topic, "", ""
    node, kind = topic.split("/", 1)
    if kind.startswith(LINKS + "/"):
        return LINKS, node, kind[len(LINKS) + 1:]
    return kind, node, ""


# --------------------------------------------------------------------------- drivers

@dataclass(frozen=True)
class DriverSpec:
    """A Pioneer driver's side of the bridge: topic names relative to the driver's
    namespace (the bridge's ``driver_ns`` parameter; remap further with ``-r``).

    cmd : velocity command in (Twist, or TwistStamped with the bridge's ``cmd_type``);
    odom : nav_msgs/Odometry out, starting at 0 where the robot was placed;
    motors : how motors are enabled; motors_kind: 'empty_service' (std_srvs/Empty),
        'setbool_service' (std_srvs/SetBool, data true), 'p2os_motor_state'
        (p2os_msgs/MotorState with state 1, a topic) or 'none' (a base whose motors are
        always on: TurtleBot, Jackal, Husky);
    default_ns : the driver's usual namespace.
    """

    cmd: str
    odom: str
    motors: str
    motors_kind: str
    default_ns: str


DRIVERS: dict[str, DriverSpec] = {
    # RosAria (ROS 1 via ros1_bridge, or its ROS 2 ports): node RosAria
    "rosaria": DriverSpec("cmd_vel", "pose", "enable_motors", "empty_service", "/RosAria"),
    # p2os2 (p2os_driver): motors on by publishing p2os_msgs/MotorState{state: 1}
    "p2os2": DriverSpec("cmd_vel", "pose", "cmd_motor_state", "p2os_motor_state", "/"),
    # ros2aria: odometry on ``odom``; the motors are engaged through ``clutch``. Assumed a
    # std_srvs/SetBool service (true = engaged); not verified against the driver's source:
    # check ``ros2 interface`` on the robot, and remap or change motors_kind if it differs
    "ros2aria": DriverSpec("cmd_vel", "odom", "clutch", "setbool_service", "/"),
    # any differential-drive base with the common interface: cmd_vel in, nav_msgs/Odometry
    # out, no motor service (formation_ilc.config.bases has presets of the topic names)
    "base": DriverSpec("cmd_vel", "odom", "", "none", "/"),
}
