"""The physics plants, free of ROS: the PyBullet world behind the plant contract, and
behind a base's interface.

``PhysicsPlant`` is ``protocol.plant.KinematicPlant`` (the same schedule, lockstep and
realtime timing, re-sends and report) with the rigid-body world of
``formation_ilc.model.physics`` in place of eq. (1): at a trial's start the robots are
placed at their desired start plus the scenario's initial shift, each sample's commands
are held for dT while the engine runs its substeps. The measured pose is the engine's
ground truth (a motion-capture stand-in) or the robot's wheel odometry, plus the scenario's
output noise; the true trajectory is always the ground truth. The input disturbance is not
applied (the engine's own dynamics are the plant's disturbance). Its trial report adds the
contacts between robots, the largest tilt and the odometry's drift from the truth, for the
trial and for every trial so far. ``robot_sim.physics_node`` is the thin node around it.

Contacts are acted on (``ON_CONTACT``): the first contact between two robots in a trial, or
a robot tilted past ``tilt_limit``, is a ``ContactEvent`` the node reports at once. With
``stop`` (the default) the plant holds every robot's command at zero for the rest of the
trial and asks the leader to abort it (the same iteration runs again), at most ``retries``
times per iteration, after which the run ends (``give_up``); ``abort`` stops the robots and
ends the run at once; ``continue`` reports and goes on.

``BaseRobots`` is the same world in wall time with each robot exposed as a base exposes
itself (``robot_sim.physics_base``): the newest command of each robot is held (zero once
older than the base's own command time-out), odometry in the frame of the robot's start
pose with the body's real roll and pitch, and what the robots were asked: the largest
|v|, |omega| and, between consecutive commands (by their stamps), |dv/dt|, |domega/dt|.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.option_table import ON_CONTACT, TILT_RANGE, default, option
from formation_ilc.config.params import Param
from formation_ilc.config.runconfig import RunConfig
from formation_ilc.core.names import robot_name
from formation_ilc.model.physics import (
    DEFAULT_RATE,
    POSE_SOURCES,
    PhysicsWorld,
    RobotModel,
    robot_model,
)
from formation_ilc.protocol.plant import KinematicPlant
from formation_ilc.protocol.schedule import ABORT, TrialEvent

__all__ = ["PhysicsPlant", "BaseRobots", "BaseOdometry", "physics_available", "ON_CONTACT",
           "ContactEvent", "ContactWatch", "PHASES", "BaseTrials", "contact_then",
           "CONTACT_PARAMS", "TILT_RANGE", "TILT_LIMIT"]

#: the tilt limit [rad] a plant takes unless told (the option table's, in deg there)
TILT_LIMIT = math.radians(default("tilt_limit"))

#: what a plant with bodies does about contacts: the physics plant's and the physics bases'
#: parameters
CONTACT_PARAMS: tuple[Param, ...] = (
    Param("on_contact", default("on_contact"),
          "when robots touch (or one tips past tilt_limit): stop them and run the trial "
          "again (at most contact_retries times), stop them and end the run, or report "
          "and go on", choices=ON_CONTACT),
    Param("contact_retries", default("contact_retries"),
          "how often one trial runs again after a contact", lo=option("contact_retries").lo,
          hi=option("contact_retries").hi),
    Param("tilt_limit", default("tilt_limit"), "a robot tilted past this counts as a "
          "contact", option("tilt_limit").unit, lo=TILT_RANGE[0], hi=TILT_RANGE[1]),
)

#: where a contact happened: in a trial, or on the way back to the start poses (the bases'
#: returns, which the bridges drive)
PHASES = ("trial", "return")


@dataclass(frozen=True)
class ContactEvent:
    """Robots touched (or tipped) in a trial or its return: the iteration and slot, the
    sample (in a trial; -1 in a return), the pairs new to this trial or return (i, j
    1-based, seconds in contact, deepest penetration [m]), the largest tilt of the robots
    newly past the limit [rad] (0: none) and its robot (1-based, 0: none), and what the
    plant does about it (``action``: 'stop', 'abort', 'continue' or 'give_up': the retries
    are spent). ``acts``: the first event of its trial or return, the one acted on; later
    ones are said and counted under the same action. ``phase``: PHASES; ``seconds``: into
    the return. ``n``: the plant's count of events so far (1-based)."""

    trial: int
    slot: int
    sample: int
    pairs: tuple[tuple[int, int, float, float], ...]
    tilt: float
    tilted: int
    action: str
    phase: str = "trial"
    seconds: float = 0.0
    acts: bool = True
    n: int = 1

    def line(self, dt: float, tilt_limit: float) -> str:
        what = [f"robots {i} and {j} in contact ({depth * 100:.1f} cm deep)"
                for i, j, _, depth in self.pairs]
        if self.tilted and self.tilt > tilt_limit:
            what.append(f"robot {self.tilted} tilted {math.degrees(self.tilt):.1f} deg")
        when = (f"t = {self.sample * dt:.1f} s" if self.phase == "trial" else
                f"{self.seconds:.1f} s into the return to the start poses")
        return f"trial {self.trial} (slot {self.slot}), {when}: {'; '.join(what)}"

    def to_json(self, dt: float, tilt_limit: float) -> dict[str, Any]:
        """The diagnostics' ``contact`` field (the console says ``line``)."""
        return {"slot": self.slot, "sample": self.sample, "line": self.line(dt, tilt_limit),
                "action": self.action, "pairs": [list(p) for p in self.pairs],
                "tilt": self.tilt, "phase": self.phase, "n": self.n, "acts": self.acts}


