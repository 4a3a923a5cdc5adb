"""Kinematic simulator and link emulator (``formation-ilc-sim``), one process, one executor.

``robot_sim`` integrates eq. (1) for every robot with the scenario's initial-state shifts,
input disturbances and output noises (the plant stream of trial k, as the batch simulator
draws it), publishes ``/clock`` and each robot's measured pose, and reads ``cmd_vel``.

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

``link_emulator`` carries the scenario's delay model on the robot-to-robot links (the
delay stream of trial k): at tick t it delivers to robot i, on each in-link, the sender's
shared pose labelled t - tau, with its original label, and the leader's reference
labelled t - tau0, as one bundle per robot and tick. It reports the injected delay
histograms on ``/formation/diagnostics``. Lockstep: tick t's bundles go out when every
robot's sample-t pose and the reference are in. Realtime: the tick is ``/clock``; robot
i's bundle goes out as soon as the poses it needs are in, at the latest ``DELIVERY_WAIT``
dT after the tick, without the ones still missing (counted as ``late`` per link; they are
not in ``injected``, so the robots' eq. (11) measurements still equal ``injected``).

Parameters: ``timeout`` [s] (lockstep). The run configuration comes from /formation/config.
"""

from __future__ import annotations

import sys
import time
from collections import Counter
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from rclpy.node import Node
from rosgraph_msgs.msg import Clock
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.kinematics import step_into
from formation_ilc.nodes.common import (
    DropCounter,
    RunConfig,
    config_from_msg,
    fail,
    matched,
    spin_main,
    warm_up,
)
from formation_ilc.simulate import Problem

#: realtime: the link emulator sends a bundle at the latest this many dT after the tick
DELIVERY_WAIT = 0.5


class _Configured(Node):
    """A node that builds itself from the latched run configuration."""

    def __init__(self, name: str, **kwargs: Any):
        super().__init__(name, namespace=ms.NAMESPACE, **kwargs)
        self.drops = DropCounter(self)
        self.configured = False
        self._cfg_sub = self.create_subscription(String, ms.CONFIG, self._on_config,
                                                 ms.LATCHED_QOS)

    def _on_config(self, msg: String) -> None:
        if self.configured:
            return
        cfg = config_from_msg(msg, self.drops)
        if cfg is not None:
            self.configured = True
            self.configure(cfg)

    def configure(self, cfg: RunConfig) -> None:
        raise NotImplementedError


class SimNode(_Configured):
    """The kinematic simulator of all robots."""

    def __init__(self, **kwargs: Any):
        super().__init__("robot_sim", **kwargs)
        self.declare_parameter("timeout", 0.0)

    def configure(self, cfg: RunConfig) -> None:
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
        self.k = -1
        self.t = -1
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
            self.ready_pub.publish(ms.json_to_msg({"node": "robot_sim", "trial": 0}))

    def _on_event(self, msg: String) -> None:
        try:
            ev = ms.msg_to_json(msg, ("event", "trial"))
            k = int(ev["trial"])
        except (ms.MalformedMessage, TypeError, ValueError) as exc:
            self.drops.drop("malformed", "trial_events", str(exc))
            return
        if ev["event"] != ms.START:
            return
        if k <= self.k or self.in_trial:
            self.drops.drop("stale", "trial_events", f"start of trial {k} in trial {self.k}")
            return
        self.k = k
        pb = self.pb
        shift, self.dist, self.noise = self.unc.draw_plant(self.cfg.scenario.seed, k, pb.n,
                                                           pb.samples)
        self.xi[:, 0] = pb.eta_d[:, 0] + shift
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
        self.eta[:, t] = self.xi[:, t] + self.noise[:, t]
        if t == self.T:
            # ground truth and diagnostics before the last poses: the robots finish the trial
            # on those poses, and a monitor that stops the run after the robots' last word
            # must already have this node's
            self.in_trial = False
            stamps = [self.clock.stamp_ns(k, s) for s in range(self.T + 1)]
            for r in range(self.n):
                self.true_pubs[r].publish(ms.trajectory_to_path(self.xi[r], stamps,
                                                                ms.robot_name(r + 1)))
            self.trial_time += time.perf_counter() - self.trial_t0
            self.samples_done += self.T
            d = {"node": "robot_sim", "trial": k, "mode": self.cfg.mode,
                 "missed": dict(self.missed), "timing": self._timing()}
            d.update(self.drops.as_dict())
            self.diag_pub.publish(ms.json_to_msg(d))
        self.clock_pub.publish(ms.clock_msg(ns))
        for r in range(self.n):
            self.pose_pubs[r].publish(ms.pose_to_msg(self.eta[r, t], ns, ms.robot_name(r + 1),
                                                     self.pose_msgs[r]))
        if t == self.T:
            self.ready_pub.publish(ms.json_to_msg({"node": "robot_sim", "trial": k + 1}))
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
            self.drops.drop("malformed", f"robot_{r + 1}/cmd_vel", str(exc))
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
        step_into(self.xi[:, t], self.u[:, t], self.dist[:, t], self.pb.dt, self.xi[:, t + 1])
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
        step_into(self.xi[:, t], self.u[:, t], self.dist[:, t], self.pb.dt, self.xi[:, t + 1])
        self.t = t + 1
        self._publish_sample()

    def _watchdog(self) -> None:
        if self.in_trial and self.pending and \
                time.perf_counter() - self.wait_start > self.timeout:
            who = ", ".join(ms.robot_name(r + 1) for r in sorted(self.pending))
            fail(self, f"lockstep timeout: waited {self.timeout:.1f} s at trial {self.k} "
                       f"sample {self.t} for cmd_vel of {who}")


