"""The run description between the hosts of a run file's ``hosts:``, over the ROS graph.

The ground station's launcher publishes its run's description (``core.names.HOSTS_RUN``,
latched JSON: the run's id, ROS domain, namespace, the key that seals the leader's events
and, once the run ended, its status) from its monitor node (``nodes.host.LauncherHost``);
each other host's launcher takes it with a node of its own (:class:`RunListener`, in the
namespace ``HOSTS_NAMESPACE`` below the formation's: no member of the formation) and starts
its members in that run (``cli.hostlaunch``). The machines share the network, not a
folder. Without ``--secure`` every participant of the domain can read the description, as
it reads every topic; under ``--secure`` the launchers keep the handshake file
(``cli.hostlaunch``) until the enclaves grant the topic.
"""

from __future__ import annotations

import json
from typing import Any

__all__ = ["RunListener", "listener_name"]


def listener_name(host: str) -> str:
    """The node name of host ``host``'s listener: ``host_NAME``, made a valid ROS name."""
    clean = "".join(c if c.isalnum() or c == "_" else "_" for c in host)
    return f"host_{clean}"[:200]


class RunListener:
    """rclpy and one node that takes the ground station's run description: :meth:`read`
    gives the newest (a dict), or None before any came."""

    def __init__(self, host: str, namespace: str):
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import String

        import msgs_schema as ms
        from formation_ilc.core.names import HOSTS_NAMESPACE, HOSTS_RUN, absolute

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node(listener_name(host),
                                      namespace=absolute(HOSTS_NAMESPACE, namespace))
        self.latest: dict[str, Any] | None = None
        self.topic = absolute(HOSTS_RUN, namespace)
        self.sub = self.node.create_subscription(String, self.topic, self._take,
                                                 ms.LATCHED_QOS)
        self.ex = SingleThreadedExecutor()
        self.ex.add_node(self.node)

    def _take(self, msg: Any) -> None:
        try:
            d = json.loads(msg.data)
        except (ValueError, TypeError):
            return
        if isinstance(d, dict) and isinstance(d.get("run_id"), str):
            self.latest = d

    def read(self, timeout: float = 0.0) -> dict[str, Any] | None:
        """The newest description, after handling what came within ``timeout`` seconds."""
        self.ex.spin_once(timeout_sec=timeout)
        return self.latest

    def close(self) -> None:
        import rclpy

        self.ex.remove_node(self.node)
        self.node.destroy_node()
        rclpy.try_shutdown()