class ContactWatch:
    """Which contacts and tilts of a plant with bodies are news, and what the plant does.

    Every pair that comes into contact and every robot that tips past ``tilt_limit`` [rad]
    in a trial (or a return) is an event, said once per trial or return (``window`` starts
    one). The first event of a window decides (``on_contact``, ON_CONTACT): ``stop`` stops
    the robots and runs the trial again, at most ``retries`` times per iteration, then
    ``give_up`` ends the run; ``abort`` ends it; ``continue`` goes on. A return is not run
    again: ``stop`` there ends the run as ``abort`` does. ValueError for a bad setting."""

    def __init__(self, on_contact: str = default("on_contact"),
                 retries: int = default("contact_retries"), tilt_limit: float = TILT_LIMIT):
        if on_contact not in ON_CONTACT:
            raise ValueError(f"parameter on_contact: one of {', '.join(ON_CONTACT)}, got "
                             f"{on_contact!r}")
        if retries < 0:
            raise ValueError(f"parameter contact_retries: >= 0, got {retries}")
        if not 0 < tilt_limit <= math.pi:
            raise ValueError(f"parameter tilt_limit: in (0, 180] deg, got "
                             f"{math.degrees(tilt_limit):g}")
        self.on_contact, self.retries, self.tilt_limit = on_contact, retries, tilt_limit
        #: re-runs each iteration had
        self.reruns: dict[int, int] = {}
        #: events said, in all
        self.events = 0
        self.window()

    def window(self, carry: bool = False) -> None:
        """A trial or a return begins: its contacts are news again; ``carry``: except
        those said in the window before (a return that begins with robots still touching
        continues the trial's contact, it is not a new one)."""
        if not carry or not hasattr(self, "said_pairs"):
            self.said_pairs: set[tuple[int, int]] = set()
            self.said_tilted: set[int] = set()
        #: the window's first event (the one acted on), or None
        self.first: ContactEvent | None = None

    def check(self, trial: int, slot: int, sample: int,
              pairs: list[tuple[int, int, float, float]], tilts: NDArray[np.float64],
              phase: str = "trial", seconds: float = 0.0) -> ContactEvent | None:
        """The event of what is new in ``pairs`` (the window's pairs that touched) and
        ``tilts`` (each robot's tilt now), or None."""
        new = tuple(p for p in pairs if (p[0], p[1]) not in self.said_pairs)
        over = [r for r in range(len(tilts))
                if tilts[r] > self.tilt_limit and r + 1 not in self.said_tilted]
        if not new and not over:
            return None
        self.said_pairs.update((p[0], p[1]) for p in new)
        self.said_tilted.update(r + 1 for r in over)
        first = self.first is None
        if self.first is None:
            action = self.on_contact
            if action == "stop" and phase == "return":
                action = "abort"  # nothing to run again
            if action == "stop":
                self.reruns[trial] = self.reruns.get(trial, 0) + 1
                if self.reruns[trial] > self.retries:
                    action = "give_up"
        else:
            action = self.first.action
        worst = max(over, key=lambda r: tilts[r]) if over else -1
        self.events += 1
        ev = ContactEvent(trial, slot, sample, new, float(tilts[worst]) if over else 0.0,
                          worst + 1, action, phase, seconds, first, self.events)
        if first:
            self.first = ev
        return ev


