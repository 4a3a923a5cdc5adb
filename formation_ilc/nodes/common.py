"""What every node of the stack shares: the run configuration, counters, spinning, warm-up.

The run configuration travels on ``/formation/config`` (latched) as JSON: the scenario's
YAML text and the command-line overrides, so that no node needs the scenario file.
"""

from __future__ import annotations

import signal
import sys
from collections import Counter
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.scenario import Scenario, load_scenario, scenario_from_text
from formation_ilc.simulate import Problem

#: reasons a message is dropped (the diagnostics counters)
DROP_REASONS = ("malformed", "stale", "out_of_order")


@dataclass(frozen=True)
class RunConfig:
    """Everything a node needs to know about a run, from the config topic.

    mode : 'lockstep' (the simulator waits for every robot) or 'realtime' (wall clock).
    gap : samples between the end of one trial's labels and the next trial's (stamps).
    monitored : a monitor (the launcher) reads trajectories and diagnostics.
    """

    scenario: Scenario
    mode: str = "lockstep"
    gap: int = 20
    monitored: bool = False
    timeout: float = 30.0

    @property
    def clock(self) -> ms.SampleClock:
        return ms.SampleClock.for_run(self.scenario.dt, self.scenario.samples, self.gap)

    def to_json(self) -> dict[str, Any]:
        sc = self.scenario
        return {"scenario_text": sc.text, "source": sc.source, "seed": sc.seed,
                "noise": sc.uncertainty.noisy,
                "delay": sc.uncertainty.delay.kind != "none", "trials": sc.trials,
                "law": sc.law.kind, "memory": sc.law.memory, "mode": self.mode,
                "gap": self.gap, "monitored": self.monitored, "timeout": self.timeout}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> RunConfig:
        try:
            sc = scenario_from_text(str(d["scenario_text"]), str(d.get("source", "<config>")))
            sc = sc.with_options(law=int(d["law"]), memory=str(d["memory"]),
                                 noise=bool(d["noise"]), delay=bool(d["delay"]),
                                 seed=int(d["seed"]), trials=int(d["trials"]))
            mode = str(d.get("mode", "lockstep"))
            if mode not in ("lockstep", "realtime"):
                raise ValueError(f"mode must be lockstep or realtime, got {mode!r}")
            return cls(sc, mode, int(d.get("gap", 20)), bool(d.get("monitored", False)),
                       float(d.get("timeout", 30.0)))
        except (KeyError, TypeError, ValueError) as exc:
            raise ms.MalformedMessage(f"bad run configuration: {exc}") from None


def make_config(scenario: str, *, seed: int | None = None, noise: bool = True,
                delay: bool = True, trials: int | None = None, law: int | None = None,
                memory: str | None = None, mode: str = "lockstep", gap: int = 20,
                monitored: bool = False, timeout: float = 30.0) -> RunConfig:
    """The run configuration of a scenario name or file with command-line overrides."""
    sc = load_scenario(scenario).with_options(law=law, memory=memory, noise=noise,
                                              delay=delay, seed=seed, trials=trials)
    return RunConfig(sc, mode, gap, monitored, timeout)


def config_from_msg(msg: String, drops: DropCounter) -> RunConfig | None:
    """The run configuration on /formation/config, or None (dropped and counted)."""
    try:
        return RunConfig.from_json(ms.msg_to_json(msg))
    except ms.MalformedMessage as exc:
        drops.drop("malformed", ms.CONFIG, str(exc))
        return None


class DropCounter:
    """Counts dropped messages by reason and topic (published in diagnostics)."""

    def __init__(self, node: Node):
        self._node = node
        self.counts: Counter[str] = Counter({r: 0 for r in DROP_REASONS})
        self.by_topic: Counter[str] = Counter()

    def drop(self, reason: str, topic: str, why: str = "") -> None:
        self.counts[reason] += 1
        self.by_topic[f"{reason}:{topic}"] += 1
        # first few of each kind are logged; the rest only counted (a flood must not log-spam)
        if self.by_topic[f"{reason}:{topic}"] <= 3:
            self._node.get_logger().warning(f"dropped {reason} message on {topic}: {why}")

    def as_dict(self) -> dict[str, Any]:
        return {"dropped": dict(self.counts), "dropped_by_topic": dict(self.by_topic)}


