"""The hardware bridge's logic, free of ROS: limits, watchdog, odometry, return to the start.

The bridge node (``formation_ilc.nodes.pioneer_bridge``) keeps the plant contract for one
robot on top of a Pioneer driver. Everything it decides is here:

* ``CommandLimits.clamp``: the robot node's (v, omega) clamped to the base's limits;
  ``bridge_limits``: a bridge's speed and acceleration limits from its base (a preset of
  ``formation_ilc.config.bases``, or a Pioneer driver) and its parameters; with
  acceleration limits every command to the driver, in trials and returns alike, goes
  through a ``core.limits.RateLimiter`` on the command's own stamp;
* ``Watchdog``: a zero command once the robot node has been silent longer than a timeout;
* ``compose`` / ``odom_to_world``: the driver's odometry starts where the robot was placed,
  so a world pose is the initial world pose composed with the odometry pose;
* ``ReturnController``: point stabilisation of a unicycle to a goal pose in polar
  coordinates (Astolfi 1999; Aicardi et al. 1995; the form of Siegwart & Nourbakhsh,
  "Introduction to Autonomous Mobile Robots", sec. 3.6.2.4), with a tolerance and a
  timeout, driving backwards when the goal is behind; with a safety filter in the run, its
  command goes through the filter of the trials (``core.safety.filter_command``) against
  the other robots' whereabouts, which every bridge publishes between trials;
* ``initial_shift``: the achieved initial-state shift (b_xi0 of Assumption 2) of a trial;
* ``Bridge``: the bridge's state machine (idle -> trial -> return -> idle), one call per
  event with the time it happened: the leader's start and abort (taken by
  ``schedule.Follower``, with the agreed wall-clock start checked), the robot node's
  commands, the driver's odometry, and the control tick, which says what to publish (the
  pose of a sample due on the wall clock, the driver's command) and when a return ends
  (the node then says ready).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from formation_ilc.config.bases import base_preset, with_given
from formation_ilc.config.runconfig import RunConfig
from formation_ilc.config.safety import SafetySettings
from formation_ilc.core.clock import Rejected
from formation_ilc.core.limits import Limits, RateLimiter
from formation_ilc.core.safety import (
    CHANGED,
    INFEASIBLE,
    OTHER_FIELDS,
    PARAMS,
    SafetySpec,
    filter_command,
    motion,
)
from formation_ilc.model.simulate import Problem
from formation_ilc.protocol.schedule import ABORT, Follower, TrialEvent
from formation_ilc.protocol.wallclock import WallSchedule

__all__ = ["CommandLimits", "Watchdog", "compose", "odom_to_world", "odom_origin", "wrap",
           "ReturnController", "ReturnStatus", "initial_shift", "PIONEER_V_MAX",
           "PIONEER_OMEGA_MAX", "Bridge", "BridgeTick", "Returned", "IDLE", "TRIAL", "RETURN",
           "bridge_limits", "WHEREABOUTS_PERIOD", "PEER_SILENCE", "return_filter"]

# A Pioneer driver's limits: the p3dx row of the one limits table (config.bases): |v| <=
# 0.75 m/s, |omega| <= 100 deg/s, well inside the robot's 1.2 m/s and 300 deg/s (the
# drivers' own defaults are of that order; paper-triangle3 needs at most ~0.5 m/s)
PIONEER_V_MAX = base_preset("p3dx").limits.v_max            # [m/s]
PIONEER_OMEGA_MAX = base_preset("p3dx").limits.omega_max    # [rad/s]

Pose = tuple[float, float, float]
#: scratch row of ``core.safety.motion``
_MOTION = np.zeros((1, OTHER_FIELDS))


def bridge_limits(base: str | None, given: Mapping[str, float] | None = None) -> Limits:
    """The limits a bridge holds: its base preset's (``base``; None: a Pioneer driver's
    PIONEER_V_MAX and PIONEER_OMEGA_MAX, no acceleration limit), then every value of
    ``given`` > 0 (``config.bases.LIMIT_KEYS``, in the parameters' units: m/s, deg/s,
    m/s^2, deg/s^2). ValueError for an unknown preset or a bad value."""
    default = (base_preset(base).limits if base else Limits(PIONEER_V_MAX, PIONEER_OMEGA_MAX))
    return with_given(default, given or {})


def wrap(a: float) -> float:
    """Angle in (-pi, pi]."""
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))


@dataclass(frozen=True)
class CommandLimits:
    """Velocity limits of the base [m/s, rad/s]; both must be positive."""

    v_max: float = PIONEER_V_MAX
    omega_max: float = PIONEER_OMEGA_MAX

    def __post_init__(self) -> None:
        if not (self.v_max > 0 and self.omega_max > 0
                and math.isfinite(self.v_max) and math.isfinite(self.omega_max)):
            raise ValueError(f"command limits must be positive and finite, got v_max "
                             f"{self.v_max}, omega_max {self.omega_max}")

    def clamp(self, v: float, omega: float) -> tuple[float, float, bool]:
        """(v, omega) within the limits, and whether anything was clipped. A non-finite
        input is a zero command (clipped)."""
        if not (math.isfinite(v) and math.isfinite(omega)):
            return 0.0, 0.0, True
        cv = max(-self.v_max, min(self.v_max, v))
        cw = max(-self.omega_max, min(self.omega_max, omega))
        return cv, cw, (cv != v or cw != omega)


class Watchdog:
    """A command holds for ``timeout`` seconds after it arrived; then the command is zero."""

    def __init__(self, timeout: float):
        if not timeout > 0:
            raise ValueError(f"watchdog timeout must be positive, got {timeout}")
        self.timeout = timeout
        self.last: float | None = None
        self.expired_count = 0
        self._expired = True

    def feed(self, now: float) -> None:
        self.last = now
        self._expired = False

    def expired(self, now: float) -> bool:
        """True once the last command is older than the timeout (and before any command);
        each silence is counted once in ``expired_count``."""
        if self.last is None or now - self.last > self.timeout:
            if not self._expired:
                self.expired_count += 1
            self._expired = True
            return True
        return False


def compose(a: Pose, b: Pose) -> Pose:
    """Pose ``b`` (given in the frame of pose ``a``) in ``a``'s parent frame (SE(2))."""
    x, y, th = a
    c, s = math.cos(th), math.sin(th)
    return (x + c * b[0] - s * b[1], y + s * b[0] + c * b[1], th + b[2])