def contact_then(ev: ContactEvent, reruns: int, retries: int) -> str:
    """What the plant does about ``ev``, in words (its log)."""
    if not ev.acts:
        return ("going on (--on-contact continue)" if ev.action == "continue" else
                "the robots already stand")
    return {"stop": f"robots stopped; the trial runs again ({reruns} of {retries})",
            "continue": "going on (--on-contact continue)",
            "abort": ("robots stopped; ending the run (a return is not run again)"
                      if ev.phase == "return" else
                      "robots stopped; ending the run (--on-contact abort)"),
            "give_up": f"robots stopped; the trial touched again after {retries} re-runs: "
                       f"ending the run"}[ev.action]


def physics_available() -> str | None:
    """None if PyBullet can be imported; else the one line that says how to install it."""
    try:
        import pybullet  # noqa: F401
    except ImportError:
        return ("the physics plant needs PyBullet: pip install -c requirements.lock -e "
                "'.[physics]'")
    return None


class PhysicsPlant(KinematicPlant):
    """Every robot of run ``cfg`` in one PyBullet world of ``model`` ('p3dx', 'husky').

    pose : the measured pose's source (POSE_SOURCES). rate : engine steps per second.
    collide : robots collide (default) or pass through each other. ValueError for a
    value that is not one of these, or without PyBullet.
    """

    def __init__(self, cfg: RunConfig, model: str = "p3dx", *, pose: str = "truth",
                 rate: float = DEFAULT_RATE, collide: bool = True,
                 on_contact: str = default("on_contact"),
                 retries: int = default("contact_retries"), tilt_limit: float = TILT_LIMIT):
        missing = physics_available()
        if missing is not None:
            raise ValueError(missing)
        if pose not in POSE_SOURCES:
            raise ValueError(f"parameter pose: one of {', '.join(POSE_SOURCES)}, got {pose!r}")
        if not (rate > 0 and math.isfinite(rate)):
            raise ValueError(f"parameter rate: engine steps per second > 0, got {rate}")
        #: which contacts are news, what is done about them, the re-runs of each iteration
        self.watch = ContactWatch(on_contact, retries, tilt_limit)
        #: the trial's acting contact (None: none yet)
        self.contact: ContactEvent | None = None
        #: contact events not yet taken by the node (``take_contacts``)
        self.new_contacts: list[ContactEvent] = []
        robot: RobotModel = robot_model(model)
        super().__init__(cfg)
        self.pose_source = pose
        self.world = PhysicsWorld(robot, self.n, cfg.scenario.dt, rate=rate, collide=collide)
        self.tilt_max = 0.0
        self.drift = 0.0
        # per trial (iteration), for the run's summary: a latched report keeps only the last
        self.by_trial: dict[str, dict[str, Any]] = {
            "contacts_by_trial": {}, "tilt_by_trial": {}, "odometry_drift_by_trial": {}}

    def describe(self) -> str:
        w = self.world
        return (f"physics: {self.n} x {w.model.name}, {w.substeps} substeps of "
                f"{w.h * 1e3:.2f} ms per sample, pose from {self.pose_source}, robots "
                f"{'collide' if w.collide else 'pass through each other'}")

    def place(self) -> None:
        self.world.place(self.xi[:, 0])
        self.xi[:, 0] = self.world.truth()  # where it stands once settled on its wheels
        self.tilt_max = 0.0
        self.drift = 0.0
        self.contact = None
        self.new_contacts = []
        self.watch.window()

    def move(self, t: int) -> None:
        if self.contact is not None and self.contact.action != "continue":
            self.u[:, t] = 0.0  # the robots were stopped: they stand for the rest of it
        self.world.step(self.u[:, t])
        self.xi[:, t + 1] = self.world.truth()
        tilts = self.world.tilt()
        self.tilt_max = max(self.tilt_max, float(tilts.max()))
        ev = self.watch.check(self.iteration, self.k, t + 1, self.world.contact_pairs(), tilts)
        if ev is not None:
            self.new_contacts.append(ev)
            if ev.acts:
                self.contact = ev

    @property
    def held(self) -> bool:
        """The trial waits for the leader's abort: its robots touched and were stopped
        (``stop``), so no further sample goes out, its last one included (a sample after
        the contact would let the robots finish and learn from the trial the abort is to
        take back). The abort of its slot releases it (``on_event``)."""
        return self.contact is not None and self.contact.action == "stop"

    def on_event(self, ev: TrialEvent, now: float) -> TrialEvent | None:
        taken = super().on_event(ev, now)
        if (taken is not None and taken.event == ABORT and self.contact is not None
                and taken.slot == self.contact.slot):
            self.contact = None  # the trial it held is gone
        return taken

    def take_contacts(self) -> list[ContactEvent]:
        """This trial's contact events not yet taken (the node reports each once)."""
        out, self.new_contacts = self.new_contacts, []
        return out

    def measured(self, t: int) -> NDArray[np.float64]:
        odom = self.world.odom
        self.drift = max(self.drift, float(np.hypot(*(odom[:, :2] - self.xi[:, t, :2]).T)
                                           .max()))
        base = self.xi[:, t] if self.pose_source == "truth" else odom
        return base + self.noise[:, t]

    def plant_report(self) -> dict[str, Any]:
        k = str(self.iteration)
        contacts = self.world.contacts()
        if contacts:
            self.by_trial["contacts_by_trial"][k] = contacts
        self.by_trial["tilt_by_trial"][k] = self.tilt_max
        self.by_trial["odometry_drift_by_trial"][k] = self.drift
        return {"contacts": contacts, "tilt_max": self.tilt_max,
                "odometry_drift": self.drift, "pose_source": self.pose_source,
                "model": self.world.model.name, "substeps": self.world.substeps,
                "limited": self.world.limited,
                "contact_report": self.contact_report(),
                **self.by_trial}

    def contact_report(self) -> dict[str, Any]:
        """The trial's contacts for the metrics rows (``protocol.trialrows``): its slot
        and the pairs that touched (i, j, seconds, depth [m])."""
        return {"slot": self.k, "pairs": [list(p) for p in self.world.contact_pairs()]}

    def close(self) -> None:
        self.world.close()


