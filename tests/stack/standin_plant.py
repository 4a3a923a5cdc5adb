"""A stand-in plant that speaks only the plant contract of ``msgs_schema`` (lockstep).

It shares no code with ``robot_sim``: its own unicycle integration, no noise, no
disturbance, no true trajectories, no diagnostics. A test runs the stack with
``--plant external --plant-nodes standin_plant`` and this process, and checks that the team
still learns: nothing else in the stack may need the plant to be the simulator.

    python tests/stack/standin_plant.py [--ros-args -r __ns:=/team2]
"""

from __future__ import annotations

import math
import sys

import rclpy
from geometry_msgs.msg import PoseStamped, Twist
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config.runconfig import RunConfig

NAME = "standin_plant"


class StandinPlant(Node):
    def __init__(self) -> None:
        super().__init__(NAME, namespace=ms.NAMESPACE)
        self.cfg: RunConfig | None = None
        self.create_subscription(String, ms.CONFIG, self._on_config, ms.LATCHED_QOS)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.clock_pub = self.create_publisher(Clock, ms.CLOCK, ms.CLOCK_QOS)
        self.said_ready = False

    def _on_config(self, msg: String) -> None:
        if self.cfg is not None:
            return
        self.cfg = RunConfig.from_json(ms.msg_to_json(msg))
        sc = self.cfg.scenario
        self.n, self.T, self.dt = sc.n, sc.samples, sc.dt
        self.start = [tuple(map(float, sc.desired.eta[i, 0])) for i in range(self.n)]
        self.pose_pubs = [self.create_publisher(PoseStamped, ms.pose_topic(i + 1),
                                                ms.SAMPLE_QOS) for i in range(self.n)]
        for i in range(self.n):
            self.create_subscription(Twist, ms.cmd_vel_topic(i + 1),
                                     lambda m, i=i: self._on_cmd(m, i), ms.SAMPLE_QOS)
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        self.create_timer(0.02, self._check_ready)

    def _check_ready(self) -> None:
        pubs = self.pose_pubs + [self.clock_pub, self.ready_pub]
        if not self.said_ready and all(p.get_subscription_count() >= 1 for p in pubs):
            self.said_ready = True
            self._ready(0)

    def _ready(self, trial: int) -> None:
        self.ready_pub.publish(String(data=f'{{"node": "{NAME}", "trial": {trial}}}'))

    def _on_event(self, msg: String) -> None:
        ev = ms.msg_to_json(msg)
        if ev.get("event") != ms.START:
            return
        self.k = int(ev["trial"])
        self.t = 0
        self.state = [list(s) for s in self.start]
        self.cmd: dict[int, tuple[float, float]] = {}
        self._publish()

    def _publish(self) -> None:
        assert self.cfg is not None
        ns = self.cfg.clock.stamp_ns(self.k, self.t)
        self.clock_pub.publish(ms.clock_msg(ns))
        for i, (x, y, th) in enumerate(self.state):
            self.pose_pubs[i].publish(ms.pose_to_msg((x, y, th), ns, ms.WORLD_FRAME))
        if self.t == self.T:
            self._ready(self.k + 1)

    def _on_cmd(self, msg: Twist, i: int) -> None:
        self.cmd[i] = (msg.linear.x, msg.angular.z)
        if len(self.cmd) < self.n:
            return
        for j, (v, w) in self.cmd.items():
            x, y, th = self.state[j]
            self.state[j] = [x + self.dt * math.cos(th) * v, y + self.dt * math.sin(th) * v,
                             th + self.dt * w]
        self.cmd = {}
        self.t += 1
        self._publish()


def main() -> int:
    rclpy.init(args=sys.argv)
    node = StandinPlant()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