def odom_to_world(initial: Pose, odom: Pose) -> Pose:
    """The world pose of a robot whose odometry (starting at 0 where it was placed) reads
    ``odom``, placed at ``initial`` in the world frame."""
    return compose(initial, odom)


def odom_origin(world: Pose, odom: Pose) -> Pose:
    """Where the odometry's origin lies in the world frame when the robot is at ``world``
    and its odometry reads ``odom``: the T with ``compose(T, odom) == world`` (the
    ``map -> odom`` frame a located robot's pose and its odometry give, REP-105)."""
    th = world[2] - odom[2]
    c, s = math.cos(th), math.sin(th)
    return (world[0] - (c * odom[0] - s * odom[1]), world[1] - (s * odom[0] + c * odom[1]), th)


def initial_shift(achieved: Pose, desired: Pose) -> Pose:
    """b_xi0 of Assumption 2: the achieved start minus the desired one (heading wrapped)."""
    return (achieved[0] - desired[0], achieved[1] - desired[1],
            wrap(achieved[2] - desired[2]))


@dataclass(frozen=True)
class ReturnStatus:
    """What the return controller says: a command, and whether it is done (``reached`` or
    ``timed_out``); ``error`` is the pose error (rho [m], heading [rad])."""

    v: float
    omega: float
    reached: bool
    timed_out: bool
    rho: float
    heading_error: float

    @property
    def done(self) -> bool:
        return self.reached or self.timed_out