# --------------------------------------------------------------------------- bases
#: a base's odometry: (x, y, yaw) in the frame of its start pose, (v, omega), and the
#: orientation quaternion (x, y, z, w) with the body's roll and pitch
BaseOdometry = tuple[tuple[float, float, float], tuple[float, float],
                     tuple[float, float, float, float]]


def _quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


class BaseRobots:
    """``starts`` (N, 3) robots of ``model`` stepped every ``tick`` [s] in wall time.

    ``command(i, v, omega, stamp, now)``: robot i's (0-based) newest command, its stamp [s]
    (the message's, or the arrival time for one without) and arrival ``now`` [s, a
    monotonic clock]; ``step(now)`` advances the world one tick and gives every robot's
    odometry; ``truth`` every robot's true pose (N, 3) after the last step (world frame,
    heading unwrapped); ``report()`` what the robots were asked, the odometry's drift,
    contacts.
    """

    def __init__(self, model: str, starts: NDArray[np.float64], tick: float, *,
                 rate: float = 250.0, collide: bool = True, cmd_timeout: float = 0.5):
        missing = physics_available()
        if missing is not None:
            raise ValueError(missing)
        starts = np.asarray(starts, dtype=float)
        if starts.ndim != 2 or starts.shape[1] != 3 or len(starts) < 1:
            raise ValueError(f"parameters robots, poses: 3 numbers (x, y, theta) per robot, "
                             f"got shape {starts.shape}")
        if not (tick > 0 and cmd_timeout > 0):
            raise ValueError("parameters tick and cmd_timeout must be > 0")
        self.start = starts
        self.n = n = len(starts)
        self.tick, self.cmd_timeout = tick, cmd_timeout
        self.world = PhysicsWorld(robot_model(model), n, tick, rate=rate, collide=collide)
        self.world.place(starts)
        self.cmd = np.zeros((n, 2))
        self.cmd_at = np.full(n, -math.inf)
        self.last: list[tuple[float, float, float] | None] = [None] * n
        self.stats = np.zeros((n, 4))  # max |v|, |omega|, |dv/dt|, |domega/dt|
        self.drift = np.zeros(n)
        self.truth = self.world.truth()
        #: every robot held at zero whatever it is sent (a contact stopped them)
        self.held = False
        self._since: dict[tuple[int, int], float] = {}

    def window(self) -> None:
        """A trial or a return begins: ``window_pairs`` counts from now."""
        self._since = {(i, j): secs for i, j, secs, _ in self.world.contact_pairs()}

    def window_pairs(self) -> list[tuple[int, int, float, float]]:
        """The pairs that touched since ``window``: (i, j) 1-based, seconds in contact
        since, the deepest penetration of the run [m]."""
        out = []
        for i, j, secs, depth in self.world.contact_pairs():
            before = self._since.get((i, j), 0.0)
            if secs > before:
                out.append((i, j, secs - before, depth))
        return out

    def command(self, i: int, v: float, omega: float, stamp: float, now: float) -> None:
        """Robot i's command (a non-finite one is ignored)."""
        if not (math.isfinite(v) and math.isfinite(omega)):
            return
        prev = self.last[i]
        st = self.stats[i]
        st[0], st[1] = max(st[0], abs(v)), max(st[1], abs(omega))
        if prev is not None and stamp - prev[0] > 1e-4:
            st[2] = max(st[2], abs(v - prev[1]) / (stamp - prev[0]))
            st[3] = max(st[3], abs(omega - prev[2]) / (stamp - prev[0]))
        self.last[i] = (stamp, v, omega)
        self.cmd[i] = (v, omega)
        self.cmd_at[i] = now

    def step(self, now: float) -> list[BaseOdometry]:
        """One tick under each robot's newest command (zero once older than cmd_timeout);
        every robot's odometry after it."""
        self.cmd[now - self.cmd_at > self.cmd_timeout] = 0.0
        if self.held:
            self.cmd[:] = 0.0
        world = self.world
        world.step(self.cmd)
        self.truth = truth = world.truth()
        self.drift = np.maximum(self.drift, np.hypot(*(truth[:, :2] - world.odom[:, :2]).T))
        tilts = world.roll_pitch()
        out: list[BaseOdometry] = []
        for i in range(self.n):
            # odometry in the frame of the start pose, as a base's driver reports it
            x0, y0, th0 = self.start[i]
            dx, dy = world.odom[i, 0] - x0, world.odom[i, 1] - y0
            c, s = math.cos(th0), math.sin(th0)
            pose = (c * dx + s * dy, -s * dx + c * dy, float(world.odom[i, 2] - th0))
            out.append((pose, (float(self.cmd[i, 0]), float(self.cmd[i, 1])),
                        _quaternion(float(tilts[i, 0]), float(tilts[i, 1]), pose[2])))
        return out

    def report(self) -> dict[str, Any]:
        return {"commands_max": {robot_name(i + 1): {
                    "v": float(s[0]), "omega": float(s[1]), "a": float(s[2]),
                    "alpha": float(s[3])} for i, s in enumerate(self.stats)},
                "odometry_drift": {robot_name(i + 1): float(x)
                                   for i, x in enumerate(self.drift)},
                "contacts": self.world.contacts()}

    def close(self) -> None:
        self.world.close()