def warm_up(pb: Problem) -> None:
    """Compile (or load from the numba cache) every kernel a node calls, with the node's
    shapes, so the first sample is not late by seconds."""
    from formation_ilc.kinematics import step_into
    from formation_ilc.law import command, learn
    from formation_ilc.simulate import trial_errors

    n, n_t, n_l = pb.n, pb.samples, pb.src.shape[1]
    i = slice(0, 1)
    out = np.zeros((1, 2))
    eta = np.zeros((1, n_t + 1, 3))
    command(0, pb.law, np.zeros((1, 2)), eta, pb.eta_d[i], np.zeros((1, n_l, 3)),
            np.zeros((1, n_l), dtype=np.int64), pb.src[i], pb.weight[i], pb.eta_d,
            np.zeros(1, dtype=np.int64), pb.leader[i], pb.gain_prime[i], pb.heading, out)
    learn(pb.law, pb.memory, np.zeros((1, n_t, 2)), np.zeros((1, n_t, 2)), eta, pb.eta_d[i],
          np.zeros((1, n_l, n_t + 1, 3)), pb.src[i], pb.weight[i], pb.eta_d, pb.leader[i],
          pb.gain[i], pb.heading, np.zeros((1, n_t, 2)))
    step_into(np.zeros((n, 3)), np.zeros((n, 2)), np.zeros((n, 2)), pb.dt, np.zeros((n, 3)))
    trial_errors(pb.eta_d, pb.eta_d, pb.eta_d, pb.src, pb.weight, np.zeros(6))


def matched(pairs: Iterable[tuple[Any, int]]) -> bool:
    """True when every publisher has at least ``count`` matched subscriptions."""
    return all(pub.get_subscription_count() >= count for pub, count in pairs)


class Exit:
    """Exit status a node asks for; ``stop`` is done when the process should end."""

    code = 0
    stop: Future | None = None


def fail(node: Node, message: str, code: int = 3) -> None:
    """Log ``message`` as the node's last word and stop its process with ``code``."""
    node.get_logger().fatal(message)
    print(f"{node.get_name()}: {message}", file=sys.stderr, flush=True)
    Exit.code = code
    if Exit.stop is not None:
        Exit.stop.set_result(code)


def make_executor(kind: str = "events") -> Any:
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor()


def spin_main(build: Callable[[list[str]], list[Node]], args: list[str] | None = None,
              executor: str = "events") -> int:
    """The Jazzy main idiom for one process holding one or more nodes on one executor.

    build : gets the non-ROS command-line arguments and returns the nodes.
    """
    # rclpy's own SIGINT handling raises KeyboardInterrupt inside whatever callback runs,
    # which aborts the process from C++; a flag for the spin loop is enough
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    Exit.stop = Future()

    def on_signal(signum: int, frame: Any) -> None:
        if Exit.stop is not None and not Exit.stop.done():
            Exit.stop.set_result(0)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    argv = rclpy.utilities.remove_ros_args(args if args is not None else sys.argv)[1:]
    nodes: list[Node] = []
    try:
        nodes = build(argv)
        ex = make_executor(executor)
        for n in nodes:
            ex.add_node(n)
        # EventsExecutor.spin() never returns to Python, so SIGINT would go unseen: spin in
        # slices, which costs one return to the interpreter every 0.25 s
        while rclpy.ok() and not Exit.stop.done():
            ex.spin_until_future_complete(Exit.stop, timeout_sec=0.25)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown()
    return Exit.code