class ReturnController:
    """Drive a unicycle to ``goal`` (world pose) from wherever it is.

    Polar coordinates of the goal seen from the robot: rho (distance), alpha (bearing of
    the goal from the heading), beta = -theta - alpha + theta_goal; the law
    v = k_rho rho, omega = k_alpha alpha + k_beta beta is locally exponentially stable for
    k_rho > 0, k_beta < 0, k_alpha - k_rho > 0 (Siegwart & Nourbakhsh, eq. 3.96). With the
    goal behind (|alpha| > pi/2) it drives backwards (the same law on the reversed heading).
    Inside ``tol_pos`` it turns in place to the goal heading; it is done when within
    ``tol_pos`` and ``tol_heading``, or after ``timeout`` seconds (reported, never hidden).
    Commands are clamped to ``limits``.
    """

    def __init__(self, goal: Pose, limits: CommandLimits, *, tol_pos: float = 0.02,
                 tol_heading: float = math.radians(2.0), timeout: float = 60.0,
                 k_rho: float = 0.6, k_alpha: float = 1.6, k_beta: float = -0.5,
                 k_turn: float = 1.5):
        if not (k_rho > 0 and k_beta < 0 and k_alpha - k_rho > 0):
            raise ValueError("gains: k_rho > 0, k_beta < 0 and k_alpha > k_rho are required")
        if not (tol_pos > 0 and tol_heading > 0 and timeout > 0):
            raise ValueError("tolerances and timeout must be positive")
        self.goal = goal
        self.limits = limits
        self.tol_pos, self.tol_heading, self.timeout = tol_pos, tol_heading, timeout
        self.k_rho, self.k_alpha, self.k_beta, self.k_turn = k_rho, k_alpha, k_beta, k_turn
        self.t0: float | None = None

    def step(self, pose: Pose, now: float, stale: bool = False) -> ReturnStatus:
        """The command at ``now`` [s] for the robot at ``pose``. ``stale``: the pose is
        old (odometry stopped): stop and wait (the timeout still runs)."""
        if self.t0 is None:
            self.t0 = now
        gx, gy, gth = self.goal
        x, y, th = pose
        dx, dy = gx - x, gy - y
        rho = math.hypot(dx, dy)
        dth = wrap(gth - th)
        if rho <= self.tol_pos and abs(dth) <= self.tol_heading:
            return ReturnStatus(0.0, 0.0, True, False, rho, dth)
        if now - self.t0 > self.timeout:
            return ReturnStatus(0.0, 0.0, False, True, rho, dth)
        if stale:
            return ReturnStatus(0.0, 0.0, False, False, rho, dth)
        if rho <= self.tol_pos:
            v, w = 0.0, self.k_turn * dth
        else:
            alpha = wrap(math.atan2(dy, dx) - th)
            sign = 1.0
            if abs(alpha) > math.pi / 2:  # goal behind: drive backwards
                sign = -1.0
                alpha = wrap(alpha + math.pi)
            # beta on the reversed heading is the same expression (both headings + pi)
            beta = wrap(gth - th - alpha)
            v = sign * self.k_rho * rho
            w = self.k_alpha * alpha + self.k_beta * beta
        cv, cw, _ = self.limits.clamp(v, w)
        return ReturnStatus(cv, cw, False, False, rho, dth)


# ---------------------------------------------------------------------- the state machine

#: the bridge's phases: between trials, sampling a trial, driving back to the start
IDLE, TRIAL, RETURN = "idle", "trial", "return"
Command = tuple[float, float]


@dataclass(frozen=True)
class Returned:
    """A return to the initial pose ended (``reached``, else timed out) after ``seconds``
    [s] with initial shift ``shift``: the bridge is ready for trial ``trial``."""

    trial: int
    reached: bool
    shift: Pose
    seconds: float


@dataclass(frozen=True)
class BridgeTick:
    """What a control tick makes the bridge do, in this order: publish the pose of a sample
    (its label [ns], the world pose), end a return (say ready), send a command (v [m/s],
    omega [rad/s]) to the driver. None: nothing of that kind."""

    sample: tuple[int, Pose] | None = None
    returned: Returned | None = None
    cmd: Command | None = None
    #: at a trial's last sample, with ``truth``: the trial's true poses (T+1) and their
    #: labels [ns], published before the sample's pose
    true_path: tuple[list[Pose], list[int]] | None = None
    #: between trials, with a safety filter: the robot's world pose, for the other
    #: bridges' returns (every ``WHEREABOUTS_PERIOD``)
    whereabouts: Pose | None = None
    #: [s] how long ago that pose came (the odometry's or the located pose's arrival):
    #: it is stamped then, so that the others' speed estimates divide its motion by the
    #: time it took, not by the ticks', which beat against the pose's own rate
    whereabouts_age: float = 0.0


#: how often a bridge says where its robot is between trials [s]
WHEREABOUTS_PERIOD = 0.05
#: a robot not heard for this long between trials is not filtered against [s]
PEER_SILENCE = 1.0