class LinkEmulator(_Configured):
    """The robot-to-robot links, with the scenario's delays in simulated time."""

    def __init__(self, **kwargs: Any):
        super().__init__("link_emulator", **kwargs)

    def configure(self, cfg: RunConfig) -> None:
        sc = cfg.scenario
        pb = Problem.from_scenario(sc)
        self.cfg, self.pb, self.clock = cfg, pb, cfg.clock
        n, n_t = pb.n, pb.samples
        self.n, self.T = n, n_t
        self.k = -1
        self.realtime = cfg.mode == "realtime"
        self.injected: dict[str, Counter[int]] = {}
        self.late: dict[str, int] = {}  # realtime: deliveries not in by the deadline
        for i in range(n):
            for j in pb.src[i]:
                if j >= 0:
                    self.injected[f"{ms.robot_name(j + 1)}->{ms.robot_name(i + 1)}"] = Counter()
            if pb.leader[i] != 0.0:
                self.injected[f"{ms.LEADER_FRAME}->{ms.robot_name(i + 1)}"] = Counter()
        self.late = {link: 0 for link in self.injected}
        self.waiting: dict[int, int] = {}  # realtime: receiver -> tick it still waits for
        self.bundle_pubs = [self.create_publisher(Path, ms.neighbour_poses_topic(i + 1),
                                                  ms.SAMPLE_QOS) for i in range(n)]
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.diag_pub = self.create_publisher(String, ms.DIAGNOSTICS, ms.LATCHED_QOS)
        for j in range(n):
            self.create_subscription(PoseStamped, ms.shared_pose_topic(j + 1),
                                     lambda m, j=j: self._on_shared(m, j), ms.SAMPLE_QOS)
        self.create_subscription(PoseStamped, ms.REFERENCE, self._on_reference, ms.SAMPLE_QOS)
        if self.realtime:
            self.create_subscription(Clock, ms.CLOCK, self._on_clock, ms.CLOCK_QOS)
            self._deadline = self.create_timer(DELIVERY_WAIT * sc.dt, self._on_deadline)
            self._deadline.cancel()
        self._gate = self.create_timer(0.02, self._check_ready)

    def _check_ready(self) -> None:
        if matched([(p, 1) for p in self.bundle_pubs] + [(self.ready_pub, 1)]):
            self._gate.cancel()
            self.ready_pub.publish(ms.json_to_msg({"node": "link_emulator", "trial": 0}))

    def _start(self, k: int) -> None:
        self.k = k
        pb = self.pb
        self.tau, self.tau0 = self.cfg.scenario.uncertainty.draw_delays(
            self.cfg.scenario.seed, k, pb.n, pb.src.shape[1], pb.samples)
        self.shared: list[list[PoseStamped | None]] = [[None] * (self.T + 1)
                                                        for _ in range(self.n)]
        self.ref: list[PoseStamped | None] = [None] * (self.T + 1)
        self.count = np.zeros(self.T + 1, dtype=np.int64)
        self.next_t = 0
        self.waiting = {}
        self.reported = False

    def _label(self, msg: PoseStamped, frame: str, topic: str) -> tuple[int, int] | None:
        try:
            k, s = self.clock.decode(ms.stamp_to_ns(msg.header.stamp))
            if msg.header.frame_id != frame:
                raise ms.MalformedMessage(f"frame {msg.header.frame_id!r}, expected {frame}")
            ms.msg_to_pose(msg)
        except ms.MalformedMessage as exc:
            self.drops.drop("malformed", topic, str(exc))
            return None
        if k < self.k:
            self.drops.drop("stale", topic, f"label of trial {k} in trial {self.k}")
            return None
        if k > self.k:
            self._start(k)
        return k, s

    def _on_shared(self, msg: PoseStamped, j: int) -> None:
        name = ms.robot_name(j + 1)
        lab = self._label(msg, name, f"{name}/shared_pose")
        if lab is None:
            return
        s = lab[1]
        if self.shared[j][s] is not None or (s < self.next_t and not self.realtime):
            self.drops.drop("out_of_order", f"{name}/shared_pose", f"sample {s} again")
            return
        self.shared[j][s] = msg
        self.count[s] += 1
        if self.realtime:
            self._deliver_waiting()
        else:
            self._deliver()

    def _on_reference(self, msg: PoseStamped) -> None:
        lab = self._label(msg, ms.LEADER_FRAME, "leader/reference")
        if lab is None:
            return
        s = lab[1]
        if self.ref[s] is not None or (s < self.next_t and not self.realtime):
            self.drops.drop("out_of_order", "leader/reference", f"sample {s} again")
            return
        self.ref[s] = msg
        if self.realtime:
            self._deliver_waiting()
        else:
            self._deliver()

    def _deliver(self) -> None:
        pb = self.pb
        while self.next_t < self.T and self.count[self.next_t] == self.n \
                and self.ref[self.next_t] is not None:
            t = self.next_t
            tick = self.clock.stamp_ns(self.k, t)
            for i in range(self.n):
                poses = []
                to = ms.robot_name(i + 1)
                for ell in range(pb.src.shape[1]):
                    j = pb.src[i, ell]
                    if j < 0:
                        continue
                    tau = int(self.tau[i, ell, t])
                    if t - tau >= 0:
                        poses.append(self.shared[j][t - tau])
                        self.injected[f"{ms.robot_name(j + 1)}->{to}"][tau] += 1
                if pb.leader[i] != 0.0:
                    tau = int(self.tau0[i, t])
                    if t - tau >= 0:
                        poses.append(self.ref[t - tau])
                        self.injected[f"{ms.LEADER_FRAME}->{to}"][tau] += 1
                self.bundle_pubs[i].publish(ms.bundle_to_msg(tick, to, poses))
            self.next_t = t + 1
            if self.next_t == self.T:
                self._report()
                self.ready_pub.publish(ms.json_to_msg({"node": "link_emulator",
                                                       "trial": self.k + 1}))

    # ------------------------------------------------------------------ realtime
    def _on_clock(self, msg: Clock) -> None:
        try:
            k, t = self.clock.decode(ms.stamp_to_ns(msg.clock))
        except ms.MalformedMessage as exc:
            self.drops.drop("malformed", "clock", str(exc))
            return
        if k < self.k:
            self.drops.drop("stale", "clock", f"time of trial {k} in trial {self.k}")
            return
        if k > self.k:
            self._start(k)
        if self.waiting:  # the previous tick's deadline has not fired: it is over now
            self._on_deadline()
        if t >= self.T:
            return
        self.next_t = t
        self.waiting = {i: t for i in range(self.n)}
        self._deadline.reset()
        self._deliver_waiting()

    def _needs(self, i: int, t: int) -> list[tuple[str, PoseStamped | None, int]]:
        """(link, pose or None if not in yet, tau) of everything robot i gets at tick t."""
        pb, to = self.pb, ms.robot_name(i + 1)
        out: list[tuple[str, PoseStamped | None, int]] = []
        for ell in range(pb.src.shape[1]):
            j = pb.src[i, ell]
            if j < 0:
                continue
            tau = int(self.tau[i, ell, t])
            if t - tau >= 0:
                out.append((f"{ms.robot_name(j + 1)}->{to}", self.shared[j][t - tau], tau))
        if pb.leader[i] != 0.0:
            tau = int(self.tau0[i, t])
            if t - tau >= 0:
                out.append((f"{ms.LEADER_FRAME}->{to}", self.ref[t - tau], tau))
        return out

    def _deliver_waiting(self, force: bool = False) -> None:
        """Send every waiting bundle whose poses are in; with ``force``, the rest too,
        without the missing poses (counted late)."""
        for i, t in list(self.waiting.items()):
            needs = self._needs(i, t)
            if not force and any(m is None for _, m, _ in needs):
                continue
            poses = []
            for link, m, tau in needs:
                if m is None:
                    self.late[link] += 1
                else:
                    poses.append(m)
                    self.injected[link][tau] += 1
            to = ms.robot_name(i + 1)
            self.bundle_pubs[i].publish(ms.bundle_to_msg(self.clock.stamp_ns(self.k, t), to,
                                                         poses))
            del self.waiting[i]
        if not self.waiting:
            self._deadline.cancel()
            if self.next_t == self.T - 1 and not self.reported:
                # the trial's last bundles are out (as in lockstep, before sample T)
                self.reported = True
                self._report()
                self.ready_pub.publish(ms.json_to_msg({"node": "link_emulator",
                                                       "trial": self.k + 1}))

    def _on_deadline(self) -> None:
        self._deliver_waiting(force=True)

    def _report(self) -> None:
        d: dict[str, Any] = {"node": "link_emulator", "trial": self.k,
                             "injected": {link: {str(t): c for t, c in sorted(h.items())}
                                          for link, h in self.injected.items()}}
        if self.realtime:
            d["late"] = dict(self.late)
        d.update(self.drops.as_dict())
        self.diag_pub.publish(ms.json_to_msg(d))


def main(args: list[str] | None = None) -> int:
    return spin_main(lambda argv: [SimNode(), LinkEmulator()], args)


if __name__ == "__main__":
    sys.exit(main())
