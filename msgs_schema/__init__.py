"""The wire contract of the distributed stack: topic names, message types, QoS, converters.

Nodes and tests import everything of the wire from here. The names themselves are
``formation_ilc.core.names``' (re-exported here), so that code which needs only a name (the
launcher's plan, the roster, the keystore's grants, the recordings) needs no ROS. The rest
is in this package's modules, all re-exported: ``qos`` (the profiles), ``tables`` (each
recorded and view topic with its type and QoS), ``convert`` (numpy <-> message converters,
tested by round trip in tests/msgs_schema/), ``wire`` (the per-sample messages as bytes),
``drivers`` (odometry and commands of a robot's driver), ``kinds`` (each kind of topic
with its type and QoS, for a node that wires its roster member's topics), ``view`` (the
view messages) and ``diagnostics``. Standard messages only.

Names are relative: a node resolves them in its namespace (``NAMESPACE`` by default;
``--ros-args -r __ns:=/team2`` moves one node, ``formation-ilc launch --namespace /team2`` a
whole formation), so several formations share a ROS domain. ``/clock`` is the ROS
convention's absolute name; a namespaced launch remaps it into the namespace too.

Topics (robot ``i`` is 1-based in names, index ``i - 1`` in arrays; ``S`` a sender,
``robot_j`` or ``leader``):

=========================  ===========================  ==================================
topic                      type                         from -> to
=========================  ===========================  ==================================
config                     std_msgs/String (JSON)       leader -> all (latched)
leader/reference           geometry_msgs/PoseStamped    leader -> robots that see it, links
leader/trial_events        std_msgs/String (JSON)       leader -> all
ready                      std_msgs/String (JSON)       all -> leader (latched)
diagnostics                diagnostic_msgs/             all -> monitor, recorder,
                           DiagnosticArray              ROS tools (latched)
robot_i/pose               geometry_msgs/PoseStamped    plant -> robot i
robot_i/cmd_vel            geometry_msgs/Twist          robot i -> plant
robot_i/robot_description  std_msgs/String (URDF,       plant (simulator, physics plant,
                           latched)                     bridge i) -> viewers
robot_i/shared_pose        geometry_msgs/PoseStamped    robot i -> out-neighbours (direct),
                                                        link emulator (emulated)
robot_i/links/S            nav_msgs/Path (0 or 1 pose)  link emulator -> robot i (emulated)
X/clock/ping               sensor_msgs/TimeReference    realtime and wallclock: node X's
                                                        questions for the clocks it hears
                                                        (X robot_i or bridge_i) -> them
X/clock/pong               sensor_msgs/TimeReference    node X's answers (X robot_j or
                                                        leader) -> the nodes that asked
robot_i/trajectory         nav_msgs/Path (trial end)    robot i -> out-neighbours, monitor
robot_i/true_trajectory    nav_msgs/Path (trial end)    simulator, physics plant, bridge
                                                        of a physics base (optional) ->
                                                        monitor
/clock                     rosgraph_msgs/Clock          plant, in simulated time -> all
estop                      std_msgs/Bool (latched)      leader (a stop call), anyone ->
                                                        bridges, robots, leader, recorder
preview/poses              nav_msgs/Path (every         simulator, <= PREVIEW_HZ while
                           robot's pose of a sample)    read -> live view (not recorded)
team/poses                 nav_msgs/Path (every         simulator, physics plant (every
                           robot's pose of a sample)    sample, with a safety filter) ->
                                                        robots' safety filters
=========================  ===========================  ==================================

Services: ``stop`` (std_srvs/Trigger), the leader's stop button: every robot commands zero
(``estop`` latched true) and the run ends with status 7.

Frames (REP-105). Every pose and path is in the world-fixed frame ``WORLD_FRAME`` ("map");
the topic names whose pose it is. Diagnostics and ready messages name their node in JSON.

Time labels (``formation_ilc.core.clock.SampleClock``). A stamp is ``(k * period + s) * dT``
[ns] for trial ``k`` and sample ``s``. The plant stamps robot i's pose with the label of
its sample: the robot's clock Rt of eq. (11). The shared pose keeps that stamp as the send
label St; the robot measures each delay from St and its own Rt. An emulated link's message
for tick t is stamped t (the tick) and holds the pose delivered then, with its ORIGINAL
stamp, or no pose when nothing is delivered at t. In ``mode: wallclock`` (real robots)
stamps are wall time instead (``formation_ilc.core.clock.WallGrid``): sample s of slot q is
stamped ``start(q) + s * dT``, the start agreed by the leader's ``start`` event, whose
remainder by dT is q; the label (q, s) follows from the stamp exactly. Malformed input raises
:class:`MalformedMessage`, which nodes count and drop.

The per-sample messages (poses, shared poses, references, link ticks, ``cmd_vel``,
``/clock``) travel as CDR bytes that ``msgs_schema.wire`` packs and reads without rclpy's
message objects (the same bytes, the same checks); the converters below remain for
everything else and for tests.

The plant contract
------------------
A plant (the kinematic simulator, a hardware bridge, a test's stand-in) closes the loop for
robots 1..N. It

1. reads the run configuration on ``config`` (latched) and follows ``leader/trial_events``;
2. publishes, for each robot i and each sample s = 0..T of trial k, the measured pose on
   ``robot_i/pose`` (PoseStamped in ``WORLD_FRAME``, stamp ``stamp_ns(k, s)``); sample 0
   after the ``start`` event of trial k, sample s+1 after it applied sample s's command
   (``mode: wallclock``, real robots: sample s at the wall time
   ``start_wall_ns + s * dT``, ``start_wall_ns`` being in the ``start`` event, and stamped
   with that time);
3. applies ``robot_i/cmd_vel`` (Twist: ``linear.x`` = v [m/s], ``angular.z`` = omega
   [rad/s]) from its sample to the next; in lockstep it waits for every robot's command,
   in realtime it holds the last command of a robot that is late;
4. in simulated time owns ``/clock``: it publishes the sample's time before that sample's
   poses, and the leader broadcasts the reference on it (not in ``wallclock``: nobody
   publishes ``/clock``, the leader follows its own wall timer);
5. says ``{"node": NAME, "trial": k}`` on ``ready`` (latched) when it can run trial k
   (k = 0 once its publishers are matched; k+1 after sample T of trial k).

It may publish ``robot_i/true_trajectory`` (its ground truth) at trial end and its own
``diagnostics``; nothing in the stack needs them (metrics then lack the true-state columns).
"""