def return_filter(settings: SafetySettings, tick: float) -> SafetySpec:
    """The filter of a run's returns (``settings``: the run's ``config.safety``) for a
    bridge that decides a command every ``tick`` [s]: the trials' filter at that sample
    time, with the other robots' motion read from whereabouts WHEREABOUTS_PERIOD apart
    (so its estimate lags by half that, which the filter widens by)."""
    from formation_ilc.model.safety import spec_of

    spec = spec_of(settings, tick)
    return replace(spec, window=math.ceil(WHEREABOUTS_PERIOD / tick - 1e-9) + 1)


class Bridge:
    """Robot ``robot`` (1-based) of run ``cfg`` (mode wallclock, links direct) on its base.

    name : the node's name (in error messages). initial : where the robot is placed (world
    pose); None: the scenario's desired start of the robot. limits : the base's velocity
    limits. rate : the base's speed and acceleration limits: every command to the driver
    goes through a RateLimiter of them (None: the speed clamp only, as for the Pioneer
    drivers). cmd_timeout : [s] a zero command once the robot node is silent that long (0:
    2.5 dT). period : [s] the command is sent again at least this often (the driver's own
    watchdog). tol : return tolerances (position [m], heading [rad]) and timeout [s].
    truth : the base reports its true pose (``on_truth``; a simulated base): each sample
    keeps the newest, a sample the schedule skipped the one before it (or after it, at the
    start), and the trial's last tick gives them all (``BridgeTick.true_path``).
    safety : the run's safety filter, for a sample time of the control tick (its ``dt``:
    each tick's command is held until the next). With it the bridge says where its robot
    is between trials (``BridgeTick.whereabouts``) and filters its return's commands
    against the other robots' whereabouts (``on_peer``), as a robot node filters its
    trial's: no two returning robots drive into each other, or into one that already
    stands at its start. None: the return controller alone.

    Times: ``now`` [s] on a monotonic clock, ``now_wall_ns`` [ns] on the robot's wall
    clock; a command sent at ``now_wall_ns`` is stamped with it, and the acceleration
    limits hold on those stamps (a reader of TwistStamped sees every change within a_max
    times the stamps' difference, whatever the jitter of the caller). ``team_ns`` [ns]:
    the team's time, the leader's clock that the agreed start refers to, as this robot
    estimates it (``protocol.timesync``); samples are due and starts checked on it (None:
    the robot's wall clock is taken for it, as when the clocks are synchronised).
    """

    def __init__(self, cfg: RunConfig, robot: int, *, name: str, initial: Pose | None = None,
                 limits: CommandLimits | None = None, rate: Limits | None = None,
                 cmd_timeout: float = 0.0,
                 period: float = 0.05, tol: tuple[float, float, float] = (
                     0.02, math.radians(2.0), 60.0), truth: bool = False,
                 safety: SafetySpec | None = None, located: bool = False):
        if cfg.mode != "wallclock" or cfg.links != "direct":
            raise ValueError(f"{name}: a real robot runs wall-clock trials with direct "
                             f"links (mode wallclock, links direct), got mode {cfg.mode}, "
                             f"links {cfg.links}")
        pb = Problem.from_scenario(cfg.scenario)
        if robot > pb.n:
            raise ValueError(f"{name}: the scenario has robots 1..{pb.n}")
        if initial is None:
            x, y, th = (float(v) for v in pb.eta_d[robot - 1, 0])
            initial = (x, y, th)
        self.initial: Pose = initial
        self.limits = limits or CommandLimits()
        self.rate = None if rate is None else RateLimiter(rate)
        self.clock, self.T, self.period, self.tol = cfg.clock, pb.samples, period, tol
        dt = cfg.scenario.dt
        self.follower = Follower(cfg.run_id, wall_trial_ns=self.T * self.clock.dt_ns,
                                 clock=self.clock)
        self.watchdog = Watchdog(cmd_timeout if cmd_timeout > 0 else 2.5 * dt)
        #: odometry older than this [s] is stale: counted in trials, a stop in returns
        self.odom_limit = max(0.5, 2.0 * dt)
        #: the robot's pose: the driver's odometry (composed with ``initial``), or, where
        #: the robot is ``located``, a world pose from outside (motion capture, a
        #: localiser, the physics bases' ground truth: ``on_located``), with when it came
        self.located = located
        self.odom: Pose | None = None
        self.odom_time = 0.0
        self.phase = IDLE
        self.schedule: WallSchedule | None = None
        self.returner: ReturnController | None = None
        self.return_t0 = 0.0
        self.robot_cmd: Command = (0.0, 0.0)
        self.out_cmd: Command = (0.0, 0.0)
        self.last_out = 0.0
        self.counts = {"missed": 0, "clipped": 0, "clipped_accel": 0, "watchdog_zero": 0,
                       "return_timeouts": 0, "stale_odometry": 0, "estops": 0}
        self.tilt_max = 0.0    # [rad] the largest tilt of the odometry taken
        self.shifts: dict[str, list[float]] = {}
        self.returns: dict[str, dict[str, Any]] = {}
        self.ready_sent = -1   # the trial of the last ready (-1: none yet)
        #: the base's newest true pose (with ``truth``), and the trial's at each sample
        self.wants_truth = truth
        self.truth: Pose | None = None
        self.trail: list[Pose | None] = []
        #: the return's filter, and what it knows of the other robots: by robot number,
        #: (the time it was heard [s, monotonic], its pose, its stamp [ns], its motion)
        self.safety = safety
        self._params = None if safety is None else safety.params()
        self.robot = robot
        self.peers: dict[int, tuple[float, Pose, int, tuple[float, float, float]]] = {}
        self._said_at = -math.inf   # when the whereabouts went out last
        if safety is not None:
            self.counts.update(return_filtered=0, return_infeasible=0)

    @property
    def k(self) -> int:
        """Slot of the current (or last) trial."""
        return self.follower.slot

    @property
    def iteration(self) -> int:
        return self.follower.trial

    def world(self) -> Pose:
        """The robot's world pose (after the first odometry, or the first located pose)."""
        assert self.odom is not None
        return self.odom if self.located else odom_to_world(self.initial, self.odom)

    def shift(self) -> Pose:
        """The initial shift the robot would start a trial from now."""
        return initial_shift(self.world(), self.initial)

    # ------------------------------------------------------------------ inputs
    def on_odom(self, pose: Pose, now: float, tilt: float = 0.0) -> None:
        """The driver's odometry pose (x [m], y [m], theta [rad]) at ``now``, its body
        tilted by ``tilt`` [rad] (a base's odometry read with its roll and pitch)."""
        self.tilt_max = max(self.tilt_max, tilt)
        if not self.located:
            self.odom = pose
            self.odom_time = now

    def on_located(self, pose: Pose, now: float) -> None:
        """The robot's world pose (x, y, theta) at ``now`` from outside the base: what the
        bridge samples, returns on and tells the others where it is ``located`` (else
        unused)."""
        if self.located:
            self.odom = pose
            self.odom_time = now

    def on_peer(self, robot: int, pose: Pose, stamp_ns: int, now: float) -> None:
        """Robot ``robot``'s whereabouts, stamped ``stamp_ns`` on its bridge's clock, heard
        at ``now`` [s]: its motion comes from its last two (their stamps' difference; the
        same clock), its age from when it was heard. An older or repeated stamp is not
        news."""
        if robot == self.robot or self.safety is None:
            return
        old = self.peers.get(robot)
        vel = (0.0, 0.0, 0.0)
        if old is not None:
            if stamp_ns <= old[2]:
                return
            scratch = _MOTION
            motion(pose[0], pose[1], pose[2], old[1][0], old[1][1], old[1][2],
                   (stamp_ns - old[2]) * 1e-9, scratch, 0)
            vel = (float(scratch[0, 3]), float(scratch[0, 4]), float(scratch[0, 5]))
        self.peers[robot] = (now, pose, stamp_ns, vel)

    def on_truth(self, pose: Pose) -> None:
        """The simulated base's true world pose, the newest (``truth``)."""
        self.truth = pose

    def on_cmd(self, u: tuple[float, float], now: float, now_wall_ns: int | None = None
               ) -> Command:
        """The robot node's command: clamped, it goes to the driver now (returned; stamp it
        ``now_wall_ns``). Rejected (unexpected) outside a trial: it would move the robot
        outside the protocol."""
        if self.phase != TRIAL:
            raise Rejected("unexpected", f"a command while {self.phase}")
        v, w, clipped = self.limits.clamp(float(u[0]), float(u[1]))
        self.counts["clipped"] += int(clipped)
        self.robot_cmd = (v, w)
        self.watchdog.feed(now)
        return self.send(self.robot_cmd, now, now_wall_ns)

    def on_event(self, ev: TrialEvent, now: float, now_wall_ns: int) -> TrialEvent | None:
        """The leader's event: the start or abort taken, or None (nothing to do); Rejected
        for a start the bridge must not obey (``schedule.Follower``, with its agreed
        start checked against ``now_wall_ns``, the team's time). An abort of the running
        trial stops the sampling and drives the robot back."""
        taken = self.follower.take(ev, idle=self.phase == IDLE, now_wall_ns=now_wall_ns)
        if taken is None:
            return None
        if taken.event == ABORT:
            if self.phase == TRIAL and taken.slot == self.k:
                self.schedule = None
                self._begin_return(now)
            return taken
        assert taken.start_wall_ns is not None  # checked by the follower
        self.schedule = WallSchedule(taken.start_wall_ns, self.clock.dt_ns, self.T)
        self.phase = TRIAL
        self.trail = [None] * (self.T + 1)
        return taken

    def answers_abort(self) -> bool:
        """Whether a ready answers an abort at once: idle, after its first ready (inside a
        trial or a return the ready comes once the robot is back)."""
        return self.phase == IDLE and self.ready_sent >= 0

    def said_ready(self, trial: int, shift: Pose) -> None:
        """The node said ready for ``trial`` from initial shift ``shift``."""
        self.shifts[str(trial)] = [float(x) for x in shift]
        self.ready_sent = trial
        self.follower.said_ready()

    # ------------------------------------------------------------------ the tick
    def tick(self, now: float, now_wall_ns: int, team_ns: int | None = None) -> BridgeTick:
        """The control tick: the sample due on the team's time, the return controller,
        the watchdog, and the command sent again at least every ``period``."""
        sample = None
        true_path = None
        if self.phase == TRIAL and self.schedule is not None:
            s = self.schedule.due(now_wall_ns if team_ns is None else team_ns)
            if s is not None:
                sample = self._sample(s, now)
                if sample is not None and self.wants_truth:
                    true_path = self._keep_truth(s)
        if self.phase == RETURN and self.returner is not None and self.odom is not None:
            stale = now - self.odom_time > self.odom_limit
            self.counts["stale_odometry"] += int(stale)
            st = self.returner.step(self.world(), now, stale)
            if st.done:
                returned = self._returned(st.reached, now)
                return BridgeTick(sample, returned, self.send((0.0, 0.0), now, now_wall_ns),
                                  true_path, *self._whereabouts(now))
            cmd = (st.v, st.omega) if stale else self._safe((st.v, st.omega), now)
            return BridgeTick(sample, None, self.send(cmd, now, now_wall_ns), true_path,
                              *self._whereabouts(now))
        cmd = self.robot_cmd
        if self.watchdog.expired(now):
            if self.out_cmd != (0.0, 0.0) and self.phase == TRIAL:
                self.counts["watchdog_zero"] += 1
            cmd = (0.0, 0.0)
        where, age = self._whereabouts(now)
        if cmd != self.out_cmd or now - self.last_out >= self.period:
            return BridgeTick(sample, None, self.send(cmd, now, now_wall_ns), true_path,
                              where, age)
        return BridgeTick(sample, true_path=true_path, whereabouts=where, whereabouts_age=age)

    def _whereabouts(self, now: float) -> tuple[Pose | None, float]:
        """The robot's world pose to say now (with a filter, between trials, every
        WHEREABOUTS_PERIOD), or None; and how long ago it came [s]."""
        if (self.safety is None or self.phase == TRIAL or self.odom is None
                or now - self._said_at < WHEREABOUTS_PERIOD):
            return None, 0.0
        self._said_at = now
        return self.world(), max(0.0, now - self.odom_time)

    def _safe(self, cmd: Command, now: float) -> Command:
        """The return controller's ``cmd`` through the safety filter (its ``dt``: the
        tick, how long a command is held before the next one), against every robot heard
        between trials. A robot never heard, or not for PEER_SILENCE (its bridge stopped:
        a pose that old would widen into a wall), is not filtered against (as in a
        trial)."""
        params = self._params
        if params is None:
            return cmd
        x, y, th = self.world()
        heard = [p for p in self.peers.values() if now - p[0] <= PEER_SILENCE]
        others = np.zeros((max(len(heard), 1), OTHER_FIELDS))
        ages = np.zeros(len(others))
        for m, (at, pose, _, vel) in enumerate(heard):
            others[m, :3] = pose
            others[m, 3:6] = vel
            others[m, 7] = params[PARAMS.index("pose_error")]  # raw poses: the fixed widening
            ages[m] = max(0.0, now - at)
        out = np.zeros(2)
        flags = filter_command(cmd[0], cmd[1], x, y, th, self.out_cmd[0], self.out_cmd[1],
                               others, ages, len(heard), params, out)
        self.counts["return_filtered"] += int(bool(flags & CHANGED))
        self.counts["return_infeasible"] += int(bool(flags & INFEASIBLE))
        return float(out[0]), float(out[1])

    #: the e-stop is latched: every command to the driver is zero (``estop``)
    estopped = False

    def estop(self, on: bool, now: float) -> Command | None:
        """The e-stop latched (``on``) or released. Latched: the zero command to send now
        (no limit holds it back), and zero for every command after, the robot's, the
        return controller's and the repeats alike, until released (None: nothing to
        send)."""
        was, self.estopped = self.estopped, bool(on)
        if on:
            self.counts["estops"] += int(not was)
            return self.stop(now)
        return None

    def stop(self, now: float) -> Command:
        """The zero command, to send on the way out (no limit holds it back)."""
        self.out_cmd, self.last_out = (0.0, 0.0), now
        return self.out_cmd

    def send(self, cmd: Command, now: float, now_wall_ns: int | None = None) -> Command:
        """``cmd`` as it goes to the driver at ``now``, stamped ``now_wall_ns`` (None: the
        stamps are ``now``): through the acceleration limits, if any. In a trial, a command
        they held back is counted (``clipped_accel``); a return starts from the trial's
        last speed and is not. Zero while the e-stop is latched."""
        if self.estopped:
            return self.stop(now)
        if self.rate is not None:
            before = self.rate.clipped_accel
            stamp = now if now_wall_ns is None else now_wall_ns * 1e-9
            v, w, _ = self.rate.limit(cmd[0], cmd[1], stamp)
            if self.phase == TRIAL:
                self.counts["clipped_accel"] += self.rate.clipped_accel - before
            cmd = (v, w)
        self.out_cmd = cmd
        self.last_out = now
        return cmd

    def _sample(self, s: int, now: float) -> tuple[int, Pose] | None:
        if self.odom is None:
            return None
        if now - self.odom_time > self.odom_limit:
            self.counts["stale_odometry"] += 1
        out = (self.clock.stamp_ns(self.k, s), self.world())
        if s == self.T:
            assert self.schedule is not None
            self.counts["missed"] += self.schedule.skipped
            self.schedule = None
            self._begin_return(now)
        return out

    def _keep_truth(self, s: int) -> tuple[list[Pose], list[int]] | None:
        """Keep the newest true pose as sample ``s``'s; at the last sample, the trial's
        true poses (a skipped sample's: the one before it, or after it at the start) and
        their labels."""
        self.trail[s] = self.truth
        if s < self.T:
            return None
        last = next((p for p in self.trail if p is not None), None)
        if last is None:  # no true pose came in the whole trial (the ready waits for one)
            return None
        poses: list[Pose] = []
        for p in self.trail:
            last = p if p is not None else last
            poses.append(last)
        return poses, [self.clock.stamp_ns(self.k, i) for i in range(self.T + 1)]

    def _begin_return(self, now: float) -> None:
        self.robot_cmd = (0.0, 0.0)
        self.phase = RETURN
        self.returner = ReturnController(self.initial, self.limits, tol_pos=self.tol[0],
                                         tol_heading=self.tol[1], timeout=self.tol[2])
        self.return_t0 = now

    def _returned(self, reached: bool, now: float) -> Returned:
        self.phase = IDLE
        self.returner = None
        shift = self.shift()
        secs = now - self.return_t0
        if not reached:
            self.counts["return_timeouts"] += 1
        self.returns[str(self.iteration + 1)] = {"reached": reached, "seconds": round(secs, 3)}
        return Returned(self.iteration + 1, reached, shift, secs)

    def report(self) -> dict[str, Any]:
        """Diagnostics: the initial shift of each trial, each return, and the counters."""
        limits = (self.rate.limits if self.rate is not None
                  else Limits(self.limits.v_max, self.limits.omega_max))
        return {"initial_shifts": self.shifts, "returns": self.returns,
                "limits": list(limits.as_tuple()), "tilt_max_deg": math.degrees(self.tilt_max),
                **self.counts}
