"""Physics plant (``formation-ilc-physics``): every robot in a PyBullet world, in one process.

The same plant contract, schedule and timing as the kinematic simulator (``robot_sim.node``,
which this node extends), with the rigid-body world of ``formation_ilc.model.physics`` in
place of eq. (1): at a trial's start the robots are placed at their desired start plus the
scenario's initial shift, each sample's commands are held for ``dT`` while the engine runs
its substeps (``rate`` Hz, 48 per sample at dT = 0.2 s and 240 Hz), in lockstep with
``/clock`` or on a wall-clock timer (``--mode realtime``).

* measured pose (``robot_i/pose``): ``pose`` = ``truth``, the engine's ground truth (a
  motion-capture stand-in, the default), or ``odometry``, the robot's wheel odometry
  (drifts as the wheels slip); plus the scenario's output noise.
* true trajectory (``robot_i/true_trajectory``): always the engine's ground truth.
* diagnostics at each trial's end: ``contacts`` (seconds in contact per pair of robots),
  ``tilt_max`` [rad], ``odometry_drift`` [m] (largest distance between odometry and truth),
  and the same for every trial so far (``contacts_by_trial`` ...); a contact is also
  logged as a warning.

Parameters: ``model`` (p3dx, husky), ``pose`` (truth, odometry), ``rate`` [Hz], ``collide``
(robots collide, default true; false lets them pass through each other), ``timeout`` [s].
"""

from __future__ import annotations

import sys
from typing import Any

import numpy as np

from formation_ilc.model.physics import DEFAULT_RATE, PhysicsWorld, robot_model
from formation_ilc.nodes.common import RunConfig, node_parser, spin_main
from formation_ilc.studies.physics import POSE_SOURCES
from robot_sim.node import SimNode

#: the physics plant's node name (what it says ready as)
NAME = "physics_sim"


class PhysicsNode(SimNode):
    """All robots of the run in one PyBullet world."""

    def __init__(self, **kwargs: Any):
        self.world: PhysicsWorld | None = None
        super().__init__(NAME, **kwargs)  # the run configuration arrives later, on a topic
        self.declare_parameter("model", "p3dx")
        self.declare_parameter("pose", "truth")
        self.declare_parameter("rate", DEFAULT_RATE)
        self.declare_parameter("collide", True)

    def configure(self, cfg: RunConfig) -> None:
        try:
            import pybullet  # noqa: F401
        except ImportError:
            raise ValueError("the physics plant needs PyBullet: pip install -c "
                             "requirements.lock -e '.[physics]'") from None
        pose = str(self.get_parameter("pose").value)
        if pose not in POSE_SOURCES:
            raise ValueError(f"parameter pose: one of {', '.join(POSE_SOURCES)}, got {pose!r}")
        model = robot_model(str(self.get_parameter("model").value))
        rate = float(self.get_parameter("rate").value)
        if not rate > 0:
            raise ValueError(f"parameter rate: engine steps per second > 0, got {rate}")
        self.pose_source = pose
        self.world = PhysicsWorld(model, cfg.scenario.n, cfg.scenario.dt, rate=rate,
                                  collide=bool(self.get_parameter("collide").value))
        self.get_logger().info(
            f"physics: {cfg.scenario.n} x {model.name}, {self.world.substeps} substeps of "
            f"{self.world.h * 1e3:.2f} ms per sample, pose from {pose}, robots "
            f"{'collide' if self.world.collide else 'pass through each other'}")
        self.tilt_max = 0.0
        self.drift = 0.0
        # per trial (iteration), for the run's summary: the latched diagnostics keep only
        # the last message
        self.by_trial: dict[str, dict[str, Any]] = {"contacts_by_trial": {},
                                                     "tilt_by_trial": {},
                                                     "odometry_drift_by_trial": {}}
        super().configure(cfg)

    def _place(self) -> None:
        world = self.world
        assert world is not None
        world.place(self.xi[:, 0])
        self.xi[:, 0] = world.truth()  # where it stands once settled on its wheels
        self.tilt_max = 0.0
        self.drift = 0.0

    def _plant_step(self, t: int) -> None:
        world = self.world
        assert world is not None
        world.step(self.u[:, t])
        self.xi[:, t + 1] = world.truth()
        self.tilt_max = max(self.tilt_max, float(world.tilt().max()))

    def _measure(self, t: int) -> None:
        world = self.world
        assert world is not None
        base = self.xi[:, t] if self.pose_source == "truth" else world.odom
        self.drift = max(self.drift, float(np.hypot(*(world.odom[:, :2] - self.xi[:, t, :2]).T)
                                           .max()))
        self.eta[:, t] = base + self.noise[:, t]

    def _trial_report(self) -> dict[str, Any]:
        world = self.world
        assert world is not None
        k = str(self.iteration)
        contacts = world.contacts()
        if contacts:
            self.get_logger().warning(f"trial {k}: robots in contact: {contacts} [s]")
            self.by_trial["contacts_by_trial"][k] = contacts
        self.by_trial["tilt_by_trial"][k] = self.tilt_max
        self.by_trial["odometry_drift_by_trial"][k] = self.drift
        return {"contacts": contacts, "tilt_max": self.tilt_max,
                "odometry_drift": self.drift, "pose_source": self.pose_source,
                "model": world.model.name, "substeps": world.substeps, **self.by_trial}

    def destroy_node(self) -> None:
        if self.world is not None:
            self.world.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [PhysicsNode()],
                     node_parser("formation-ilc-physics", __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
