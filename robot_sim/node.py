"""Kinematic simulator (``formation-ilc-robot-sim``): the plant of every robot, in one process.

It speaks the plant contract of ``msgs_schema`` and nothing more: it integrates eq. (1) for
every robot with the scenario's initial-state shifts, input disturbances and output noises
(the plant stream of trial k, as the batch simulator draws it), publishes ``/clock`` and
each robot's measured pose (in the world frame, stamped with the sample's label), and
applies ``cmd_vel``. At each trial's end it also publishes the true trajectories (ground
truth, for the metrics' ``true_`` columns) and its timing on ``diagnostics``. While a viewer
takes it, a preview of the whole team's poses goes out at most ``msgs_schema.PREVIEW_HZ`` a
second (what the live view shows of a fast run).

* lockstep: sample t+1 is computed when every robot has commanded sample t, so a run goes
  as fast as the processes allow; if a robot stays silent for ``timeout`` seconds the
  simulator exits (status 3) naming the robots it waited for.
* realtime: a wall-clock timer advances one sample every dT, in phase with the trial's
  start. At each tick the simulator applies, per robot, the newest command that arrived
  since the previous tick; a robot with none holds its previous command (zero-order hold,
  0 at sample 0) and the sample is counted as missed for that robot (``missed`` in the
  diagnostics). ``cmd_vel`` carries no sample label, so a command that arrives after the
  tick it was meant for is applied at the next tick unless a newer one replaces it (what a
  robot base does with a Twist). ``timing`` reports the command arrival after the tick
  (p50/p90/p99/max over every command), the all-in latency per sample, and how late the
  timer itself fired.

Trials follow the leader's events (``formation_ilc.protocol.schedule``): ``start`` names the
iteration (whose plant stream is drawn) and the slot (whose labels the poses carry); on
``abort`` the simulator drops the trial and reports ready.

The links between robots are not part of the plant: with ``links: emulated`` the link
emulator (``formation-ilc-link-emulator``) is its own process; with ``links: direct`` the robots
talk to each other.

A ``start`` event is obeyed only for the trial after the current one, once the simulator
has said ready for it and is not inside a trial; any other (a replay, a later trial, a
second start) is dropped and counted (``dropped`` in its diagnostics), by the rule every
follower of the schedule applies (``formation_ilc.protocol.schedule.Follower``).

Everything it decides is in ``formation_ilc.protocol.plant.KinematicPlant``; this node reads
its parameters, decodes and publishes, and makes one call into the plant per event.

Parameters: ``timeout`` [s] (lockstep; default: the run configuration's). The run
configuration comes from the latched ``config`` topic.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.config import params
from formation_ilc.core.clock import Rejected
from formation_ilc.nodes.common import (
    ConfiguredNode,
    RunConfig,
    fail,
    matched,
    node_parser,
    spin_main,
    unmatched,
)
from formation_ilc.nodes.frames import Frame, Frames, describe_body
from formation_ilc.nodes.params import declare, effective
from formation_ilc.protocol.plant import RESEND_S, KinematicPlant, Sample

#: the plant's node name (what it says ready as)
NAME = ms.SIM_NODE
#: [s] while the preview has no reader, how often the simulator asks again
PREVIEW_ASK_S = 0.5


class SimNode(ConfiguredNode):
    """The kinematic simulator of all robots.

    Another plant with this node's schedule, timing and publishing (the physics plant,
    ``robot_sim.physics_node``) subclasses it with its own ``name`` and ``make_plant``.
    """

    def __init__(self, name: str = NAME, **kwargs: Any):
        super().__init__(name, **kwargs)
        declare(self, params.SIM)
        self.declare_plant_parameters()
        self.follow_config()

    def declare_plant_parameters(self) -> None:
        """The plant's own parameters (a subclass's)."""

    def make_plant(self, cfg: RunConfig) -> KinematicPlant:
        """The plant core of run ``cfg`` (ValueError: the node refuses the run)."""
        return KinematicPlant(cfg)

    def body_name(self) -> str:
        """The robots' body (``config.urdf``): the safety filter's, else a Pioneer 3-DX."""
        return self.cfg.safety.body if self.cfg.safety is not None else "p3dx"

    def report(self) -> dict[str, Any]:
        """The trial's diagnostics."""
        return self.plant.report()

    def configure(self, cfg: RunConfig) -> None:
        self.plant = plant = self.make_plant(cfg)
        self.follower = plant.follower
        self.cfg = cfg
        n = plant.n
        timeout = float(self.get_parameter("timeout").value)
        self.timeout = timeout if timeout > 0 else cfg.timeout
        effective(self, {"timeout": float(self.timeout)})  # the parameter reads what runs
        self.realtime = plant.realtime
        self.pose_pubs = [self.create_publisher(PoseStamped, ms.pose_topic(r + 1), ms.SAMPLE_QOS)
                          for r in range(n)]
        self.true_pubs = [self.create_publisher(Path, ms.true_trajectory_topic(r + 1),
                                                ms.TRAJECTORY_QOS) for r in range(n)]
        self.clock_pub = self.create_publisher(Clock, ms.CLOCK, ms.CLOCK_QOS)
        self.preview_pub = self.create_publisher(Path, ms.PREVIEW, ms.PREVIEW_QOS)
        self._preview_due = 0.0
        # every robot's pose of a sample in one message, for the robots' safety filters
        self.team_pub = (self.create_publisher(Path, ms.TEAM_POSES, ms.SAMPLE_QOS)
                         if cfg.safety is not None and cfg.safety.sensing == "team" else None)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        # the frames: robot_i/odom is map (its poses are measurements in map), and each
        # sample's measured pose is robot_i/base_link in it (nodes.frames)
        self.frames = Frames(self, [Frame(ms.WORLD_FRAME, ms.odom_frame(r + 1), 0.0, 0.0, 0.0)
                                    for r in range(n)])
        # each robot's body, latched, for viewers (config.urdf)
        self.body_pubs = [describe_body(self, r + 1, self.body_name()) for r in range(n)]
        self.cmd_subs = [  # bytes: msgs_schema.wire
            self.create_subscription(Twist, ms.cmd_vel_topic(r + 1),
                                     lambda m, r=r: self._on_cmd(m, r), ms.SAMPLE_QOS, raw=True)
            for r in range(n)]
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        self._gate = self.create_timer(0.05, self._check_ready)
        if self.realtime:
            # started (reset) at each trial's start, so ticks are in phase with sample 0
            self._tick = self.create_timer(cfg.scenario.dt, self._on_wall_tick)
            self._tick.cancel()
        else:
            self.create_timer(min(1.0, self.timeout / 4), self._watchdog)
            self.create_timer(RESEND_S / 4, self._resend)

    def _check_ready(self) -> None:
        need: list[tuple[Any, int | tuple[str, ...]]] = [(p, 1) for p in self.pose_pubs]
        need += [(self.clock_pub, 1), (self.ready_pub, 1)]
        if self.team_pub is not None:  # every robot filters with it
            need.append((self.team_pub, tuple(ms.robot_name(r + 1)
                                              for r in range(self.plant.n))))
        need += [(s, 1) for s in self.cmd_subs]  # both ends matched: no first command lost
        # every reader of the results by name (RunConfig.result_readers): a count would
        # let the recorder stand in for a monitor not yet matched, or the other way round
        need += [(p, self.cfg.result_readers) for p in self.true_pubs]
        if matched(need, self):
            self._gate.cancel()
            self._say_ready(0)
            return
        self.not_ready(unmatched(need, self))

    def _say_ready(self, trial: int) -> None:
        self.ready_pub.publish(self.ready_msg(trial))

    def _on_event(self, msg: String) -> None:
        plant = self.plant
        ev = self.take_event(msg, lambda ev: plant.on_event(ev, time.perf_counter()))
        if ev is None:
            return
        if ev.event == ms.ABORT:
            if self.realtime and not plant.in_trial:
                self._tick.cancel()
            if self._gate.is_canceled():
                self._say_ready(plant.iteration + 1)
            return
        if self.realtime:
            self._tick.reset()
        self._publish_sample()

    def _publish_sample(self) -> None:
        plant = self.plant
        s = plant.sample()
        if s.last:
            # ground truth and diagnostics before the last poses: the robots finish the trial
            # on those poses, and a monitor that stops the run after the robots' last word
            # must already have this node's
            stamps = plant.stamps()
            for r in range(plant.n):
                self.true_pubs[r].publish(ms.wire.path_bytes(plant.xi[r], stamps,
                                                             ms.WORLD_FRAME))
            d = {"node": self.get_name(), **self.report()}
            d.update(self.drops.as_dict())
            self.diag_pub.publish(ms.diagnostics_to_msg(
                d, self.get_clock().now().nanoseconds, self.cfg.scenario.dt,
                self.cfg.scenario.samples))
        self._send(s)
        if s.last:
            self._say_ready(plant.iteration + 1)
            return
        plant.sent(time.perf_counter())

    def _on_cmd(self, msg: Twist | bytes, r: int) -> None:
        try:
            u = ms.wire.read_twist(ms.wire.as_bytes(msg))
        except ms.MalformedMessage as exc:
            self.drops.reject(exc, ms.cmd_vel_topic(r + 1))
            return
        try:
            due = self.plant.command(r, u, time.perf_counter())
        except Rejected as exc:
            self.drops.reject(exc, f"robot_{r + 1}/cmd_vel")
            return
        if due:
            self._publish_sample()

    def _on_wall_tick(self) -> None:
        if not self.plant.tick(time.perf_counter()):
            self._tick.cancel()
            return
        self._publish_sample()

    def _resend(self) -> None:
        """Lockstep: the current sample again (its /clock, every pose) when a command is
        still due RESEND_S after it went out (protocol.plant): what a lost message held
        comes back without waiting for the time-out."""
        if not self.plant.resend_due(time.perf_counter()):
            return
        self._send(self.plant.sample())

    def _send(self, s: Sample) -> None:
        """A sample's /clock and every pose, as bytes (msgs_schema.wire)."""
        self.clock_pub.publish(ms.wire.clock_bytes(s.stamp_ns))
        if self.team_pub is not None:
            self.team_pub.publish(ms.wire.pose_set_bytes(s.stamp_ns, [
                ms.wire.raw_pose(s.eta[r], s.stamp_ns, ms.WORLD_FRAME)
                for r in range(self.plant.n)]))
        for r in self.plant.send_order:
            self.pose_pubs[r].publish(ms.wire.pose_bytes(s.eta[r], s.stamp_ns, ms.WORLD_FRAME))
        self.frames.publish(s.stamp_ns, [
            Frame(ms.odom_frame(r + 1), ms.base_frame(r + 1), *s.eta[r])
            for r in range(self.plant.n)])
        now = time.monotonic()
        if now >= self._preview_due:
            self._preview(s, now)

    def _preview(self, s: Sample, now: float) -> None:
        """The team's poses of this sample on the preview (``msgs_schema.PREVIEW``): at most
        PREVIEW_HZ a second, and while nobody takes it, its readers asked twice a second."""
        if not self.preview_pub.get_subscription_count():
            self._preview_due = now + PREVIEW_ASK_S
            return
        self._preview_due = now + 1.0 / ms.PREVIEW_HZ
        self.preview_pub.publish(ms.wire.pose_set_bytes(s.stamp_ns, [
            ms.wire.raw_pose(s.eta[r], s.stamp_ns, ms.WORLD_FRAME) for r in range(self.plant.n)]))

    def _watchdog(self) -> None:
        late = self.plant.overdue(time.perf_counter(), self.timeout)
        if late:
            who = ", ".join(ms.robot_name(r + 1) for r in late)
            fail(self, f"lockstep timeout: waited {self.timeout:.1f} s at trial {self.plant.k} "
                       f"sample {self.plant.t} for cmd_vel of {who}")


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [SimNode()], node_parser("formation-ilc-robot-sim", __doc__),
                     args)


if __name__ == "__main__":
    sys.exit(main())
