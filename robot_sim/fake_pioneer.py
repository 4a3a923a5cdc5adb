"""A fake Pioneer driver for tests (``python -m robot_sim.fake_pioneer``): a kinematic
unicycle in wall time speaking the RosAria (or ros2aria) topics.

In its namespace (``-r __ns:=/pioneer_1``; default ``/RosAria``): subscribes ``cmd_vel``
(Twist, or TwistStamped with ``cmd_type:=twist_stamped``), publishes ``pose``
(nav_msgs/Odometry in ``odom``, starting at 0 where the robot was placed) at ``rate`` Hz
(default 50), and offers the std_srvs/Empty service ``enable_motors``; commands are
ignored until the motors are enabled. ``driver:=ros2aria``: odometry on ``odom``, motors
engaged by the std_srvs/SetBool service ``clutch`` (msgs_schema.DRIVERS). Like RosAria,
it stops the robot when the newest ``cmd_vel`` is older than ``cmd_timeout`` s (default 0.6).

The true motion integrates the command exactly over each wall-clock step. The odometry
is wrong like a real one: a scale error on the travelled distance (``odom_scale``,
default 0.01) and on the rotation (``odom_turn_scale``, default -0.01), a rotation bias
(``odom_turn_bias`` [rad/s], default 0.002), and white noise on the published pose
(``odom_noise`` [m], heading noise a tenth of it in rad, default 0.002), seeded by ``seed``.
It reports its true pose and the odometry's error on ``fake_pioneer/truth`` (JSON, latched)
when asked with ``truth_period`` > 0 (tests only; no keystore grants it: a secure run
refuses the writer).
"""

from __future__ import annotations

import json
import math
import sys
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from std_msgs.msg import String
from std_srvs.srv import Empty, SetBool

import msgs_schema as ms
from formation_ilc.config import params
from formation_ilc.nodes.common import node_parser, spin_main
from formation_ilc.nodes.params import check, declare, probe_overrides

FAKE_DRIVERS = ("rosaria", "ros2aria")


class FakePioneer(Node):
    def __init__(self, driver: str = "rosaria", **kwargs: Any):
        for p in kwargs.get("parameter_overrides") or ():
            if p.name == "driver":
                driver = str(p.value)
        driver = check(params.FAKE_DRIVER[0], driver)
        spec = ms.DRIVERS[driver]
        kwargs.setdefault("namespace", spec.default_ns)
        super().__init__(ms.FAKE_DRIVER_NODE, **kwargs)
        declare(self, params.FAKE_DRIVER, driver=driver)
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        self.cmd_timeout = float(g("cmd_timeout"))
        self.scale, self.turn_scale = float(g("odom_scale")), float(g("odom_turn_scale"))
        self.bias, self.noise = float(g("odom_turn_bias")), float(g("odom_noise"))
        self.rng = np.random.default_rng(int(g("seed")))
        self.true = [0.0, 0.0, 0.0]   # in the odometry frame (the start), exact
        self.odom = [0.0, 0.0, 0.0]   # what the wheel encoders integrate
        self.cmd = (0.0, 0.0)
        self.cmd_time = -math.inf
        self.motors = False
        self.watchdog_stops = 0
        self.last = time.monotonic()
        self.odom_msg = Odometry()
        stamped = str(g("cmd_type")) == "twist_stamped"
        self.create_subscription(TwistStamped if stamped else Twist, spec.cmd,
                                 self._on_cmd, ms.DRIVER_CMD_QOS)
        self.odom_pub = self.create_publisher(Odometry, spec.odom, ms.ODOM_QOS)
        self.create_service(Empty if spec.motors_kind == "empty_service" else SetBool,
                            spec.motors, self._on_enable)
        self.create_timer(1.0 / float(g("rate")), self._on_tick)
        if float(g("truth_period")) > 0:
            self.truth_pub = self.create_publisher(String, "fake_pioneer/truth",
                                                   ms.LATCHED_QOS)
            self.create_timer(float(g("truth_period")), self._publish_truth)

    def _on_enable(self, req: Any, res: Any) -> Any:
        self.motors = bool(getattr(req, "data", True))
        if hasattr(res, "success"):
            res.success = True
        self.get_logger().info("motors enabled")
        return res

    def _on_cmd(self, msg: Twist | TwistStamped) -> None:
        t = msg.twist if isinstance(msg, TwistStamped) else msg
        if not self.motors:
            return
        now = time.monotonic()
        self._advance(now)  # the old command drove until now, the new one drives from now
        self.cmd = (float(t.linear.x), float(t.angular.z))
        self.cmd_time = now

    def _advance(self, now: float) -> None:
        """Move the robot from the last instant to ``now``: the command until the driver's
        watchdog stops it ``cmd_timeout`` after it came, nothing after, however late the
        tick fires (a starved process still drives 0.6 s on one command, as the driver does)."""
        v, w = self.cmd
        stop_at = self.cmd_time + self.cmd_timeout
        if (v, w) != (0.0, 0.0) and now > stop_at:
            self._move(v, w, max(0.0, stop_at - self.last))
            self.cmd = (0.0, 0.0)  # the driver's watchdog
            self.watchdog_stops += 1
        else:
            self._move(v, w, now - self.last)
        self.last = now

    def _move(self, v: float, w: float, dt: float) -> None:
        if (v, w) == (0.0, 0.0):
            return
        self._integrate(self.true, v, w, dt)
        self._integrate(self.odom, v * (1 + self.scale), w * (1 + self.turn_scale) + self.bias,
                        dt)

    def _on_tick(self) -> None:
        self._advance(time.monotonic())
        v, w = self.cmd
        n = self.rng.normal(0.0, 1.0, 3) * self.noise * np.array((1.0, 1.0, 0.1))
        pose = (self.odom[0] + n[0], self.odom[1] + n[1], self.odom[2] + n[2])
        self.odom_pub.publish(ms.odometry_msg(pose, (v, w), time.time_ns(),
                                              out=self.odom_msg))

    @staticmethod
    def _integrate(p: list[float], v: float, w: float, dt: float) -> None:
        """Exact unicycle motion over dt with constant (v, w)."""
        th = p[2]
        if abs(w) < 1e-9:
            p[0] += v * dt * math.cos(th)
            p[1] += v * dt * math.sin(th)
        else:
            p[0] += v / w * (math.sin(th + w * dt) - math.sin(th))
            p[1] -= v / w * (math.cos(th + w * dt) - math.cos(th))
        p[2] = th + w * dt

    def _publish_truth(self) -> None:
        self.truth_pub.publish(String(data=json.dumps({
            "true": self.true, "odom": self.odom, "motors": self.motors,
            "watchdog_stops": self.watchdog_stops})))


def main(args: list[str] | None = None) -> int:
    def build(ns: Any, argv: list[str]) -> list[Node]:
        # the driver names the namespace: read before the node exists (-p or a params file)
        with probe_overrides(ms.FAKE_DRIVER_NODE, ms.DRIVERS["rosaria"].default_ns) as found:
            return [FakePioneer(found.get("driver", "rosaria"))]

    return spin_main(build,
                     node_parser(ms.FAKE_DRIVER_NODE, __doc__), args)


if __name__ == "__main__":
    sys.exit(main())