from __future__ import annotations

from formation_ilc.core.clock import SampleClock
from formation_ilc.core.links import link_name
from formation_ilc.core.names import (
    BASE_TRUTH,
    BASES_NODE,
    BRIDGE_PREFIX,
    CLOCK,
    CONFIG,
    DIAGNOSTICS,
    DRIVERS,
    ESTOP,
    FAKE_DRIVER_NODE,
    LEADER,
    LEADER_FRAME_ID,
    LEADER_NODE,
    LINKS,
    LINKS_NODE,
    LIVEVIEW_NODE,
    MARKERS,
    MONITOR_NODE,
    NAMESPACE,
    PHYSICS_NODE,
    PREVIEW,
    READY,
    RECORDER_NODE,
    REFERENCE,
    ROS_DIAGNOSTICS,
    SHARED_TOPICS,
    SIM_NODE,
    STOP_SERVICE,
    TEAM_POSES,
    TF,
    TF_STATIC,
    TRIAL_EVENTS,
    WORLD_FRAME,
    DriverSpec,
    absolute,
    applied_topic,
    base_frame,
    bridge_name,
    clock_ping_topic,
    clock_pong_topic,
    clock_topic,
    cmd_vel_topic,
    desired_path_topic,
    desired_pose_topic,
    link_topic,
    odom_frame,
    pose_topic,
    recorded_topics,
    relative,
    robot_description_topic,
    robot_name,
    service_dds_topics,
    shared_pose_topic,
    topic_kind,
    tracking_error_topic,
    trajectory_topic,
    trial_error_topic,
    true_trajectory_topic,
    view_topics,
    whereabouts_topic,
)
from formation_ilc.core.names import robot_number as robot_index
from formation_ilc.protocol.schedule import ABORT, DONE, END, START
from msgs_schema import wire
from msgs_schema.clocksync import *  # noqa: F403
from msgs_schema.clocksync import __all__ as _clocksync
from msgs_schema.convert import *  # noqa: F403
from msgs_schema.convert import __all__ as _convert
from msgs_schema.diagnostics import *  # noqa: F403
from msgs_schema.diagnostics import __all__ as _diagnostics
from msgs_schema.drivers import *  # noqa: F403
from msgs_schema.drivers import __all__ as _drivers
from msgs_schema.kinds import *  # noqa: F403
from msgs_schema.kinds import __all__ as _kinds
from msgs_schema.qos import *  # noqa: F403
from msgs_schema.qos import __all__ as _qos
from msgs_schema.tables import *  # noqa: F403
from msgs_schema.tables import __all__ as _tables
from msgs_schema.view import *  # noqa: F403
from msgs_schema.view import __all__ as _view

#: sender name of the leader's reference (link names ``leader->robot_i``)
LEADER_FRAME = LEADER
#: trial events (``event`` field of the JSON on TRIAL_EVENTS): START, END, ABORT, DONE,
#: defined with the protocol (slots, aborts, ready) in ``formation_ilc.protocol.schedule``

__all__ = [
    # names (formation_ilc.core.names)
    "NAMESPACE", "CONFIG", "REFERENCE", "TRIAL_EVENTS", "READY", "DIAGNOSTICS", "CLOCK",
    "ROS_DIAGNOSTICS", "ESTOP", "STOP_SERVICE", "service_dds_topics", "TF", "TF_STATIC",
    "LEADER_FRAME_ID", "odom_frame", "base_frame", "robot_description_topic",
    "WORLD_FRAME", "LEADER", "LEADER_FRAME", "robot_name", "robot_index", "link_name",
    "pose_topic", "cmd_vel_topic", "applied_topic", "shared_pose_topic", "link_topic",
    "trajectory_topic",
    "whereabouts_topic", "true_trajectory_topic", "absolute", "relative", "clock_topic",
    "recorded_topics",
    "MARKERS", "desired_pose_topic", "desired_path_topic", "tracking_error_topic",
    "trial_error_topic", "view_topics", "PREVIEW", "TEAM_POSES", "DriverSpec", "DRIVERS",
    "SHARED_TOPICS", "LINKS", "topic_kind",
    "BRIDGE_PREFIX",
    "bridge_name", "LEADER_NODE", "SIM_NODE", "LINKS_NODE", "MONITOR_NODE", "RECORDER_NODE",
    "FAKE_DRIVER_NODE", "PHYSICS_NODE", "BASES_NODE", "BASE_TRUTH", "LIVEVIEW_NODE",
    # the protocol's events, the sample clock
    "START", "END", "ABORT", "DONE", "SampleClock",
    # this package's modules
    "wire", *_qos, *_tables, *_convert, *_drivers, *_kinds, *_view, *_diagnostics, *_clocksync,
    "clock_ping_topic", "clock_pong_topic",
]
