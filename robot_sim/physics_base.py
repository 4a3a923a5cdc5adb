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

It also publishes, on ``diagnostics`` in its own namespace (the launcher puts it in the
formation's, so the recorder keeps it), what the robots were asked: per robot the largest
|v|, |omega| and, between consecutive commands (by their header stamps when stamped),
|dv/dt| and |domega/dt|, and the true poses' drift from the odometry. Parameters:
``robots``, ``poses`` (x, y, theta per robot, flat: where each robot is placed), ``model``,
``rate`` [Hz], ``collide``, ``seed``-free: the engine is deterministic.
"""

from __future__ import annotations

import functools
import math
import sys
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.model.physics import PhysicsWorld, robot_model
from formation_ilc.nodes.common import node_parser, spin_main

NAME = "physics_bases"


class PhysicsBases(Node):
    """N physics robots, each a base with cmd_vel and odometry."""

    def __init__(self, **kwargs: Any):
        # in the formation's namespace (its diagnostics are recorded); the bases' own topics
        # are absolute
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(NAME, **kwargs)
        for name, default in (("robots", 3), ("poses", [0.0]), ("model", "p3dx"),
                              ("rate", 250.0), ("tick", 0.02), ("collide", True),
                              ("ns_pattern", "/base_{i}"), ("cmd_type", "twist"),
                              ("odom_topic", "odom"), ("cmd_timeout", 0.5)):
            self.declare_parameter(name, default)
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        n = int(g("robots"))
        poses = np.asarray([float(x) for x in g("poses")], dtype=float)
        if n < 1 or poses.size != 3 * n:
            raise ValueError(f"parameters robots, poses: {n} robots need 3 numbers each "
                             f"(x, y, theta), got {poses.size}")
        self.start = poses.reshape(n, 3)
        self.tick = float(g("tick"))
        self.cmd_timeout = float(g("cmd_timeout"))
        self.world = PhysicsWorld(robot_model(str(g("model"))), n, self.tick,
                                  rate=float(g("rate")), collide=bool(g("collide")))
        self.world.place(self.start)
        self.n = n
        self.cmd = np.zeros((n, 2))
        self.cmd_at = np.full(n, -math.inf)
        self.last: list[tuple[float, float, float] | None] = [None] * n
        self.stats = np.zeros((n, 4))  # max |v|, |omega|, |dv/dt|, |domega/dt|
        self.drift = np.zeros(n)
        stamped = str(g("cmd_type")) == "twist_stamped"
        self.odom_pubs = []
        self.msgs = [Odometry() for _ in range(n)]
        for i in range(n):
            ns = str(g("ns_pattern")).replace("{i}", str(i + 1)).rstrip("/")
            self.create_subscription(TwistStamped if stamped else Twist, f"{ns}/cmd_vel",
                                     functools.partial(self._on_cmd, i=i), ms.DRIVER_CMD_QOS)
            self.odom_pubs.append(self.create_publisher(Odometry, f"{ns}/{g('odom_topic')}",
                                                        ms.ODOM_QOS))
        self.diag_pub = self.create_publisher(String, ms.DIAGNOSTICS, ms.LATCHED_QOS)
        self.create_timer(self.tick, self._on_tick)
        self.create_timer(1.0, self._report)
        self.get_logger().info(f"{n} physics bases ({self.world.model.name}), "
                               f"{self.world.substeps} engine steps per {self.tick} s tick")

    def _on_cmd(self, msg: Twist | TwistStamped, i: int) -> None:
        stamped = isinstance(msg, TwistStamped)
        t = msg.twist if stamped else msg
        v, w = float(t.linear.x), float(t.angular.z)
        if not (math.isfinite(v) and math.isfinite(w)):
            return
        when = (ms.stamp_to_ns(msg.header.stamp) * 1e-9 if stamped else time.monotonic())
        prev = self.last[i]
        st = self.stats[i]
        st[0], st[1] = max(st[0], abs(v)), max(st[1], abs(w))
        if prev is not None and when - prev[0] > 1e-4:
            st[2] = max(st[2], abs(v - prev[1]) / (when - prev[0]))
            st[3] = max(st[3], abs(w - prev[2]) / (when - prev[0]))
        self.last[i] = (when, v, w)
        self.cmd[i] = (v, w)
        self.cmd_at[i] = time.monotonic()

    def _on_tick(self) -> None:
        now = time.monotonic()
        stale = now - self.cmd_at > self.cmd_timeout
        self.cmd[stale] = 0.0
        world = self.world
        world.step(self.cmd)
        truth = world.truth()
        self.drift = np.maximum(self.drift, np.hypot(*(truth[:, :2] - world.odom[:, :2]).T))
        stamp = time.time_ns()
        pb = world.pb
        for i in range(self.n):
            # odometry in the frame of the start pose, as a base's driver reports it
            x0, y0, th0 = self.start[i]
            dx, dy = world.odom[i, 0] - x0, world.odom[i, 1] - y0
            c, s = math.cos(th0), math.sin(th0)
            pose = (c * dx + s * dy, -s * dx + c * dy, world.odom[i, 2] - th0)
            m = ms.odometry_msg(pose, self.cmd[i], stamp, out=self.msgs[i])
            # the body's roll and pitch, as an IMU-fused odometry carries them
            q_body = world._root(world.bodies[i])[1]
            roll, pitch, _ = pb.getEulerFromQuaternion(q_body)
            q = pb.getQuaternionFromEuler([roll, pitch, pose[2]])
            o = m.pose.pose.orientation
            o.x, o.y, o.z, o.w = (float(v) for v in q)
            self.odom_pubs[i].publish(m)

    def _report(self) -> None:
        d = {"node": NAME, "trial": -1,
             "commands_max": {ms.robot_name(i + 1): {
                 "v": float(s[0]), "omega": float(s[1]), "a": float(s[2]),
                 "alpha": float(s[3])} for i, s in enumerate(self.stats)},
             "odometry_drift": {ms.robot_name(i + 1): float(x)
                                for i, x in enumerate(self.drift)},
             "contacts": self.world.contacts()}
        self.diag_pub.publish(ms.json_to_msg(d))

    def destroy_node(self) -> None:
        self.world.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [PhysicsBases()], node_parser(NAME, __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
