"""Physics plant (``formation-ilc-physics``): every robot in a PyBullet world, in one process.

The same plant contract, schedule and timing as the kinematic simulator (``robot_sim.node``,
whose node this one is), with the rigid-body world of ``formation_ilc.model.physics`` in
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

Everything it decides is in ``formation_ilc.protocol.physics_plant.PhysicsPlant``.

Parameters: ``model`` (p3dx, husky), ``pose`` (truth, odometry), ``rate`` [Hz], ``collide``
(robots collide, default true; false lets them pass through each other), ``timeout`` [s].
"""

from __future__ import annotations

import sys
from typing import Any

from formation_ilc.config.params import Param
from formation_ilc.core.names import PHYSICS_NODE
from formation_ilc.model.physics import DEFAULT_RATE, MODELS, POSE_SOURCES
from formation_ilc.nodes.common import RunConfig, node_parser, spin_main
from formation_ilc.nodes.params import declare
from formation_ilc.protocol.physics_plant import PhysicsPlant
from robot_sim.node import SimNode

#: the physics plant's node name (what it says ready as)
NAME = PHYSICS_NODE

#: the physics plant's own parameters (the simulator's come from ``config.params.SIM``)
PARAMS: tuple[Param, ...] = (
    Param("model", "p3dx", "the robot model every robot of the team is",
          choices=tuple(MODELS)),
    Param("pose", "truth", "what a robot's pose is: the body's true pose, or its "
          "odometry from the wheel encoders", choices=POSE_SOURCES),
    Param("rate", DEFAULT_RATE, "engine steps per second (each sample is dT * rate steps)",
          "Hz", lo=1.0, hi=1e5),
    Param("collide", True, "robots collide with each other (false: they pass through)"),
)


class PhysicsNode(SimNode):
    """All robots of the run in one PyBullet world."""

    def __init__(self, **kwargs: Any):
        super().__init__(NAME, **kwargs)  # the run configuration arrives later, on a topic

    def declare_plant_parameters(self) -> None:
        declare(self, PARAMS)  # after the simulator's (SIM)

    def make_plant(self, cfg: RunConfig) -> PhysicsPlant:
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        plant = PhysicsPlant(cfg, str(g("model")), pose=str(g("pose")), rate=float(g("rate")),
                             collide=bool(g("collide")))
        self.get_logger().info(plant.describe())
        return plant

    def report(self) -> dict[str, Any]:
        d = super().report()
        if d.get("contacts"):
            self.get_logger().warning(f"trial {d['trial']}: robots in contact: "
                                      f"{d['contacts']} [s]")
        return d

    def destroy_node(self) -> None:
        plant = getattr(self, "plant", None)
        if isinstance(plant, PhysicsPlant):
            plant.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [PhysicsNode()],
                     node_parser("formation-ilc-physics", __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
