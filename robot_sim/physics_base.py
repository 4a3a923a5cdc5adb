"""Physics robots behind a base's interface (``python -m robot_sim.physics_base``).

The PyBullet world of ``formation_ilc.model.physics`` in wall time, every robot exposed
the way a real differential-drive base exposes itself: ``cmd_vel`` in and wheel odometry
out (nav_msgs/Odometry, starting at 0 where the robot was placed, its orientation carrying
the body's real roll and pitch), no ground truth to the stack. The generic bridge
(``formation-ilc-bridge -p base:=...``) drives it exactly as it drives a TurtleBot or a
Husky: ``formation-ilc launch --plant base --physics-bases`` runs the two together.

Robot i's topics are in ``ns_pattern`` with {i} replaced (default ``/base_{i}``):
``cmd_vel`` (Twist, or TwistStamped with ``cmd_type:=twist_stamped``) and ``odom_topic``
(default ``odom``). Every ``tick`` s (default 0.02) the engine advances one tick under the
newest command of each robot (zero once it is older than ``cmd_timeout``, the base's own
watchdog) and each robot's odometry is published.

With ``truth:=true`` each robot's true pose goes out after every tick on ``truth`` in its
namespace (PoseStamped, world frame, stamped with the wall time): the ground truth a
simulator has and a real base has not, which the launcher gives the bridges for the
metrics' true columns.

It also publishes, on ``diagnostics`` in its own namespace (the launcher puts it in the
formation's, so the recorder keeps it), what the robots were asked: per robot the largest
|v|, |omega| and, between consecutive commands (by their header stamps when stamped),
|dv/dt| and |domega/dt|, and the true poses' drift from the odometry. Everything it
decides is in ``formation_ilc.protocol.physics_plant.BaseRobots``. Parameters:
``robots``, ``poses`` (x, y, theta per robot, flat: where each robot is placed), ``model``,
``rate`` [Hz], ``collide``, ``truth``; the engine is deterministic.

In a run (the launcher's, whose configuration it reads) it follows the trials as the link
emulator does (the leader waits for its ready) and watches the bodies: every contact
between two robots and every robot tipped past ``tilt_limit``, in a trial or on the way
back to the start poses, is logged and published at once in its diagnostics (the console
says it), counted per trial (its trial report: ``contact_report``, the rows' ``contacts``)
and per return, and acted on (``on_contact``, ``contact_retries``: as the physics plant;
a return is not run again, so ``stop`` there ends the run): the robots are held at zero
whatever they are sent, the leader is asked to abort the trial, or the process ends with
status 6 (the run's).
"""

from __future__ import annotations

import functools
import math
import sys
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Odometry
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config.option_table import default
from formation_ilc.config.params import Param
from formation_ilc.config.roster import DRIVER_NS
from formation_ilc.core.names import BASE_TRUTH, BASES_NODE
from formation_ilc.model.physics import MODELS
from formation_ilc.nodes.common import (
    ConfiguredNode,
    RunConfig,
    node_parser,
    spin_main,
)
from formation_ilc.nodes.contacts import ContactActing
from formation_ilc.nodes.params import declare
from formation_ilc.protocol.physics_plant import (
    CONTACT_PARAMS,
    BaseRobots,
    BaseTrials,
    ContactWatch,
)
from formation_ilc.protocol.plant import RESEND_S

NAME = BASES_NODE

#: N physics robots as plain differential-drive bases (``formation-ilc-physics-bases``)
PARAMS: tuple[Param, ...] = (
    Param("robots", 3, "how many bases", lo=1, hi=1000),
    Param("poses", [0.0], "their start poses: x, y, theta of each base in turn", "m, rad"),
    Param("model", default("robot_model"), "the robot model of every base",
          choices=tuple(MODELS)),
    Param("rate", 250.0, "engine steps per second", "Hz", lo=1.0, hi=1e5),
    Param("tick", 0.02, "how often the world is stepped and odometry published", "s",
          lo=1e-4, hi=10.0),
    Param("collide", True, "bases collide with each other"),
    Param("ns_pattern", DRIVER_NS["base"], "namespace of base i's topics ({i}: 1-based)"),
    Param("cmd_type", "twist", "the message type of cmd_vel",
          choices=("twist", "twist_stamped")),
    Param("odom_topic", "odom", "the odometry topic, relative to the base's namespace"),
    Param("cmd_timeout", 0.5, "a base stops when no command came for this long", "s",
          lo=1e-3, hi=1e3),
    Param("truth", False, f"also publish each base's true pose on '{BASE_TRUTH}' in its "
          "namespace (PoseStamped, world frame)"),
    *CONTACT_PARAMS,
)


