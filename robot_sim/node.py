"""Kinematic simulator (``formation-ilc-sim``): the plant of every robot, in one process.

It speaks the plant contract of ``msgs_schema`` and nothing more: it integrates eq. (1) for
every robot with the scenario's initial-state shifts, input disturbances and output noises
(the plant stream of trial k, as the batch simulator draws it), publishes ``/clock`` and
each robot's measured pose (in the world frame, stamped with the sample's label), and
applies ``cmd_vel``. At each trial's end it also publishes the true trajectories (ground
truth, for the metrics' ``true_`` columns) and its timing on ``diagnostics``.

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
emulator (``formation-ilc-links``) is its own process; with ``links: direct`` the robots
talk to each other.

A ``start`` event is obeyed only for the trial after the current one, once the simulator
has said ready for it and is not inside a trial; any other (a replay, a later trial, a
second start) is dropped and counted (``dropped`` in its diagnostics).

Parameters: ``timeout`` [s] (lockstep; default: the run configuration's). The run
configuration comes from the latched ``config`` topic.
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.core.kinematics import step_into
from formation_ilc.model.simulate import Problem
from formation_ilc.nodes.common import (
    ConfiguredNode,
    RunConfig,
    fail,
    matched,
    node_parser,
    spin_main,
    warm_up,
)
from formation_ilc.protocol.schedule import unexplained_gap

#: the plant's node name (what it says ready as)
NAME = "robot_sim"


class SimNode(ConfiguredNode):
    """The kinematic simulator of all robots.

    Another plant that keeps this node's schedule, timing and publishing (the physics plant,
    ``robot_sim.physics_node``) subclasses it and replaces the plant's three steps:
    ``_place`` (a trial starts at xi[:, 0]), ``_plant_step`` (sample t to t+1 under
    u[:, t]) and ``_measure`` (the measured pose of sample t).
    """

    def __init__(self, name: str = NAME, **kwargs: Any):
        super().__init__(name, **kwargs)
        self.declare_parameter("timeout", 0.0)
        self.follow_config()

    def configure(self, cfg: RunConfig) -> None:
        if cfg.mode == "wallclock":
            raise ValueError("mode wallclock is for real robots behind bridges (no /clock); "
                             "the simulator runs lockstep or realtime")
        sc = cfg.scenario
        pb = Problem.from_scenario(sc)
        warm_up(pb)
        self.cfg, self.pb, self.clock = cfg, pb, cfg.clock
        self.unc = sc.uncertainty
        n, n_t = pb.n, pb.samples
        self.n, self.T = n, n_t
        timeout = float(self.get_parameter("timeout").value)
        self.timeout = timeout if timeout > 0 else cfg.timeout
        self.xi = np.zeros((n, n_t + 1, 3))
        self.eta = np.zeros((n, n_t + 1, 3))
        self.u = np.zeros((n, n_t, 2))
        self.k = -1            # slot of the current (or last) trial
        self.iteration = -1    # its iteration
        self.t = -1
        self.ready_for = -1               # the trial this node last said ready for
        self.pending: set[int] = set()
        self.in_trial = False
        self.wait_start = 0.0
        self.missed: Counter[str] = Counter()
        self.latency: list[float] = []   # [s] sample published -> every command in
        self.trial_time = 0.0            # [s] wall time inside trials
        self.samples_done = 0
        self.realtime = cfg.mode == "realtime"
        self.u_now = np.zeros((n, 2))     # realtime: newest command of each robot
        self.fresh = np.zeros(n, dtype=bool)
        self.arrival: list[float] = []    # [s] realtime: tick -> each command's arrival
        self.tick_lag: list[float] = []   # [s] realtime: timer callback after its due time
        self.late_cmds = 0                # realtime: commands after the trial's last tick
        self.superseded = 0               # realtime: commands replaced before their tick
        if self.realtime:
            self.missed.update({ms.robot_name(r + 1): 0 for r in range(n)})
        self.pose_msgs = [PoseStamped() for _ in range(n)]
        self.pose_pubs = [self.create_publisher(PoseStamped, ms.pose_topic(r + 1), ms.SAMPLE_QOS)
                          for r in range(n)]
        self.true_pubs = [self.create_publisher(Path, ms.true_trajectory_topic(r + 1),
                                                ms.TRAJECTORY_QOS) for r in range(n)]
        self.clock_pub = self.create_publisher(Clock, ms.CLOCK, ms.CLOCK_QOS)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.diag_pub = self.create_publisher(String, ms.DIAGNOSTICS, ms.LATCHED_QOS)
        for r in range(n):
            self.create_subscription(Twist, ms.cmd_vel_topic(r + 1),
                                     lambda m, r=r: self._on_cmd(m, r), ms.SAMPLE_QOS)
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        self._gate = self.create_timer(0.02, self._check_ready)
        if self.realtime:
            # started (reset) at each trial's start, so ticks are in phase with sample 0
            self._tick = self.create_timer(sc.dt, self._on_wall_tick)
            self._tick.cancel()
        else:
            self.create_timer(min(1.0, self.timeout / 4), self._watchdog)

    def _check_ready(self) -> None:
        need = [(p, 1) for p in self.pose_pubs] + [(self.clock_pub, 1), (self.ready_pub, 1)]
        need += [(p, int(self.cfg.monitored)) for p in self.true_pubs]
        if matched(need):
            self._gate.cancel()
            self._say_ready(0)

    def _say_ready(self, trial: int) -> None:
        self.ready_for = trial
        self.ready_pub.publish(self.ready_msg(trial))

    def _on_event(self, msg: String) -> None:
        ev = self.new_start_or_abort(msg)
        if ev is None:
            return
        if ev.event == ms.ABORT:
            self.seen = ev.seq
            if ev.slot == self.k:
                self.in_trial = False
                self.pending = set()
                if self.realtime:
                    self._tick.cancel()
            if self._gate.is_canceled():
                self._say_ready(self.iteration + 1)
            return
        # the next slot (any, for a process that has just started: the leader may have
        # aborted slots meanwhile), between trials, once this node said ready
        if unexplained_gap(self.k, ev.slot, self.aborted_slots):
            self.drops.drop("future", ms.TRIAL_EVENTS, f"start of slot {ev.slot} in {self.k}")
            return
        if ev.slot <= self.k or self.in_trial or self.ready_for <= self.iteration:
            self.drops.drop("stale" if ev.slot <= self.k else "unexpected", ms.TRIAL_EVENTS,
                            f"start of slot {ev.slot} in slot {self.k}"
                            f"{' (running)' if self.in_trial else ''}")
            return
        self.seen = ev.seq
        self.k = ev.slot
        self.iteration = ev.trial
        pb = self.pb
        # the plant stream of the iteration, as the batch simulator draws it
        shift, self.dist, self.noise = self.unc.draw_plant(self.cfg.scenario.seed, ev.trial,
                                                           pb.n, pb.samples)
        self.xi[:, 0] = pb.eta_d[:, 0] + shift
        self._place()
        self.u[:] = 0.0
        self.t = 0
        self.in_trial = True
        self.trial_t0 = time.perf_counter()
        if self.realtime:
            self.u_now[:] = 0.0
            self.fresh[:] = False
            self._tick.reset()
            self.tick_due = self.trial_t0 + pb.dt
        self._publish_sample()

    def _publish_sample(self) -> None:
        t, k = self.t, self.k
        ns = self.clock.stamp_ns(k, t)
        self._measure(t)
        if t == self.T:
            # ground truth and diagnostics before the last poses: the robots finish the trial
            # on those poses, and a monitor that stops the run after the robots' last word
            # must already have this node's
            self.in_trial = False
            stamps = [self.clock.stamp_ns(k, s) for s in range(self.T + 1)]
            for r in range(self.n):
                self.true_pubs[r].publish(ms.trajectory_to_path(self.xi[r], stamps,
                                                                ms.WORLD_FRAME))
            self.trial_time += time.perf_counter() - self.trial_t0
            self.samples_done += self.T
            d = {"node": self.get_name(), "trial": self.iteration, "slot": k,
                 "mode": self.cfg.mode, "missed": dict(self.missed), "timing": self._timing()}
            d.update(self._trial_report())
            d.update(self.drops.as_dict())
            self.diag_pub.publish(ms.json_to_msg(d))
        self.clock_pub.publish(ms.clock_msg(ns))
        for r in range(self.n):
            self.pose_pubs[r].publish(ms.pose_to_msg(self.eta[r, t], ns, ms.WORLD_FRAME,
                                                     self.pose_msgs[r]))
        if t == self.T:
            self._say_ready(self.iteration + 1)
            return
        self.pending = set(range(self.n))
        self.wait_start = time.perf_counter()

    def _timing(self) -> dict[str, Any]:
        # lockstep: publish -> every command in; realtime: tick -> each command's arrival
        lat = np.array(self.arrival if self.realtime else self.latency) * 1e3
        if lat.size == 0:
            lat = np.full(1, np.nan)
        tim = {"samples": self.samples_done, "seconds": self.trial_time,
               "samples_per_s": self.samples_done / max(self.trial_time, 1e-9),
               "p50_ms": float(np.percentile(lat, 50)),
               "p90_ms": float(np.percentile(lat, 90)),
               "p99_ms": float(np.percentile(lat, 99)),
               "max_ms": float(lat.max())}
        if self.realtime:
            all_in = np.array(self.latency or [np.nan]) * 1e3
            lag = np.array(self.tick_lag or [np.nan]) * 1e3
            tim.update({"commands": len(self.arrival),
                        "missed_total": int(sum(self.missed.values())),
                        "all_in_p50_ms": float(np.percentile(all_in, 50)),
                        "all_in_p99_ms": float(np.percentile(all_in, 99)),
                        "tick_lag_p50_ms": float(np.percentile(lag, 50)),
                        "tick_lag_p99_ms": float(np.percentile(lag, 99)),
                        "tick_lag_max_ms": float(lag.max()),
                        "late_commands": self.late_cmds, "superseded": self.superseded})
        return tim

    def _on_cmd(self, msg: Twist, r: int) -> None:
        try:
            u = ms.twist_to_u(msg)
        except ms.MalformedMessage as exc:
            self.drops.reject(exc, ms.cmd_vel_topic(r + 1))
            return
        if self.realtime:
            self._on_cmd_realtime(u, r)
            return
        if not self.in_trial or r not in self.pending:
            self.drops.drop("out_of_order", f"robot_{r + 1}/cmd_vel",
                            f"a second command for sample {self.t}")
            return
        self.u[r, self.t] = u
        self.pending.discard(r)
        if not self.pending and self.cfg.mode == "lockstep":
            self._advance()

    def _advance(self) -> None:
        t = self.t
        self.latency.append(time.perf_counter() - self.wait_start)
        self._plant_step(t)
        self.t = t + 1
        self._publish_sample()

    def _on_cmd_realtime(self, u: np.ndarray, r: int) -> None:
        if not self.in_trial:
            self.late_cmds += 1  # for the trial's last sample, after its last tick
            return
        if self.fresh[r]:
            self.superseded += 1
        else:
            now = time.perf_counter()
            self.arrival.append(now - self.wait_start)
            self.pending.discard(r)
            if not self.pending:
                self.last_in = now - self.wait_start
        self.u_now[r] = u
        self.fresh[r] = True

    def _on_wall_tick(self) -> None:
        if not self.in_trial:
            self._tick.cancel()
            return
        now = time.perf_counter()
        self.tick_lag.append(now - self.tick_due)
        self.tick_due += self.pb.dt
        for r in np.flatnonzero(~self.fresh):
            self.missed[ms.robot_name(int(r) + 1)] += 1
        t = self.t
        self.u[:, t] = self.u_now  # newest command, or the held one for a robot that missed
        self.fresh[:] = False
        if not self.pending:
            self.latency.append(self.last_in)
        self._plant_step(t)
        self.t = t + 1
        self._publish_sample()

    # ------------------------------------------------------------------ the plant itself
    def _place(self) -> None:
        """A trial starts at xi[:, 0] (the kinematic state is xi itself)."""

    def _plant_step(self, t: int) -> None:
        """xi[:, t + 1] from xi[:, t] under u[:, t] and the input disturbance (eq. 1)."""
        step_into(self.xi[:, t], self.u[:, t], self.dist[:, t], self.pb.dt, self.xi[:, t + 1])

    def _measure(self, t: int) -> None:
        """The measured pose of sample t: the true state plus the output noise."""
        self.eta[:, t] = self.xi[:, t] + self.noise[:, t]

    def _trial_report(self) -> dict[str, Any]:
        """More diagnostics at a trial's end (a subclass's)."""
        return {}

    def _watchdog(self) -> None:
        if self.in_trial and self.pending and \
                time.perf_counter() - self.wait_start > self.timeout:
            who = ", ".join(ms.robot_name(r + 1) for r in sorted(self.pending))
            fail(self, f"lockstep timeout: waited {self.timeout:.1f} s at trial {self.k} "
                       f"sample {self.t} for cmd_vel of {who}")


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda ns, argv: [SimNode()], node_parser("formation-ilc-sim", __doc__),
                     args)


if __name__ == "__main__":
    sys.exit(main())