class BaseTrials:
    """The schedule as the physics bases see it (wall clock), for their contacts: which
    trial the robots drive (from the leader's ``start`` to its agreed end) or which return
    (from the trial's end or its abort to the next start), and what each contact means.

    ``on_event(ev, now_ns)`` takes the leader's events by the rule every follower applies
    (``schedule.Follower``; a wall-clock follower: the agreed start is checked); ``tick(
    now_ns)``, after each step of ``robots``, gives the new contact event (``ContactWatch``)
    and whether the trial just ended (its report is then ``report()``; the node says ready
    for the next). ``held``: a contact stopped the robots, until the leader aborts the
    trial (``stop``) or for good (``abort``, ``give_up``: the run ends); ``robots`` then
    holds every robot at zero.
    """

    def __init__(self, cfg: RunConfig, robots: BaseRobots, watch: ContactWatch):
        from formation_ilc.protocol.schedule import Follower

        self.T = cfg.scenario.samples
        self.dt_ns = cfg.clock.dt_ns
        self.follower = Follower(cfg.run_id, wall_trial_ns=self.T * self.dt_ns,
                                 clock=cfg.clock)
        self.watch = watch
        self.robots = robots
        self.phase = "idle"
        self.start_ns = 0
        self.back_ns = 0
        self.stopped: ContactEvent | None = None
        #: per iteration: the pairs that touched in its trial ({pair: seconds}), in its
        #: return, the largest tilt [rad] of its trial; and the events said
        self.by_trial: dict[str, dict[str, Any]] = {
            "contacts_by_trial": {}, "return_contacts_by_trial": {}, "tilt_by_trial": {}}
        self.tilt_max = 0.0
        #: the pairs that touched in this trial or return (``BaseRobots.window_pairs``)
        self.window_pairs: list[tuple[int, int, float, float]] = []

    @property
    def contacts(self) -> dict[str, float]:
        """This trial's or return's pairs that touched: seconds in contact, keyed
        'robot_i-robot_j'."""
        return {f"{robot_name(i)}-{robot_name(j)}": secs for i, j, secs, _ in self.window_pairs}

    @property
    def trial(self) -> int:
        return self.follower.trial

    @property
    def slot(self) -> int:
        return self.follower.slot

    @property
    def held(self) -> bool:
        return self.stopped is not None and self.stopped.action != "continue"

    def on_event(self, ev: TrialEvent, now_ns: int) -> TrialEvent | None:
        """The start or abort taken (None: nothing to do; Rejected: not obeyed)."""
        taken = self.follower.take(ev, idle=self.phase != "trial", now_wall_ns=now_ns)
        if taken is None:
            return None
        if taken.event == ABORT:
            if self.phase == "trial" and taken.slot == self.slot:
                self._begin_return(now_ns)
            return taken
        assert taken.start_wall_ns is not None
        self.phase, self.start_ns = "trial", int(taken.start_wall_ns)
        self._window()
        return taken

    def _window(self, carry: bool = False) -> None:
        self.watch.window(carry)
        self.robots.window()
        self.stopped = None if self.stopped is None or self.stopped.action in (
            "stop", "continue") else self.stopped
        self.robots.held = self.held
        self.tilt_max = 0.0
        self.window_pairs = []

    def _begin_return(self, now_ns: int) -> None:
        self.phase, self.back_ns = "return", now_ns
        self._window(carry=True)

    def tick(self, now_ns: int) -> tuple[ContactEvent | None, bool]:
        """(the new contact event of this tick or None, whether the trial just ended)."""
        if self.phase == "idle":
            return None, False
        pairs, tilts = self.robots.window_pairs(), self.robots.world.tilt()
        self.tilt_max = max(self.tilt_max, float(np.max(tilts, initial=0.0)))
        self.window_pairs = pairs
        k = str(self.trial)
        if self.phase == "trial":
            sample = int(min(self.T, max(0, (now_ns - self.start_ns) // self.dt_ns)))
            ev = self.watch.check(self.trial, self.slot, sample, pairs, tilts)
            self.by_trial["tilt_by_trial"][k] = self.tilt_max
            if pairs:
                self.by_trial["contacts_by_trial"][k] = self.contacts
        else:
            ev = self.watch.check(self.trial, self.slot, -1, pairs, tilts, "return",
                                  (now_ns - self.back_ns) * 1e-9)
            if pairs:
                self.by_trial["return_contacts_by_trial"][k] = self.contacts
        if ev is not None and ev.acts:
            self.stopped = ev
        self.robots.held = self.held
        ended = (self.phase == "trial" and not self.held
                 and now_ns >= self.start_ns + self.T * self.dt_ns)
        return ev, ended

    def report(self) -> dict[str, Any]:
        """The trial's report (once it ended): its contacts for the metrics rows
        (``contact_report``: its slot and the pairs that touched), the run's so far."""
        return {"contact_report": {"slot": self.slot,
                                   "pairs": [list(p) for p in self.window_pairs]},
                "contacts": self.contacts, "tilt_max": self.tilt_max,
                "contact_events": self.watch.events, **self.by_trial}

    def ended(self, now_ns: int) -> None:
        """The trial's report is out: the robots are driven back."""
        self._begin_return(now_ns)
