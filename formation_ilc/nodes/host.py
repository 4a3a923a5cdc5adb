"""The launcher's ROS host: the one rclpy context of a ``formation-ilc launch`` process.

The launcher (``formation_ilc.cli.launch``) decides and supervises without ROS; this module
is its ROS side. It joins the formation's domain (in the monitor's enclave with
``--secure``), hosts the monitor node (``formation_ilc.nodes.monitor``: per-trial metrics,
diagnostics and the leader's events from the wire), tells the leader at once when a
passive node died (a ``ready`` with ``down``), looks for another formation on the same
domain and namespace before anything starts, and spins. The launcher calls
:meth:`LauncherHost.spin_once` from its own loop, so every decision stays in its pure
code.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

__all__ = ["LauncherHost", "CLOSE_S"]

#: [s] how long the launcher's DDS teardown may take. Fast DDS can block for ever in it,
#: pushing the graph's last update into the shared-memory port of a process that has
#: ended (``SharedMemManager::Port::regenerate_port`` waiting on the port's mutex: seen
#: once, after a 53-process run whose every trial was in). Not the nodes' bound
#: (``system.lifetime.bound_the_stop``, SIGALRM's default action): the launcher's exit
#: status is the run's verdict, so it ends itself with it (``cli.launch.run``).
CLOSE_S = 10.0


class LauncherHost:
    """rclpy, the monitor node and its executor for one run of ``plan``
    (``formation_ilc.plan.specs.RunPlan``); ``on_trial(k, row)`` gets each finished trial's
    metrics row (iterations from ``first``), ``on_contact(node, report)`` a plant's
    contact the moment it is said, ``on_clock(node, level, text)`` a node's clock event
    (a clock step, an estimate that does not converge)."""

    def __init__(self, plan: Any, on_trial: Callable[[int, np.ndarray], None], first: int = 0,
                 on_contact: Callable[[str, dict[str, Any]], None] | None = None,
                 on_clock: Callable[[str, str, str], None] | None = None):
        self.plan = plan
        self.on_trial = on_trial
        self.first = first
        self.on_contact = on_contact
        self.on_clock = on_clock
        self.monitor: Any = None
        self._down_pub: Any = None
        self._describe_pub: Any = None
        self._ex: Any = None
        #: managed bridges' lifecycle manager (``formation_ilc.nodes.lifecycle``), or None
        self.transitions: Any = None

    def start(self) -> None:
        """Initialise rclpy (its signal handlers off: the launcher handles signals) in the
        monitor's enclave with ``--secure``, and start the monitor node."""
        import rclpy
        from rclpy.experimental import EventsExecutor
        from rclpy.signals import SignalHandlerOptions
        from std_msgs.msg import String

        import msgs_schema as ms
        from formation_ilc.nodes.monitor import MonitorNode

        plan = self.plan
        if plan.secure is not None:  # the monitor joins in its own enclave
            plan.secure.enter_launcher()
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        self.monitor = MonitorNode(plan.config, self.on_trial, true_state=plan.true_state,
                                   namespace=plan.namespace, first=self.first,
                                   on_contact=self.on_contact, on_clock=self.on_clock,
                                   key=plan.key, contacts_from=plan.roster.contact_watchers,
                                   report_writers=plan.roster.report_writers,
                                   trajectory_writers=plan.roster.trajectory_writers())
        self._down_pub = self.monitor.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        bridge = getattr(plan, "bridge", None)
        if bridge is not None and bridge.lifecycle:
            from formation_ilc.nodes.lifecycle import Transitions

            self.transitions = Transitions(self.monitor, [
                ms.absolute(ms.bridge_name(i), plan.namespace)
                for i in range(1, plan.scenario.n + 1)])
        self._ex = EventsExecutor()
        self._ex.add_node(self.monitor)

    def spin_once(self, timeout: float) -> None:
        self._ex.spin_once(timeout_sec=timeout)

    def down(self, name: str, pid: int) -> None:
        """Tell the leader that node ``name`` (process ``pid``) died and is started again:
        a passive one, so that no trial starts without it (the recorder: no trial
        unrecorded); any, so that the readers of shared topics free its name for its
        successor's participant (``protocol.writers``). The boot it names is the pid: an
        active node's ready has another, so its down moves no schedule (its restart
        shows in its new ready)."""
        import msgs_schema as ms
        from formation_ilc.protocol.schedule import Ready

        cfg = self.plan.config
        self._down_pub.publish(ms.json_to_msg(Ready(
            name, cfg.scenario.trials, str(pid), passive=True, run=cfg.run_id,
            down=True).to_json()))

    def describe(self, description: dict[str, Any]) -> None:
        """Publish the run's description for the other hosts' launchers (latched:
        ``nodes.hostlink``)."""
        import json

        from std_msgs.msg import String

        import msgs_schema as ms
        from formation_ilc.core.names import HOSTS_RUN, absolute

        if self._describe_pub is None:
            self._describe_pub = self.monitor.create_publisher(
                String, absolute(HOSTS_RUN, self.plan.namespace), ms.LATCHED_QOS)
        msg = String()
        msg.data = json.dumps(description)
        self._describe_pub.publish(msg)

    def described(self, timeout: float) -> bool:
        """Whether every listener has the last description, waiting at most ``timeout``
        seconds (before this launcher leaves the graph)."""
        from rclpy.duration import Duration

        pub = self._describe_pub
        return pub is None or bool(pub.wait_for_all_acked(Duration(seconds=timeout)))

    def foreign(self, wait: float, allowed: set[str]) -> list[str]:
        """Nodes of another formation in the plan's namespace on this domain (other than
        ``allowed``: an external plant's), after giving discovery ``wait`` seconds; its
        leader's ``config`` writer counts when none of its nodes is seen yet."""
        import msgs_schema as ms

        node, namespace = self.monitor, self.plan.namespace
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            time.sleep(0.05)
        found = [f"{ns.rstrip('/')}/{name}"
                 for name, ns in node.get_node_names_and_namespaces()
                 if ns == namespace and name != node.get_name() and name not in allowed]
        if node.count_publishers(ms.absolute(ms.CONFIG, namespace)) and not found:
            found.append(ms.absolute(ms.CONFIG, namespace))
        return found

    #: a teardown did not return within CLOSE_S: the process should end without waiting
    #: for it (the interpreter's exit would wait on the same Fast DDS lock)
    teardown_hung = False

    def close(self) -> dict[str, dict[str, Any]]:
        """The nodes' last diagnostics; then the monitor destroyed and rclpy shut down,
        for at most CLOSE_S (else ``teardown_hung``, and a warning)."""
        import rclpy

        diagnostics: dict[str, dict[str, Any]] = {}
        monitor = self.monitor
        if monitor is not None:
            diagnostics = dict(monitor.diagnostics)
            diagnostics[monitor.get_name()] = monitor.report()
        failed: list[BaseException] = []

        def teardown() -> None:
            try:
                if monitor is not None:
                    monitor.destroy_node()
                rclpy.try_shutdown()
            except BaseException as exc:  # noqa: BLE001 - raised again in the caller
                failed.append(exc)

        worker = threading.Thread(target=teardown, name="dds-teardown", daemon=True)
        worker.start()
        worker.join(CLOSE_S)
        if worker.is_alive():
            LauncherHost.teardown_hung = True
            print(f"warning: the launcher's DDS teardown did not end within {CLOSE_S:g} s "
                  f"(Fast DDS waiting on the shared-memory port of a process that ended); "
                  f"the results are written without it", file=sys.stderr, flush=True)
        elif failed:
            raise failed[0]
        return diagnostics
