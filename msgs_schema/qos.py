"""The stack's QoS profiles: how each kind of topic is offered and read (the topic table in
``msgs_schema``'s docstring says which topic has which)."""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["SAMPLE_QOS", "ROS_DIAGNOSTICS_QOS", "LATCHED_QOS",
           "LATCHED_READER_QOS", "TRAJECTORY_QOS",
           "TRAJECTORY_READER_QOS", "CLOCK_QOS", "ODOM_QOS", "DRIVER_CMD_QOS", "VIEW_QOS",
           "PREVIEW_HZ", "PREVIEW_QOS", "TF_QOS", "TF_STATIC_QOS", "TF_STATIC_READER_QOS"]

# Lockstep must not lose a sample on localhost: reliable, and deep enough for a burst.
# The depth is also how far a passive reader (the recorder, niced, outside the lockstep)
# may fall behind before a writer drops samples it has not acknowledged: at 64, a recorder
# that stalled for about 0.25 s of a 280 samples/s run lost samples 70-76 of trial 1 (seen
# in CI); 512 gives it about 2 s.
SAMPLE_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=512,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
# Configuration, readiness and diagnostics: a late joiner gets the last word of each writer.
# The standard diagnostics stream, as diagnostic_updater publishes it (reliable, volatile): a
# reader that joins late has every node's status within a period of the stream (1 s)
ROS_DIAGNOSTICS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                 reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.VOLATILE)
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Readers of a latched topic with many writers (ready, diagnostics): a reader's KEEP_LAST
# history is shared by all writers of a keyless topic, so depth 1 would lose messages.
LATCHED_READER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=256,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Trial-end trajectories: latched too, so a reader matched late still gets trial k's.
TRAJECTORY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.TRANSIENT_LOCAL)
# Readers of trajectories: deeper than the writers' 2, because a reader's KEEP_LAST history
# is shared by every writer of the topic, and two stray writers' messages (a restarted
# node's, a forger's) taken in the same instant as a trial's trajectory would evict it.
TRAJECTORY_READER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=32,
                                   reliability=ReliabilityPolicy.RELIABLE,
                                   durability=DurabilityPolicy.TRANSIENT_LOCAL)
# /clock: reliable writer (also serves rclpy's best-effort time-source readers); as deep
# as SAMPLE_QOS, for the recorder.
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=512,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)


# Drivers publish odometry best effort or reliable: a best-effort reader matches both.
ODOM_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.VOLATILE)
# A reliable, volatile writer matches both reliable and best-effort cmd_vel readers.
DRIVER_CMD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)


#: per-sample view messages: reliable to the recorder, never held for a viewer (depth-bound)
VIEW_QOS = SAMPLE_QOS

#: the plant's preview of the team for viewers (``PREVIEW``): a nav_msgs/Path stamped with
#: a sample's label holding every robot's measured pose of that sample (the bytes it sends
#: on robot_i/pose), at most ``PREVIEW_HZ`` a second of wall time, and only while a reader
#: takes it. A lockstep run makes hundreds of samples a second; a viewer that takes the
#: preview instead of every pose costs the run one message per frame, not one per robot
#: and sample. Best effort: the plant never waits for a viewer. Not recorded (the poses
#: are).
PREVIEW_HZ = 30.0
PREVIEW_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)

# tf2's own profiles: /tf as tf2_ros' TransformBroadcaster offers it (reliable, volatile,
# depth 100), /tf_static as its StaticTransformBroadcaster (reliable, transient local, depth
# 1: each writer's one message holds all its static transforms)
TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
TF_STATIC_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL)
# a reader of /tf_static keeps every writer's message (one writer per plant or bridge)
TF_STATIC_READER_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=256,
                                  reliability=ReliabilityPolicy.RELIABLE,
                                  durability=DurabilityPolicy.TRANSIENT_LOCAL)
