"""A rigid-body plant: N differential-drive robots in PyBullet, one sample at a time.

The physics plant behind the plant contract (``robot_sim/physics_node.py``) and the
physics studies (``studies/physics.py``) step this world; it has no ROS in it. Each robot
has mass, inertia, wheel-ground contact with friction, and wheel motors with a torque limit
under velocity control: a command (v, omega) becomes wheel speeds through the model's
effective track, held for the sample while the engine runs ``substeps`` steps of
1 / ``rate`` s.

Two models (``MODELS``):

* ``p3dx``: a two-wheel differential drive of Pioneer 3-DX size and mass with a rear caster
  (``robots/p3dx_size.urdf``; body 0.455 x 0.381 m, 9 kg, wheels 0.195 m).
* ``husky``: the Clearpath Husky URDF that the pybullet wheel bundles (``pybullet_data``;
  4-wheel skid steer, 44 kg, wheels 0.356 m, track 0.571 m). A skid-steer base slips its
  wheels sideways to turn: it turns about a point behind its base origin, and more slowly
  than its geometric track says. Its effective track and turning point come from
  ``calibrate`` (docs/physics.md) and the model tracks that point.

Each robot reports two poses of its tracked point: ground truth from the engine, and wheel
odometry integrated from its measured wheel speeds (it drifts as the wheels slip).
Contacts between robots are detected at every substep and counted per pair; robots collide
by default (a plant that let them pass through each other would hide the crash a real team
has), ``collide=False`` lets them pass.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from importlib import resources
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.option_table import default
from formation_ilc.core.kinematics import wrap_angle
from formation_ilc.core.limits import Limits
from formation_ilc.core.names import robot_name
from formation_ilc.model.footprint import Footprint, footprint_of

__all__ = ["RobotModel", "MODELS", "PhysicsWorld", "robot_model", "DEFAULT_RATE",
           "POSE_SOURCES", "RATE_RANGE", "rate_problem"]

#: where a robot's measured pose comes from: the engine's ground truth (a motion-capture
#: stand-in) or its wheel odometry (drifts)
POSE_SOURCES = ("truth", "odometry")

#: engine steps per second (PyBullet's default, the option table's): 48 substeps per
#: sample at dT = 0.2 s
DEFAULT_RATE: float = default("physics_rate")
#: [Hz] the engine rates a run may ask for (the physics plant's parameter range)
RATE_RANGE = (1.0, 1e5)


def rate_problem(rate: float, dt: float) -> str | None:
    """Why the engine cannot step at ``rate`` [Hz] for samples of ``dt`` [s], or None:
    outside RATE_RANGE, less than one step a sample (before, 1 Hz at dT = 0.2 s silently
    ran one step a sample, 5 Hz), or not a whole number of steps a sample (the rate that
    would run is named, and the two whole ones around it)."""
    lo, hi = RATE_RANGE
    if not (lo <= rate <= hi):
        return f"{rate:g} Hz is outside {lo:g} .. {hi:g} engine steps a second"
    steps = dt * rate
    if steps < 1.0 - 1e-9:
        return (f"{rate:g} Hz is {steps:.3g} engine steps a sample of {dt:g} s: at least one "
                f"({1.0 / dt:g} Hz) is needed")
    whole = round(steps)
    if abs(steps - whole) > 1e-6 * steps:
        below, above = math.floor(steps), math.ceil(steps)
        return (f"{rate:g} Hz is {steps:.4g} engine steps a sample of {dt:g} s, which would "
                f"run at {whole / dt:g} Hz: give a whole number of steps a sample, e.g. "
                f"{below / dt:g} or {above / dt:g} Hz")
    return None
#: how often [Hz] wheel encoders are read and contacts checked: 50 Hz, the update rate of
#: ROS 2's diff_drive_controller on the bases the stack drives; reading them at every
#: substep cost more than the engine itself (3 robots)
SENSE_RATE = 50.0


@dataclass(frozen=True)
class RobotModel:
    """A robot the world can load.

    urdf : 'package:NAME' (this package's ``model/robots/NAME``) or 'pybullet_data:PATH'.
    left, right : the wheel joints of each side. wheel_radius [m]. track [m]: the
    effective track that maps omega to wheel speeds (geometric for a two-wheel drive,
    calibrated for skid steer). torque [N m]: each wheel motor's limit. tracked [m]: the
    tracked point's distance ahead of the base origin. footprint: the body, about the
    tracked point. caster: links whose friction is removed (a caster swivels freely).
    base: the base preset (``config.bases``) whose speed and acceleration limits the world
    enforces on every command (``PhysicsWorld.step``) as the robot's own controller does:
    the one table the bridges, ``check`` and the safety filter read too (``limits``).
    """

    name: str
    urdf: str
    left: tuple[str, ...]
    right: tuple[str, ...]
    wheel_radius: float
    track: float
    torque: float
    tracked: float
    footprint: Footprint
    mass: float
    friction: float = 0.8
    caster: tuple[str, ...] = ()
    spawn_z: float = 0.0
    source: str = ""
    geometric_track: float = field(default=0.0)
    #: the base whose limits the world enforces on every command, from the one table of
    #: ``config.bases.BASES`` (what the bridges, ``check`` and the safety filter read)
    base: str = ""
    #: velocity loops on the base (the body's speed and turn rate, as an IMU-fused odometry
    #: gives them, fed back at SENSE_RATE): the wheel speeds' mean and difference are
    #: corrected by a proportional and an integral term of gain ``yaw_loop`` [1/s] on the
    #: errors, so that the body drives and turns as commanded whatever its wheels slip
    #: (what a skid-steer base's controller with an IMU can do); 0: open loop
    yaw_loop: float = 0.0

    @property
    def limits(self) -> Limits:
        """The speed and acceleration limits of the model's base (``config.bases``)."""
        from formation_ilc.config.bases import base_preset

        return base_preset(self.base).limits

    @property
    def limits_source(self) -> str:
        """The limits and where they come from, in one line."""
        from formation_ilc.config.bases import base_preset

        return base_preset(self.base).limits_line


MODELS: dict[str, RobotModel] = {
    "p3dx": RobotModel(
        "p3dx", "package:p3dx_size.urdf", ("left_wheel",), ("right_wheel",),
        wheel_radius=0.0975, track=0.34, torque=2.0, tracked=0.0,
        footprint=footprint_of("p3dx"), mass=9.0, caster=("caster_link",),
        spawn_z=0.002, geometric_track=0.33,
        source="Pioneer 3-DX datasheet dimensions; boxes and cylinders of this package",
        base="p3dx"),
    # track and tracked point of both: ``calibrate`` at 240 Hz (docs/physics.md has the runs)
    "husky": RobotModel(
        "husky", "pybullet_data:husky/husky.urdf",
        ("front_left_wheel", "rear_left_wheel"), ("front_right_wheel", "rear_right_wheel"),
        wheel_radius=0.17775, track=1.5, torque=30.0, tracked=-0.17,
        footprint=footprint_of("husky"), mass=44.0, spawn_z=0.02,
        geometric_track=0.5708, source="pybullet_data husky/husky.urdf (Clearpath Husky)",
        base="husky"),
}


# the Husky whose base closes velocity loops on the body's speed and turn rate (an IMU-fused
# controller): it drives and turns as commanded whatever its wheels slip (docs/physics.md,
# "Skid steer")
MODELS["husky-imu"] = replace(
    MODELS["husky"], name="husky-imu", yaw_loop=10.0,
    source="pybullet_data husky/husky.urdf (Clearpath Husky) with velocity loops on the base")


def robot_model(name: str, **changes: Any) -> RobotModel:
    """A model by name, with fields replaced (e.g. a calibrated track)."""
    from dataclasses import replace

    try:
        m = MODELS[name]
    except KeyError:
        raise ValueError(f"no robot model {name!r} (have: {', '.join(MODELS)})") from None
    return replace(m, **changes) if changes else m


def _urdf_path(spec: str) -> str:
    kind, _, rel = spec.partition(":")
    if kind == "package":
        return str(resources.files("formation_ilc.model.robots").joinpath(rel))
    if kind == "pybullet_data":
        import pybullet_data

        return str(pybullet_data.getDataPath() + "/" + rel)
    raise ValueError(f"urdf {spec!r}: expected 'package:NAME' or 'pybullet_data:PATH'")


@contextmanager
def _quiet() -> Iterator[None]:
    """Bullet's C++ warnings go to the process's stdout, not Python's: silence fd 1."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


class PhysicsWorld:
    """N robots of one model on a flat floor.

    dt : the sample time [s]; rate : engine steps per second (substeps = dt * rate,
    rounded). collide : robots collide with each other (default) or pass through.
    """

    def __init__(self, model: RobotModel, n: int, dt: float, *, rate: float = DEFAULT_RATE,
                 collide: bool = True):
        import pybullet as pb

        why = rate_problem(rate, dt)
        if why is not None:
            raise ValueError(f"parameter rate: {why}")
        self.pb = pb
        self.model, self.n, self.dt = model, n, dt
        self.substeps = max(1, int(round(dt * rate)))
        self.h = dt / self.substeps
        self.sense_every = max(1, int(round(rate / SENSE_RATE)))
        self.cid = pb.connect(pb.DIRECT)
        c = self.cid
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        pb.setTimeStep(self.h, physicsClientId=c)
        import pybullet_data

        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=c)
        self.plane = pb.loadURDF("plane.urdf", physicsClientId=c)
        pb.changeDynamics(self.plane, -1, lateralFriction=model.friction, physicsClientId=c)
        path = _urdf_path(model.urdf)
        with _quiet():  # Bullet prints a warning per link without inertia (the Husky's)
            self.bodies = [pb.loadURDF(path, [3.0 * i, 0.0, model.spawn_z + 0.2],
                                       physicsClientId=c) for i in range(n)]
        names = {pb.getJointInfo(self.bodies[0], j, physicsClientId=c)[1].decode(): j
                 for j in range(pb.getNumJoints(self.bodies[0], physicsClientId=c))}
        links = {pb.getJointInfo(self.bodies[0], j, physicsClientId=c)[12].decode(): j
                 for j in range(pb.getNumJoints(self.bodies[0], physicsClientId=c))}
        try:
            self.left = [names[j] for j in model.left]
            self.right = [names[j] for j in model.right]
        except KeyError as exc:
            raise ValueError(f"{model.name}: {path} has no joint {exc}") from None
        self.wheels = self.left + self.right
        info = pb.getDynamicsInfo(self.bodies[0], -1, physicsClientId=c)
        self.inertial = (info[3], info[4])  # the centre of mass in the root frame
        self.inertial_inv = pb.invertTransform(*self.inertial, physicsClientId=c)
        for b in self.bodies:
            for j in range(pb.getNumJoints(b, physicsClientId=c)):
                # no default motor: only the wheels drive, and nothing brakes the rest
                pb.setJointMotorControl2(b, j, pb.VELOCITY_CONTROL, force=0.0,
                                         physicsClientId=c)
            for w in self.wheels:
                pb.changeDynamics(b, w, lateralFriction=model.friction, physicsClientId=c)
            for name in model.caster:
                pb.changeDynamics(b, links[name], lateralFriction=0.0, rollingFriction=0.0,
                                  spinningFriction=0.0, physicsClientId=c)
        if not collide:
            for i in range(n):
                for j in range(i + 1, n):
                    for li in range(-1, pb.getNumJoints(self.bodies[i], physicsClientId=c)):
                        for lj in range(-1, pb.getNumJoints(self.bodies[j], physicsClientId=c)):
                            pb.setCollisionFilterPair(self.bodies[i], self.bodies[j], li, lj,
                                                      0, physicsClientId=c)
        self.collide = collide
        self.pairs = [(i, j) for i in range(n) for j in range(i + 1, n)]
        self.odom = np.zeros((n, 3))
        self.phi = np.zeros((n, 2))    # wheel angles (left, right) at the last reading
        self.yaw = np.zeros(n)         # unwrapped truth heading
        self.contact_steps = np.zeros(len(self.pairs), dtype=np.int64)
        self.contact_depth = np.zeros(len(self.pairs))
        self.steps = 0
        self._cmd = np.zeros((n, 2))
        #: commands the limits changed since ``place`` (``step``)
        self.limited = 0
        self._loop_i = np.zeros((n, 2))  # the velocity loops' integrals [m/s, rad/s]

    # ------------------------------------------------------------------ state
    def place(self, poses: NDArray[np.float64]) -> None:
        """Put every robot's tracked point at poses (N, 3), at rest; odometry starts there
        and the contact counters restart."""
        pb, c, m = self.pb, self.cid, self.model
        for b, (x, y, th) in zip(self.bodies, np.asarray(poses, dtype=float), strict=True):
            bx, by = x - m.tracked * math.cos(th), y - m.tracked * math.sin(th)
            q = pb.getQuaternionFromEuler([0.0, 0.0, th])
            # PyBullet places a body by its centre of mass, not by its URDF root frame
            com, qc = pb.multiplyTransforms([bx, by, m.spawn_z], q, *self.inertial,
                                            physicsClientId=c)
            pb.resetBasePositionAndOrientation(b, com, qc, physicsClientId=c)
            pb.resetBaseVelocity(b, [0, 0, 0], [0, 0, 0], physicsClientId=c)
            for j in range(pb.getNumJoints(b, physicsClientId=c)):
                pb.resetJointState(b, j, 0.0, 0.0, physicsClientId=c)
        self.yaw[:] = np.asarray(poses, dtype=float)[:, 2]
        self._cmd[:] = 0.0
        self.limited = 0
        self._loop_i[:] = 0.0
        # settle on the wheels without driving (a URDF's origin may sit above the floor)
        self._drive(np.zeros((self.n, 2)))
        for _ in range(self.substeps):
            pb.stepSimulation(physicsClientId=c)
        self.odom[:] = self.truth()
        self.phi[:] = 0.0
        self._sense()  # encoders zeroed where the robot stands
        self.odom[:] = self.truth()
        self.contact_steps[:] = 0
        self.contact_depth[:] = 0.0

    def truth(self) -> NDArray[np.float64]:
        """Ground truth of the tracked points, (N, 3): x, y [m], heading [rad] unwrapped
        across calls."""
        pb, m = self.pb, self.model
        out = np.empty((self.n, 3))
        for r, b in enumerate(self.bodies):
            pos, q = self._root(b)
            yaw = pb.getEulerFromQuaternion(q)[2]
            self.yaw[r] += wrap_angle(yaw - self.yaw[r])
            out[r] = (pos[0] + m.tracked * math.cos(yaw), pos[1] + m.tracked * math.sin(yaw),
                      self.yaw[r])
        return out

    def _root(self, body: int) -> tuple[Any, Any]:
        """(position, quaternion) of a body's URDF root frame (the engine reports its
        centre of mass)."""
        pb, c = self.pb, self.cid
        pos, q = pb.getBasePositionAndOrientation(body, physicsClientId=c)
        return pb.multiplyTransforms(pos, q, *self.inertial_inv, physicsClientId=c)

    def tilt(self) -> NDArray[np.float64]:
        """Each robot's tilt [rad]: the angle between its body's up axis and the vertical
        (a robot turned over reads more than pi / 2)."""
        pb = self.pb
        out = np.empty(self.n)
        for r, b in enumerate(self.bodies):
            q = self._root(b)[1]
            zz = pb.getMatrixFromQuaternion(q)[8]
            out[r] = math.acos(max(-1.0, min(1.0, zz)))
        return out

    def roll_pitch(self) -> NDArray[np.float64]:
        """Each robot's body roll and pitch [rad], (N, 2) (what an IMU-fused odometry
        carries)."""
        pb = self.pb
        return np.array([pb.getEulerFromQuaternion(self._root(b)[1])[:2] for b in self.bodies])

    def body_twist(self) -> NDArray[np.float64]:
        """Each robot's (v forward [m/s], omega [rad/s]) from the engine, (N, 2)."""
        pb, c = self.pb, self.cid
        out = np.empty((self.n, 2))
        for r, b in enumerate(self.bodies):
            lin, ang = pb.getBaseVelocity(b, physicsClientId=c)
            yaw = self.yaw[r]
            out[r] = (lin[0] * math.cos(yaw) + lin[1] * math.sin(yaw), ang[2])
        return out

    # ------------------------------------------------------------------ stepping
    def _drive(self, u: NDArray[np.float64]) -> None:
        pb, c, m = self.pb, self.cid, self.model
        half = 0.5 * m.track
        for b, (v, w) in zip(self.bodies, u, strict=True):
            left = (v - w * half) / m.wheel_radius
            right = (v + w * half) / m.wheel_radius
            targets = [left] * len(self.left) + [right] * len(self.right)
            pb.setJointMotorControlArray(b, self.wheels, pb.VELOCITY_CONTROL,
                                         targetVelocities=targets,
                                         forces=[m.torque] * len(self.wheels),
                                         physicsClientId=c)

    def limit(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """Commands u (N, 2) as the robots' controllers take them: each inside the model's
        speed limits and at most an acceleration limit x dT from the previous command (0
        after ``place``: the robots stand)."""
        lim = self.model.limits
        u = np.asarray(u, dtype=float)
        lo = np.maximum(self._cmd - self.dt * np.array([lim.a_max, lim.alpha_max]),
                        -np.array([lim.v_max, lim.omega_max]))
        hi = np.minimum(self._cmd + self.dt * np.array([lim.a_max, lim.alpha_max]),
                        np.array([lim.v_max, lim.omega_max]))
        out = np.clip(u, lo, hi)
        out = np.where(np.isfinite(u), out, 0.0)  # a non-finite command stops the wheel
        return out

    def step(self, u: NDArray[np.float64]) -> None:
        """Hold commands u (N, 2) [m/s, rad/s] for one sample: ``substeps`` engine steps,
        after the model's limits (``limit``; counted in ``limited``).
        Every ``sense_every`` steps (``SENSE_RATE``) the wheel encoders are read into the
        odometry and contacts between robots are checked."""
        pb, c = self.pb, self.cid
        u = np.asarray(u, dtype=float)
        held = self.limit(u)
        self.limited += int(np.count_nonzero(np.any(np.abs(held - u) > 1e-9, axis=1)))
        u = held
        self._cmd[:] = u
        self._drive(u)
        loop = self.model.yaw_loop
        for k in range(1, self.substeps + 1):
            pb.stepSimulation(physicsClientId=c)
            if k % self.sense_every == 0 or k == self.substeps:
                self._sense()
                if loop > 0:  # the base's own velocity loops: P + I on speed and turn
                    self.truth()  # the headings now (the body's forward direction)
                    err = u - self.body_twist()
                    self._loop_i += loop * loop / 4 * err * self.h * self.sense_every
                    self._drive(u + 0.1 * loop * err + self._loop_i)
        self.steps += self.substeps

    def _sense(self) -> None:
        """Odometry from the wheel angles since the last reading (an arc per reading, as a
        base's controller integrates its encoders) and the contact check."""
        pb, c, m = self.pb, self.cid, self.model
        nl = len(self.left)
        for r, b in enumerate(self.bodies):
            angles = [s[0] for s in pb.getJointStates(b, self.wheels, physicsClientId=c)]
            phi_l = sum(angles[:nl]) / nl
            phi_r = sum(angles[nl:]) / (len(angles) - nl)
            dl = m.wheel_radius * (phi_l - self.phi[r, 0])
            dr = m.wheel_radius * (phi_r - self.phi[r, 1])
            self.phi[r] = (phi_l, phi_r)
            ds, dth = 0.5 * (dl + dr), (dr - dl) / m.track
            th = self.odom[r, 2] + 0.5 * dth  # the arc's chord direction
            self.odom[r, 0] += ds * math.cos(th)
            self.odom[r, 1] += ds * math.sin(th)
            self.odom[r, 2] += dth
        if self.collide:
            bodies = self.bodies
            for p, (i, j) in enumerate(self.pairs):
                pts = pb.getContactPoints(bodies[i], bodies[j], physicsClientId=c)
                if pts:
                    self.contact_steps[p] += 1
                    # contact distance (index 8) is negative for penetration
                    depth = -min(pt[8] for pt in pts)
                    self.contact_depth[p] = max(self.contact_depth[p], depth)

    def contact_pairs(self) -> list[tuple[int, int, float, float]]:
        """Pairs that touched since ``place``: (i, j) 1-based, seconds in contact, the
        deepest penetration [m]."""
        return [(i + 1, j + 1, float(k * self.h * self.sense_every), float(d))
                for (i, j), k, d in zip(self.pairs, self.contact_steps, self.contact_depth,
                                        strict=True) if k]

    def contacts(self) -> dict[str, float]:
        """Time in contact per pair since ``place`` [s] (readings in contact x their
        interval), pairs that touched only, keyed 'robot_i-robot_j' (1-based)."""
        return {f"{robot_name(i + 1)}-{robot_name(j + 1)}": float(k * self.h * self.sense_every)
                for (i, j), k in zip(self.pairs, self.contact_steps, strict=True) if k}

    def close(self) -> None:
        if self.cid >= 0:
            self.pb.disconnect(physicsClientId=self.cid)
            self.cid = -1

    def __enter__(self) -> PhysicsWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def calibrate(model: RobotModel, *, v: float = 0.3, omega: float = 0.3, seconds: float = 20.0,
              rate: float = DEFAULT_RATE) -> tuple[float, float]:
    """The effective track [m] and the turning point's distance ahead of the base origin
    [m] of a model, from one run of ``seconds`` at constant (v, omega) from rest.

    The commanded wheel speeds use the model's geometric track; the measured turn rate
    omega_m (from the base's heading over the second half of the run, after the start)
    gives the effective track as geometric * omega / omega_m, the point that moves
    straight ahead (no sideways velocity) is the turning point.
    """
    geo = model.geometric_track or model.track
    from dataclasses import replace

    m = replace(model, track=geo, tracked=0.0)
    dt = 0.2
    with PhysicsWorld(m, 1, dt, rate=rate, collide=False) as world:
        world.place(np.zeros((1, 3)))
        n = int(round(seconds / dt))
        heads, lateral, turn = [], [], []
        for k in range(n):
            world.step(np.array([[v, omega]]))
            if k >= n // 2:
                pb, c = world.pb, world.cid
                lin, ang = pb.getBaseVelocity(world.bodies[0], physicsClientId=c)
                yaw = world.truth()[0, 2]
                heads.append(yaw)
                # sideways velocity of the base origin, and the turn rate
                lateral.append(-lin[0] * math.sin(yaw) + lin[1] * math.cos(yaw))
                turn.append(ang[2])
        w_m = (heads[-1] - heads[0]) / (dt * (len(heads) - 1))
        # a point a ahead of the origin moves sideways at lateral + a * omega: zero at a
        ahead = -float(np.mean(lateral)) / float(np.mean(turn))
    return geo * omega / w_m, ahead