class PhysicsBases(ContactActing, ConfiguredNode):
    """N physics robots, each a base with cmd_vel and odometry."""

    def __init__(self, **kwargs: Any):
        # in the formation's namespace (its diagnostics are recorded); the bases' own topics
        # are absolute
        super().__init__(NAME, **kwargs)
        declare(self, PARAMS)
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        n = int(g("robots"))
        poses = np.asarray([float(x) for x in g("poses")], dtype=float)
        if n < 1 or poses.size != 3 * n:
            raise ValueError(f"parameters robots, poses: {n} robots need 3 numbers each "
                             f"(x, y, theta), got {poses.size}")
        self.core = BaseRobots(str(g("model")), poses.reshape(n, 3), float(g("tick")),
                               rate=float(g("rate")), collide=bool(g("collide")),
                               cmd_timeout=float(g("cmd_timeout")))
        stamped = str(g("cmd_type")) == "twist_stamped"
        self.odom_pubs = []
        self.truth_pubs = []
        self.msgs = [Odometry() for _ in range(n)]
        self.truth_msgs = [PoseStamped() for _ in range(n)]
        for i in range(n):
            ns = str(g("ns_pattern")).replace("{i}", str(i + 1)).rstrip("/")
            self.create_subscription(TwistStamped if stamped else Twist, f"{ns}/cmd_vel",
                                     functools.partial(self._on_cmd, i=i), ms.DRIVER_CMD_QOS)
            self.odom_pubs.append(self.create_publisher(Odometry, f"{ns}/{g('odom_topic')}",
                                                        ms.ODOM_QOS))
            if bool(g("truth")):
                self.truth_pubs.append(self.create_publisher(PoseStamped,
                                                             f"{ns}/{BASE_TRUTH}",
                                                             ms.ODOM_QOS))
        self.watch = ContactWatch(str(g("on_contact")), int(g("contact_retries")),
                                  math.radians(float(g("tilt_limit"))))
        #: the trials as followed, once the run's configuration came (None: not in a run)
        self.trials: BaseTrials | None = None
        self.create_timer(self.core.tick, self._on_tick)
        self.create_timer(1.0, self._report)
        world = self.core.world
        self.get_logger().info(f"{n} physics bases ({world.model.name}), "
                               f"{world.substeps} engine steps per {self.core.tick} s tick")
        self.follow_config()

    def configure(self, cfg: RunConfig) -> None:
        """A run: follow its trials, watch the bodies, say ready as the link emulator."""
        self.cfg = cfg
        self.trials = BaseTrials(cfg, self.core, self.watch)
        self.follower = self.trials.follower
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        self.ready_pub.publish(self.ready_msg(0))

    def _on_event(self, msg: String) -> None:
        trials = self.trials
        assert trials is not None
        ev = self.take_event(msg, lambda ev: trials.on_event(ev, time.time_ns()))
        if ev is not None and ev.event == ms.ABORT:
            self.ready_pub.publish(self.ready_msg(trials.trial + 1))

    def _on_cmd(self, msg: Twist | TwistStamped, i: int) -> None:
        now = time.monotonic()
        stamped = isinstance(msg, TwistStamped)
        t = msg.twist if stamped else msg
        stamp = ms.stamp_to_ns(msg.header.stamp) * 1e-9 if stamped else now
        self.core.command(i, float(t.linear.x), float(t.angular.z), stamp, now)

    def _on_tick(self) -> None:
        odoms = self.core.step(time.monotonic())
        stamp = time.time_ns()
        for i, (pose, twist, quat) in enumerate(odoms):
            self.odom_pubs[i].publish(ms.odometry_msg(pose, twist, stamp, out=self.msgs[i],
                                                      quat=quat))
        for i, pub in enumerate(self.truth_pubs):
            pub.publish(ms.pose_to_msg(self.core.truth[i], stamp, ms.WORLD_FRAME,
                                       out=self.truth_msgs[i]))
        trials = self.trials
        if trials is None:
            return
        ev, ended = trials.tick(stamp)
        if ev is not None:
            self.act_on_contact(ev, self.watch, time.time_ns())
        elif (trials.held and trials.stopped is not None and trials.stopped.action == "stop"
              and time.monotonic() - self._asked >= RESEND_S):
            # a lost request must not leave the run waiting
            self.ask_abort(trials.stopped, self.watch)
        if ended:
            d = {"node": NAME, "trial": trials.trial, **trials.report(),
                 **self.core.report()}
            d.update(self.drops.as_dict())
            self.diag_pub.publish(ms.diagnostics_to_msg(d, stamp))
            trials.ended(stamp)
            self.ready_pub.publish(self.ready_msg(trials.trial + 1))

    def before_contact_end(self) -> None:
        self._report()  # the counts, the ending contact's included, before the end

    def _report(self) -> None:
        # of the trial whose trial or return the contact ended: a report of trial -1 after
        # that trial's own was refused as stale by the launcher's monitor, and the
        # contact that ended a run in a return was missing from return_contacts_by_trial
        extra: dict[str, Any] = {}
        trial = -1
        if self.trials is not None:
            extra = {**self.trials.by_trial, "contact_events": self.watch.events}
            trial = self.trials.trial
        self.diag_pub.publish(ms.diagnostics_to_msg({"node": NAME, "trial": trial,
                                                      **self.core.report(), **extra},
                                                     time.time_ns()))

    def destroy_node(self) -> None:
        self.core.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [PhysicsBases()], node_parser(NAME, __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
