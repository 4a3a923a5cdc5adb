"""Physics plant (``formation-ilc-physics-sim``): every robot in a PyBullet world, in one process.

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
  and the same for every trial so far (``contacts_by_trial`` ...).
* contacts acted on (``on_contact``): the first contact of a trial between two robots, or a
  robot tilted past ``tilt_limit``, is logged and published in the diagnostics at once
  (``contact``: the launcher prints it); ``stop`` (default) holds every robot still for the
  rest of the trial and asks the leader to abort it (it runs again), at most
  ``contact_retries`` times per trial, then ends the run (status 6) naming the pair;
  ``abort`` ends the run at once; ``continue`` goes on.

Everything it decides is in ``formation_ilc.protocol.physics_plant.PhysicsPlant``.

Parameters: ``model`` (p3dx, husky), ``pose`` (truth, odometry), ``rate`` [Hz], ``collide``
(robots collide, default true; false lets them pass through each other), ``timeout`` [s],
``on_contact`` (stop, abort, continue), ``contact_retries``, ``tilt_limit`` [deg].
"""

from __future__ import annotations

import math
import sys
import time
from typing import Any

from formation_ilc.config.params import Param
from formation_ilc.core.names import PHYSICS_NODE
from formation_ilc.model.physics import DEFAULT_RATE, MODELS, POSE_SOURCES, RATE_RANGE
from formation_ilc.nodes.common import RunConfig, node_parser, spin_main
from formation_ilc.nodes.contacts import ContactActing
from formation_ilc.nodes.params import declare
from formation_ilc.protocol.physics_plant import (
    CONTACT_PARAMS,
    PhysicsPlant,
)
from formation_ilc.protocol.plant import RESEND_S
from robot_sim.node import SimNode

#: the physics plant's node name (what it says ready as)
NAME = PHYSICS_NODE

#: the physics plant's own parameters (the simulator's come from ``config.params.SIM``)
PARAMS: tuple[Param, ...] = (
    Param("model", "p3dx", "the robot model every robot of the team is",
          choices=tuple(MODELS)),
    Param("pose", "truth", "what a robot's pose is: the body's true pose, or its "
          "odometry from the wheel encoders", choices=POSE_SOURCES),
    Param("rate", DEFAULT_RATE, "engine steps per second (each sample is dT * rate steps, "
          "a whole number)", "Hz", lo=RATE_RANGE[0], hi=RATE_RANGE[1]),
    Param("collide", True, "robots collide with each other (false: they pass through)"),
    *CONTACT_PARAMS,
)


class PhysicsNode(ContactActing, SimNode):
    """All robots of the run in one PyBullet world."""

    def __init__(self, **kwargs: Any):
        super().__init__(NAME, **kwargs)  # the run configuration arrives later, on a topic

    def declare_plant_parameters(self) -> None:
        declare(self, PARAMS)  # after the simulator's (SIM)

    def make_plant(self, cfg: RunConfig) -> PhysicsPlant:
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        plant = PhysicsPlant(cfg, str(g("model")), pose=str(g("pose")), rate=float(g("rate")),
                             collide=bool(g("collide")), on_contact=str(g("on_contact")),
                             retries=int(g("contact_retries")),
                             tilt_limit=math.radians(float(g("tilt_limit"))))
        self.get_logger().info(plant.describe())
        return plant

    def body_name(self) -> str:
        return str(self.get_parameter("model").value)  # the PyBullet model's base

    def report(self) -> dict[str, Any]:
        d = super().report()
        if d.get("contacts"):
            self.get_logger().warning(f"trial {d['trial']}: robots in contact: "
                                      f"{d['contacts']} [s]")
        return d

    def _publish_sample(self) -> None:
        plant = self.plant
        if isinstance(plant, PhysicsPlant):
            for ev in plant.take_contacts():
                stamp = (self.get_clock().now().nanoseconds, self.cfg.scenario.dt,
                         self.cfg.scenario.samples)
                if not self.act_on_contact(ev, plant.watch, *stamp):
                    return  # the run ends here: no sample after the contact
            if plant.held:
                return  # the trial waits for the leader's abort (it asked): no sample
        super()._publish_sample()

    def _resend(self) -> None:
        """A held trial asks for its abort again (RESEND_S apart): a lost request must not
        leave the run waiting for the watchdog."""
        plant = self.plant
        if isinstance(plant, PhysicsPlant) and plant.held and plant.contact is not None:
            now = time.monotonic()
            if now - self._asked >= RESEND_S:
                self.ask_abort(plant.contact, plant.watch)
            return
        super()._resend()

    def destroy_node(self) -> None:
        plant = getattr(self, "plant", None)
        if isinstance(plant, PhysicsPlant):
            plant.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [PhysicsNode()],
                     node_parser("formation-ilc-physics-sim", __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
