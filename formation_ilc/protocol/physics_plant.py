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
           "ContactEvent"]

#: what a physics plant does when robots touch: stop them and re-run the trial (at most
#: ``retries`` times), stop them and end the run, or report and go on
ON_CONTACT = ("stop", "abort", "continue")


@dataclass(frozen=True)
class ContactEvent:
    """Robots touched (or tipped) in a trial: the iteration and slot, the sample, the pairs
    (i, j 1-based, seconds in contact, deepest penetration [m]), the largest tilt [rad]
    and its robot (1-based), and what the plant does about it (``action``: 'stop',
    'abort', 'continue' or 'give_up': the retries are spent)."""

    trial: int
    slot: int
    sample: int
    pairs: tuple[tuple[int, int, float, float], ...]
    tilt: float
    tilted: int
    action: str

    def line(self, dt: float, tilt_limit: float) -> str:
        what = [f"robots {i} and {j} in contact ({depth * 100:.1f} cm deep)"
                for i, j, _, depth in self.pairs]
        if self.tilt > tilt_limit:
            what.append(f"robot {self.tilted} tilted {math.degrees(self.tilt):.1f} deg")
        return (f"trial {self.trial} (slot {self.slot}), t = {self.sample * dt:.1f} s: "
                f"{'; '.join(what)}")


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
                 rate: float = DEFAULT_RATE, collide: bool = True, on_contact: str = "stop",
                 retries: int = 2, tilt_limit: float = math.radians(10.0)):
        missing = physics_available()
        if missing is not None:
            raise ValueError(missing)
        if pose not in POSE_SOURCES:
            raise ValueError(f"parameter pose: one of {', '.join(POSE_SOURCES)}, got {pose!r}")
        if not (rate > 0 and math.isfinite(rate)):
            raise ValueError(f"parameter rate: engine steps per second > 0, got {rate}")
        if on_contact not in ON_CONTACT:
            raise ValueError(f"parameter on_contact: one of {', '.join(ON_CONTACT)}, got "
                             f"{on_contact!r}")
        if retries < 0:
            raise ValueError(f"parameter contact_retries: >= 0, got {retries}")
        if not 0 < tilt_limit <= math.pi:
            raise ValueError(f"parameter tilt_limit: in (0, 180] deg, got "
                             f"{math.degrees(tilt_limit):g}")
        self.on_contact, self.retries, self.tilt_limit = on_contact, retries, tilt_limit
        #: the trial's contact (None: none yet), and the re-runs each iteration had
        self.contact: ContactEvent | None = None
        self.reruns: dict[int, int] = {}
        #: contacts (pairs that touched) of every trial, by iteration, for the report
        self.contact_trials = 0
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
        self.fresh_contact: ContactEvent | None = None

    def move(self, t: int) -> None:
        if self.contact is not None and self.contact.action != "continue":
            self.u[:, t] = 0.0  # the robots were stopped: they stand for the rest of it
        self.world.step(self.u[:, t])
        self.xi[:, t + 1] = self.world.truth()
        tilts = self.world.tilt()
        self.tilt_max = max(self.tilt_max, float(tilts.max()))
        if self.contact is None:
            pairs = self.world.contact_pairs()
            if pairs or tilts.max() > self.tilt_limit:
                self._contact(t + 1, pairs, tilts)

    def _contact(self, t: int, pairs: list[tuple[int, int, float, float]],
                 tilts: NDArray[np.float64]) -> None:
        """The trial's first contact (or tilt past the limit): what the plant does."""
        i = self.iteration
        action = self.on_contact
        if action == "stop":
            self.reruns[i] = self.reruns.get(i, 0) + 1
            if self.reruns[i] > self.retries:
                action = "give_up"
        self.contact_trials += 1
        self.contact = self.fresh_contact = ContactEvent(
            i, self.k, t, tuple(pairs), float(tilts.max()), int(np.argmax(tilts)) + 1, action)

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

    def take_contact(self) -> ContactEvent | None:
        """The contact of this trial not yet taken (the node reports it once)."""
        ev, self.fresh_contact = self.fresh_contact, None
        return ev

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
