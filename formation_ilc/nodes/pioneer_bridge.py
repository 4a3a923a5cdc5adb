"""Pioneer 3-DX bridge (``formation-ilc-bridge``): one real robot behind the plant contract.

One bridge per robot, on that robot beside its robot node (``-p robot_id:=I``; the node is
named ``bridge_I`` and says ready under that name). It needs ``mode: wallclock`` and
``links: direct`` (``formation-ilc launch --plant pioneer`` sets both).

Plant side (msgs_schema's plant contract, robot I): at each sample s of trial k, at the
wall time start_wall_ns + s * dT agreed by the leader's ``start`` event, it publishes the
robot's world pose on ``robot_I/pose`` stamped with that wall time (``WallGrid``: the
label (k, s) follows from it); it
forwards ``robot_I/cmd_vel`` to the driver, clamped to ``v_max``/``omega_max``.

Driver side (parameter ``driver``; topics relative to ``driver_ns``, default the driver's
usual namespace; remap further with ``-r``):

* ``rosaria``: ``cmd_vel`` (Twist) in, ``pose`` (nav_msgs/Odometry) out, motors enabled
  by the std_srvs/Empty service ``enable_motors``;
* ``p2os2``: ``cmd_vel``, ``pose``, motors enabled by publishing p2os_msgs/MotorState
  (state 1) on ``cmd_motor_state`` (p2os_msgs comes from p2os's ROS 2 workspace: source it);
* ``ros2aria``: ``cmd_vel``, ``odom``, motors engaged by the service ``clutch`` (assumed
  std_srvs/SetBool; see msgs_schema.DRIVERS).
* ``base``: any differential-drive base with the common interface (TurtleBot 3/4, Jackal,
  Husky): ``cmd_vel`` in, ``odom`` out, no motor service. ``base:=NAME`` picks a preset of
  ``formation_ilc.config.bases`` (topic names, cmd_type, limits; driver ``base`` implied).
  Yaw comes from the full quaternion; odometry tilted by more than ``max_tilt`` [deg]
  (default 10) is refused (counted as malformed, with the reason), the largest accepted
  tilt is reported (``tilt_max_deg``).

Limits: ``v_max`` [m/s], ``omega_max`` [deg/s], ``a_max`` [m/s^2], ``alpha_max``
[deg/s^2] (0: the preset's, or for Pioneer drivers 0.75 m/s, 100 deg/s and no acceleration
limit; ``formation_ilc.protocol.bridge.bridge_limits``). With a base preset every command
sent to the driver, in trials and returns alike, goes through them
(``core.limits.RateLimiter``, on the command's own stamp); ``clipped`` counts robot
commands clamped in speed, ``clipped_accel`` commands held back by the acceleration limits.

``cmd_type``: ``twist`` (default) or ``twist_stamped`` (Jazzy's diff_drive_controller).
Odometry is read best effort (matches reliable and best-effort drivers). The command is
republished at ``rate`` Hz (default 20) so the driver's own watchdog does not stop the
robot mid-sample; once the robot node has been silent for ``cmd_timeout`` s (default 0:
2.5 dT, 0.5 s at dT = 0.2 s) the command is zero. World pose = ``initial_pose`` (x, y,
theta; default: the scenario's desired start of robot I, where the robot is placed)
composed with the odometry.

Between trials (after sample T) it drives the robot back to ``initial_pose`` with a polar
point-stabilisation law (formation_ilc.protocol.bridge.ReturnController): ``return_tol`` [m],
``return_tol_heading`` [deg], ``return_timeout`` [s]. A timeout is logged and counted
(``return_timeouts`` in diagnostics); the achieved initial shift (b_xi0 of Assumption 2,
odometry-measured) goes into its ready message and diagnostics (``initial_shifts``).
Ready for trial 0 once the driver's odometry arrives, the motors are enabled, the
publishers are matched and its estimate of the leader's clock has converged (at most
``clock_wait`` s after the leader's first answer, default 10; then it samples on the
fallback and says so; before any answer it does not wait).

Clocks (realtime and wall-clock runs): the bridge asks the leader for its time
(its questions on ``bridge_I/clock/ping``, the leader's answers on
``leader/clock/pong``; ``formation_ilc.protocol.timesync``) and samples on the leader's
clock as it estimates it: sample s is due when the leader's clock reads
start_wall_ns + s * dT, whatever this robot's clock reads, so
every robot of the team samples at the same instants without a synchronised network.
Until the estimate has converged it samples on the run's fallback (``clocks.fallback``:
the estimate so far, or the robot's own clock); with ``clocks.sync`` off (``--no-clock-
sync``), on its own clock. Its diagnostics (``clock``) hold the estimate, its
uncertainty and how many samples were taken on each (``sampled_on``). Commands to the
driver are stamped with the robot's own clock (the driver's).

What it obeys (the rest is dropped and counted in its diagnostics, with the reason): a
``start`` event only for the trial after the current one, once it said ready for it and is
idle, with an agreed start no more than ``START_AHEAD_MAX`` s ahead and not past the trial's
end; ``cmd_vel`` only inside a trial (a command before a start or during the return would
move the robot outside the protocol). Starts and aborts are taken by the rule every follower
of the schedule applies (``formation_ilc.protocol.schedule.Follower``).

With ``lifecycle:=true`` it is a managed node (``rclpy.lifecycle``, the standard
``change_state`` service and its transitions), as a lab's lifecycle manager drives a
hardware driver: it starts unconfigured and sends the driver nothing; ``configure``
succeeds only once the driver is there (a writer of its odometry, a reader of its
commands, its motor service if it has one) and fails otherwise, naming what is missing;
``activate`` enables the motors, lets commands through and lets the bridge say ready;
``deactivate`` and
``shutdown`` send the driver one zero command at once and nothing after (the robot
stops; the bridge keeps sampling its pose). ``formation-ilc launch --lifecycle`` drives
the transitions itself.

The e-stop: ``estop`` (std_msgs/Bool, latched), from whoever publishes it, with or without
a leader: true sends the driver a zero command at once and holds every command at zero
(the robot's, the return's, the repeats) until false releases it (``estops`` counts the
latches). Frames (``nodes.frames``): ``map -> robot_I/odom`` (the initial pose) on
``/tf_static`` (with ``pose_topic``: on ``/tf``, where the world pose and the odometry put
the odometry's origin, moving as it drifts), ``robot_I/odom -> robot_I/base_link`` (the
odometry) on ``/tf``; the body
(its base preset's URDF, else a Pioneer 3-DX's) on ``robot_I/robot_description``. With
``lifecycle:=true`` each transition is one INFO line of its log.

Everything it decides is in ``formation_ilc.protocol.bridge.Bridge``; this node reads its
parameters, talks to the driver (its motors included) and makes one call into the bridge
per event.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from collections import Counter
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry, Path
from rclpy.lifecycle import LifecycleNodeMixin, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from std_msgs.msg import Bool, String

import msgs_schema as ms
from formation_ilc.config import params
from formation_ilc.config.bases import LIMIT_KEYS, base_preset
from formation_ilc.core.clock import Rejected
from formation_ilc.nodes.clocks import ClockExchange, node_clock
from formation_ilc.nodes.common import (
    ConfiguredNode,
    RunConfig,
    make_config,
    matched,
    node_parser,
    robot_node_from_args,
    spin_main,
)
from formation_ilc.nodes.frames import BRIDGE_TF_HZ, Frame, Frames, describe_body
from formation_ilc.nodes.params import ParameterError, check, declare, effective
from formation_ilc.protocol.bridge import (
    Bridge,
    CommandLimits,
    Pose,
    Returned,
    bridge_limits,
    odom_origin,
    return_filter,
)
from formation_ilc.protocol.schedule import Ready
from formation_ilc.protocol.wallclock import START_AHEAD_MAX

__all__ = ["BridgeNode", "main", "TICK", "START_AHEAD_MAX"]

#: the bridge's control tick [s]: sampling, return controller, watchdog
TICK = 0.01
#: [s] a motor service call without an answer after this is made again (enabling is idempotent)
MOTOR_RETRY_S = 3.0


def _join(ns: str, name: str) -> str:
    return f"{ns.rstrip('/')}/{name}" if ns not in ("", "/") else f"/{name}"


class BridgeNode(LifecycleNodeMixin, ConfiguredNode):
    """The bridge of robot ``robot_id`` (parameter; ``**kwargs`` go to ``Node``); a managed
    node with the ``lifecycle`` parameter (its state machine and services are made only
    then)."""

    #: what a bridge that took its own scenario runs with (its draws and links are not its)
    AGREES_ON = ("scenario", "scenario_text", "mode", "gap")
    #: commands go to the driver (a plain bridge always; a managed one while active)
    active = True

    def __init__(self, robot_id: int | None = None, **kwargs: Any):
        if robot_id is None:
            for p in kwargs.get("parameter_overrides") or ():
                if p.name == "robot_id":
                    robot_id = p.value
        if robot_id is None:
            raise ParameterError("parameter robot_id: a robot number >= 1 is required "
                                 "(--ros-args -p robot_id:=I)")
        robot_id = int(check(params.BRIDGE[0], robot_id))
        # not super(): the lifecycle mixin is set up below, and only for a managed bridge
        ConfiguredNode.__init__(self, ms.bridge_name(robot_id), **kwargs)
        self.id = int(robot_id)
        self.name = ms.bridge_name(self.id)
        declare(self, params.BRIDGE, robot_id=self.id)
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        base = str(g("base")) or None
        self.base_name = base
        preset = base_preset(base) if base else None
        driver = "base" if preset is not None else str(g("driver"))
        if driver not in ms.DRIVERS:
            raise ValueError(f"parameter driver: one of {', '.join(ms.DRIVERS)}, got {driver!r}")
        self.spec = ms.DRIVERS[driver]
        if preset is not None:
            self.spec = dataclasses.replace(self.spec, cmd=preset.cmd_topic,
                                            odom=preset.odom_topic)
        self.driver = driver if preset is None else f"base ({preset.name})"
        cmd_type = str(g("cmd_type"))
        if cmd_type not in ("", "twist", "twist_stamped"):
            raise ValueError(f"parameter cmd_type: twist or twist_stamped, got {cmd_type!r}")
        # a preset's message type unless another is asked for
        self.stamped = (cmd_type or (preset.cmd_type if preset is not None else "twist")
                        ) == "twist_stamped"
        self.max_tilt = math.radians(float(g("max_tilt")))
        lim = bridge_limits(base, {k: float(g(k)) for k in LIMIT_KEYS})
        self.limits = CommandLimits(lim.v_max, lim.omega_max)
        # acceleration limits only for a base: the Pioneer drivers' runs stay as they were
        self.rate = lim if preset is not None else None
        self.period = 1.0 / float(g("rate"))
        ns = str(g("driver_ns")) or self.spec.default_ns
        self.driver_topics = (_join(ns, self.spec.cmd), _join(ns, self.spec.odom),
                              _join(ns, self.spec.motors))
        #: a simulated base's true pose (``truth``), or None
        self.truth_topic = _join(ns, ms.BASE_TRUTH) if bool(g("truth")) else None
        #: where the robot's world pose comes from: the driver's odometry (""), or a world
        #: pose topic (motion capture, a localiser; ``truth`` for the physics bases)
        self.located_topic = _join(ns, str(g("pose_topic"))) if str(g("pose_topic")) else None
        # the parameters read what the bridge drives with: a preset's driver, topics,
        # message type and limits
        used = {"v_max": lim.v_max, "omega_max": math.degrees(lim.omega_max)}
        if preset is not None:
            used.update(a_max=lim.a_max, alpha_max=math.degrees(lim.alpha_max))
        effective(self, {"driver": driver, "driver_ns": ns,
                         "cmd_type": "twist_stamped" if self.stamped else "twist",
                         **{k: float(v) for k, v in used.items() if math.isfinite(v)}})
        self.managed = bool(g("lifecycle"))
        self.active = not self.managed
        if self.managed:
            LifecycleNodeMixin.__init__(self)
        cfg = None
        if g("scenario"):
            cfg = make_config(str(g("scenario")), noise=False, delay=False, links="direct",
                              mode=str(g("mode")))
        self.follow_config(cfg)

    # ------------------------------------------------------------------ lifecycle
    def driver_missing(self) -> list[str]:
        """What of the driver is not there (empty: all of it): a writer of its odometry,
        a reader of its commands, its motor service if it has one."""
        cmd_t, odom_t, motors_t = self.driver_topics
        missing = []
        if self.count_publishers(odom_t) == 0:
            missing.append(f"no writer of {odom_t}")
        if self.count_subscribers(cmd_t) == 0:
            missing.append(f"no reader of {cmd_t}")
        if self.spec.motors_kind not in ("none", "p2os_motor_state") and motors_t not in {
                name for name, _ in self.get_service_names_and_types()}:
            missing.append(f"no service {motors_t}")
        return missing

    def _transition(self, name: str, state: LifecycleState, to: str,
                    result: TransitionCallbackReturn) -> TransitionCallbackReturn:
        """Log a transition at INFO, one line, as nav2's lifecycle nodes do (a failed one
        says what failed before)."""
        if result == TransitionCallbackReturn.SUCCESS:
            self.get_logger().info(f"{self.name}: lifecycle: {name}: {state.label} -> {to}")
        else:
            self.get_logger().info(f"{self.name}: lifecycle: {name} from {state.label} "
                                   f"failed ({result.name.lower()})")
        return result

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        missing = self.driver_missing()
        if missing:
            self.get_logger().error(f"{self.name}: configure failed, the driver is not there: "
                                    f"{'; '.join(missing)}")
            return self._transition("configure", state, "inactive",
                                    TransitionCallbackReturn.FAILURE)
        return self._transition("configure", state, "inactive", super().on_configure(state))

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = True
        return self._transition("activate", state, "active", super().on_activate(state))

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._halt()
        return self._transition("deactivate", state, "inactive", super().on_deactivate(state))

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("cleanup", state, "unconfigured", super().on_cleanup(state))

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._halt()
        return self._transition("shutdown", state, "finalized", super().on_shutdown(state))

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("error", state, "unconfigured", super().on_error(state))

    def _halt(self) -> None:
        """One zero command to the driver now, and no command after (until activated)."""
        self.active = False
        if self.configured and hasattr(self, "drv_pub"):
            self.drv_pub.publish(ms.driver_twist(0.0, 0.0, self.stamped, self._wall_ns()))
            self.core.stop(time.monotonic())
            self.get_logger().info(f"{self.name}: stopped: a zero command sent to "
                                   f"{self.driver_topics[0]}, and no command after")

    # ------------------------------------------------------------------ set-up
    def configure(self, cfg: RunConfig) -> None:
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        init = [float(x) for x in g("initial_pose")]
        # the run's safety filter keeps the returns apart too, decided every tick
        safety = None if cfg.safety is None else return_filter(cfg.safety, TICK)
        self.core = core = Bridge(
            cfg, self.id, name=self.name,
            initial=(init[0], init[1], init[2]) if len(init) == 3 else None,
            limits=self.limits, rate=self.rate, cmd_timeout=float(g("cmd_timeout")),
            period=self.period,
            tol=(float(g("return_tol")), math.radians(float(g("return_tol_heading"))),
                 float(g("return_timeout"))), truth=self.truth_topic is not None,
            safety=safety, located=self.located_topic is not None)
        self.follower = core.follower
        self.cfg = cfg
        effective(self, {"scenario": cfg.scenario_param, "mode": cfg.mode,
                         "cmd_timeout": float(core.watchdog.timeout)})
        self.motors_on = False

        self.pose_pub = self.create_publisher(PoseStamped, ms.pose_topic(self.id),
                                              ms.SAMPLE_QOS)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.create_subscription(Twist, ms.cmd_vel_topic(self.id), self._on_cmd, ms.SAMPLE_QOS)
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        # the e-stop, obeyed from whoever latches it, with or without a leader
        self.create_subscription(Bool, ms.ESTOP, self._on_estop, ms.LATCHED_READER_QOS)
        cmd_t, odom_t, motors_t = self.driver_topics
        self.drv_pub = self.create_publisher(TwistStamped if self.stamped else Twist, cmd_t,
                                             ms.DRIVER_CMD_QOS)
        self.create_subscription(Odometry, odom_t, self._on_odom, ms.ODOM_QOS)
        self._wire_peers_and_truth(cfg, safety is not None)
        self._setup_motors(motors_t)
        # the frames: robot_i/odom where the robot was placed (located: where its world
        # pose and its odometry put it, moving as the odometry drifts), robot_i/base_link
        # in it as the driver's odometry has it (nodes.frames)
        x0, y0, th0 = core.initial
        self.frames = Frames(self, [] if core.located else [
            Frame(ms.WORLD_FRAME, ms.odom_frame(self.id), x0, y0, th0)])
        # the robot's body, latched (config.urdf): its base preset's, else a Pioneer 3-DX
        self.body_pub = describe_body(self, self.id, self.base_name or "p3dx")
        self._tf_due = 0.0
        # the robot's clock (the machine's; in an emulated run its robot's), and the
        # leader's as this bridge estimates it: samples are due on the team's time
        self.wall = node_clock(cfg, self.id)
        self.clocks: ClockExchange | None = None
        self.sampled_on: Counter[str] = Counter()
        # an emulated run's truth of this robot's clock: how far from the leader's instants
        # (true time) each sample was taken, to score the run (the bridge never uses it)
        self.truth = cfg.clocks.robot_clock(cfg.scenario.seed, self.id)
        self.sample_lags: list[float] = []
        self.clock_wait = float(self.get_parameter("clock_wait").value)
        self._clock_t0: float | None = None  # when the leader's first answer was seen
        if cfg.clock_exchanges:
            # clock words on a writer of their own (the report's keeps one message)
            self.word_pub = self.create_publisher(DiagnosticArray, ms.DIAGNOSTICS,
                                                  ms.LATCHED_QOS)
            self.clocks = ClockExchange(self, self.name, cfg, self.wall, peers=[ms.LEADER],
                                        askers=(), drops=self.drops,
                                        on_report=self._clock_word)
        self._tick = self.create_timer(TICK, self._on_tick)
        self._gate = self.create_timer(0.05, self._check_ready)
        self.get_logger().info(f"{self.name}: driver {self.driver} ({cmd_t}, {odom_t}, "
                               f"motors {motors_t}), initial pose {core.initial}, limits "
                               f"{self.limits.v_max} m/s {math.degrees(self.limits.omega_max):.0f}"
                               f" deg/s")

    def _wire_peers_and_truth(self, cfg: RunConfig, returns: bool) -> None:
        """With the returns filtered (``returns``): where every other robot is, from its
        own bridge; from a physics base: the robot's true pose; a located pose."""
        self.where_pub = None
        if returns:  # between trials: where each robot is, for the returns
            self.where_pub = self.create_publisher(PoseStamped, ms.whereabouts_topic(self.id),
                                                   ms.SAMPLE_QOS)
            # each from its own bridge only (protocol.writers): a forged one, stamped
            # ahead, would stand for that robot and hide where it really is
            for j in range(1, cfg.scenario.n + 1):
                if j != self.id:
                    self.checked_subscription(PoseStamped, ms.whereabouts_topic(j),
                                              lambda m, gid, j=j: self._on_whereabouts(m, j),
                                              ms.SAMPLE_QOS, owners=(ms.bridge_name(j),))
        self.true_pub = None
        if self.truth_topic is not None:
            # from the physics bases only (protocol.writers): forged true poses made the
            # true error read 63.9 m
            self.checked_subscription(PoseStamped, self.truth_topic,
                                      lambda m, gid: self._on_truth(m), ms.ODOM_QOS,
                                      owners=(ms.BASES_NODE,))
            self.true_pub = self.create_publisher(Path, ms.true_trajectory_topic(self.id),
                                                  ms.TRAJECTORY_QOS)
        if self.located_topic is not None and self.located_topic != self.truth_topic:
            self.create_subscription(PoseStamped, self.located_topic, self._on_located,
                                     ms.ODOM_QOS)

    def _setup_motors(self, topic: str) -> None:
        kind = self.spec.motors_kind
        self.motor_future: Any = None
        if kind == "none":  # a base whose motors are always on
            self.motors_on = True
            return
        if kind == "p2os_motor_state":
            try:
                from p2os_msgs.msg import MotorState  # type: ignore[import-not-found]
            except ImportError:
                raise ValueError(
                    f"{self.name}: driver p2os2 needs the p2os_msgs Python package, which is "
                    f"not on PyPI: build p2os's ROS 2 workspace and source its setup file "
                    f"before starting the bridge (or use driver rosaria / ros2aria)") from None
            self.motor_msg = MotorState(state=1)
            self.motor_pub = self.create_publisher(MotorState, topic, ms.DRIVER_CMD_QOS)
        else:
            from std_srvs.srv import Empty, SetBool

            self.motor_srv = Empty if kind == "empty_service" else SetBool
            self.motor_client = self.create_client(self.motor_srv, topic)
        self._motor_timer = self.create_timer(0.2, self._enable_motors)
        self._motor_wait = time.monotonic()
        self._motor_sent = 0.0

    def _enable_motors(self) -> None:
        if self.motors_on:
            self._motor_timer.cancel()
            return
        if not self.active:  # a managed bridge: the motors go on when it is activated
            return
        if self.spec.motors_kind == "p2os_motor_state":
            if self.motor_pub.get_subscription_count() > 0:
                self.motor_pub.publish(self.motor_msg)
                self.motors_on = True
            return
        if self.motor_future is None:
            if self.motor_client.service_is_ready():
                req = self.motor_srv.Request()
                if hasattr(req, "data"):
                    req.data = True
                self.motor_future = self.motor_client.call_async(req)
                self._motor_sent = time.monotonic()
            elif time.monotonic() - self._motor_wait > 5.0:
                self._motor_wait = time.monotonic()
                self.get_logger().warning(f"waiting for the driver's motor service "
                                          f"{self.driver_topics[2]}")
            return
        if not self.motor_future.done():
            if time.monotonic() - self._motor_sent > MOTOR_RETRY_S:
                # the driver took the call but its answer never came (a response writer
                # not yet matched to this client's reader, as a secure handshake can leave
                # it: "failed to send response (timeout)"); enabling the motors again is
                # harmless, waiting forever is not
                self.motor_client.remove_pending_request(self.motor_future)
                self.motor_future = None
                self.get_logger().warning(f"{self.driver_topics[2]}: no answer in "
                                          f"{MOTOR_RETRY_S:g} s; asking again")
            return
        if self.motor_future.done():
            res = self.motor_future.result()
            if res is not None and getattr(res, "success", True) is False:
                self.get_logger().error(f"{self.driver_topics[2]} refused: "
                                        f"{getattr(res, 'message', '')}; retrying")
                self.motor_future = None
                return
            self.motors_on = True
            self.get_logger().info("motors enabled")

    def _wall_ns(self) -> int:
        """The robot's wall clock [ns]."""
        return self.wall.now(time.time_ns())

    def _team_ns(self) -> tuple[int, str]:
        """The team's time (the leader's clock as this bridge estimates it) and how it was
        had (``ClockSync.remote_time``: converged, estimate, own)."""
        own = self._wall_ns()
        if self.clocks is None or not self.cfg.clocks.sync:
            return own, "own"
        return self.clocks.sync.remote_time(ms.LEADER, own)

    def _clock_settled(self) -> bool:
        """Whether the bridge may say ready for trial 0 as far as its clock goes: its
        estimate of the leader's clock converged, or ``clock_wait`` s passed since the
        leader's first answer (then it samples on the fallback and says so once), or no
        answer yet (no leader to wait for: it samples on the fallback until there is)."""
        if self.clocks is None or not self.cfg.clocks.sync:
            return True
        if self._team_ns()[1] == "converged":
            return True
        first = self.clocks.sync.links[ms.LEADER].last_answer_ns
        if first is None:
            return True
        if self._clock_t0 is None:
            self._clock_t0 = time.monotonic()
        if time.monotonic() - self._clock_t0 < self.clock_wait:
            return False
        if not getattr(self, "_fallback_said", False):
            self._fallback_said = True
            est = self.clocks.sync.estimate(ms.LEADER, self._wall_ns())
            text = (f"{self.name}: the estimate of the leader's clock has not converged after "
                    f"{self.clock_wait:g} s ({'no answer' if est is None else est.to_json()}): "
                    f"sampling on the fallback ({self.cfg.clocks.fallback})")
            self.get_logger().warning(text)
            self._clock_word([["warn", text]])
        return True

    def _clock_word(self, events: list[list[str]] | None = None) -> None:
        """Where this bridge's estimate of the leader's clock is, as a word on diagnostics
        between its reports (``clock_word``)."""
        assert self.clocks is not None
        self.diag_pub.word(ms.diagnostics_to_msg(
            {"node": self.name, "trial": self.core.iteration, "clock": self.clocks.report(),
             "clock_word": {"events": events or []}},
            self.get_clock().now().nanoseconds, self.cfg.scenario.dt,
            self.cfg.scenario.samples, ms.robot_name(self.id)), self.word_pub, "clock")

    def _check_ready(self) -> None:
        if not self.active:  # a managed bridge says ready once it is active
            return
        if self.core.odom is None or not self.motors_on or not self._clock_settled():
            return
        if self.true_pub is not None and self.core.truth is None:
            return  # a simulated base's true pose: every trial's true trajectory needs one
        need = [(self.pose_pub, 1), (self.ready_pub, 1), (self.drv_pub, 1)]
        if self.true_pub is not None:  # every reader of the results, by name
            need.append((self.true_pub, self.cfg.result_readers))
        if matched(need, self):
            self._gate.cancel()
            self._say_ready(0, "placed", self.core.shift())

    # ------------------------------------------------------------------ inputs
    def _on_odom(self, msg: Odometry) -> None:
        tilt = 0.0
        try:
            if self.spec.motors_kind == "none":  # a base: yaw of the full quaternion
                x, y, yaw, tilt = ms.base_odometry_to_pose(msg, self.max_tilt)
                pose = (x, y, yaw)
            else:
                pose = ms.odometry_to_pose(msg)
        except Rejected as exc:
            self.drops.reject(exc, self.driver_topics[1])
            return
        now = time.monotonic()
        self.core.on_odom(pose, now, tilt)
        if now >= self._tf_due:
            self._tf_due = now + 1.0 / BRIDGE_TF_HZ
            frames = [Frame(ms.odom_frame(self.id), ms.base_frame(self.id), *pose)]
            if self.core.located and self.core.odom is not None:
                frames.append(Frame(ms.WORLD_FRAME, ms.odom_frame(self.id),
                                    *odom_origin(self.core.odom, pose)))
            self.frames.publish(self._team_ns()[0], frames)

    def _on_whereabouts(self, msg: PoseStamped, robot: int) -> None:
        try:
            eta, ns = ms.world_pose(msg)
        except Rejected as exc:
            self.drops.reject(exc, ms.whereabouts_topic(robot))
            return
        self.core.on_peer(robot, (float(eta[0]), float(eta[1]), float(eta[2])), ns,
                          time.monotonic())

    def _world_pose(self, msg: PoseStamped, topic: str | None) -> Pose | None:
        """A world pose from ``topic``, or None (counted as dropped) if it is not one."""
        try:
            eta, _ = ms.world_pose(msg)
        except Rejected as exc:
            self.drops.reject(exc, str(topic))
            return None
        return (float(eta[0]), float(eta[1]), float(eta[2]))

    def _on_truth(self, msg: PoseStamped) -> None:
        pose = self._world_pose(msg, self.truth_topic)
        if pose is None:
            return
        self.core.on_truth(pose)
        if self.located_topic == self.truth_topic:  # the physics bases' motion capture
            self.core.on_located(pose, time.monotonic())

    def _on_located(self, msg: PoseStamped) -> None:
        pose = self._world_pose(msg, self.located_topic)
        if pose is not None:
            self.core.on_located(pose, time.monotonic())

    def _on_cmd(self, msg: Twist) -> None:
        wall = self._wall_ns()
        try:
            u = ms.twist_to_u(msg)
            cmd = self.core.on_cmd((float(u[0]), float(u[1])), time.monotonic(), wall)
        except Rejected as exc:
            self.drops.reject(exc, ms.cmd_vel_topic(self.id))
            return
        self._send(cmd, wall)

    def _on_estop(self, msg: Bool) -> None:
        was = self.core.estopped
        cmd = self.core.estop(bool(msg.data), time.monotonic())
        if cmd is not None:  # zero to the driver now, not at the next tick
            self._send(cmd, self._wall_ns())
        if bool(msg.data) != was:
            topic = self.resolve_topic_name(ms.ESTOP)
            self.get_logger().warning(
                f"{self.name}: e-stop on {topic}: zero to {self.driver_topics[0]}, held until "
                f"released" if msg.data else f"{self.name}: e-stop released on {topic}")

    def _on_event(self, msg: String) -> None:
        core = self.core
        ev = self.take_event(msg, lambda ev: core.on_event(ev, time.monotonic(),
                                                           self._team_ns()[0]))
        # an abort taken: the trial is dropped (the robot drives back, then says ready)
        if ev is not None and ev.event == ms.ABORT and core.answers_abort():
            self._say_ready(core.iteration + 1, "idle", core.shift())

    # ------------------------------------------------------------------ the tick
    def _on_tick(self) -> None:
        wall = self._wall_ns()
        team, how = self._team_ns()
        tick = self.core.tick(time.monotonic(), wall, team)
        if tick.true_path is not None and self.true_pub is not None:
            # before the last sample's pose, as the simulator: the robots finish the trial
            # on it, and a monitor that stops the run after their last word has this
            poses, stamps = tick.true_path
            self.true_pub.publish(ms.wire.path_bytes(np.asarray(poses), stamps,
                                                     ms.WORLD_FRAME))
        if tick.sample is not None:
            ns, pose = tick.sample
            self.sampled_on[how] += 1  # on the leader's time as estimated, or not
            if self.truth is not None and len(self.sample_lags) < 100_000:
                self.sample_lags.append((self.truth.true(wall) - ns) / 1e6)
            self.pose_pub.publish(ms.pose_to_msg(pose, ns, ms.WORLD_FRAME))
        if tick.whereabouts is not None and self.where_pub is not None:
            # stamped when the pose came, not at the tick (the others' speed estimates)
            self.where_pub.publish(ms.pose_to_msg(
                tick.whereabouts, wall - int(tick.whereabouts_age * 1e9), ms.WORLD_FRAME))
        if tick.returned is not None:
            self._returned(tick.returned)
        if tick.cmd is not None:
            self._send(tick.cmd, wall)

    def _send(self, cmd: tuple[float, float], stamp_ns: int) -> None:
        """Publish the driver's command, stamped ``stamp_ns`` (the wall time the bridge's
        limits held it at); none while a managed bridge is not active."""
        if not self.active:
            return
        self.drv_pub.publish(ms.driver_twist(cmd[0], cmd[1], self.stamped, stamp_ns))

    def _returned(self, r: Returned) -> None:
        if not r.reached:
            self.get_logger().error(
                f"return to the initial pose timed out after {r.seconds:.1f} s: "
                f"{math.hypot(r.shift[0], r.shift[1]):.3f} m, "
                f"{math.degrees(r.shift[2]):.1f} deg off; trial {r.trial} starts from there "
                f"(check the robot's path)")
        self._say_ready(r.trial, "reached" if r.reached else "timeout", r.shift)

    def _say_ready(self, trial: int, how: str, shift: tuple[float, float, float]) -> None:
        self.core.said_ready(trial, shift)
        d = Ready(self.name, trial, self.boot, self.follower.seen, run=self.run_id).to_json()
        d.update({"initial_shift": list(shift), "return": how})
        self.ready_pub.publish(ms.json_to_msg(d))
        self.publish_diagnostics(trial - 1)

    def destroy_node(self) -> None:
        """Stop the robot on the way out (Ctrl-C, a failed run)."""
        if self.configured and hasattr(self, "drv_pub"):
            try:
                self._send(self.core.stop(time.monotonic()), self._wall_ns())
            except Exception:  # noqa: BLE001 - the context may already be shut down
                pass
        super().destroy_node()

    def publish_diagnostics(self, trial: int) -> None:
        d: dict[str, Any] = {"node": self.name, "trial": trial, "driver": self.driver,
                             **self.core.report()}
        if self.clocks is not None:
            # the samples taken on the leader's time by a converged estimate, an estimate
            # not yet converged, or the robot's own clock
            d["clock"] = {**self.clocks.report(), "sampled_on": dict(self.sampled_on)}
            if self.sample_lags:  # emulated: when, in true time, after the leader's instant
                lag = np.array(self.sample_lags)
                d["clock"]["sample_lag_ms"] = {
                    "p50": round(float(np.median(lag)), 3), "min": round(float(lag.min()), 3),
                    "max": round(float(lag.max()), 3), "n": int(lag.size)}
        d.update(self.drops.as_dict())
        self.diag_pub.publish(ms.diagnostics_to_msg(
            d, self.get_clock().now().nanoseconds, self.cfg.scenario.dt,
            self.cfg.scenario.samples, ms.robot_name(self.id)))


def main(args: list[str] | None = None) -> int:
    parser = node_parser("formation-ilc-bridge", __doc__)

    def build(ns: Any, argv: list[str]) -> list[Node]:
        return [robot_node_from_args(BridgeNode, argv, "formation-ilc-bridge", "bridge")]

    return spin_main(build, parser, args)


if __name__ == "__main__":
    sys.exit(main())
