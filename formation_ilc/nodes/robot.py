"""Robot node: one robot's distributed learning controller (``formation-ilc-robot``).

Parameters
----------
robot_id : int
    1-based robot number (topics under ``/formation/robot_<id>/``).
scenario : str
    Scenario name or YAML file. Empty (default): take the run configuration from
    ``/formation/config`` (latched, published by the virtual leader).
seed, noise, delay : used only with ``scenario`` (as for ``formation-ilc simulate``).

Per sample t of trial k: the measured pose arrives on ``pose`` (its stamp is the robot's
clock Rt for sample t), is shared with the neighbours on ``shared_pose`` (stamp = send label
St), the links deliver a bundle of labelled neighbour poses on ``neighbour_poses``; the node
measures every link's delay by eq. (11) from Rt and St, calls the core's ``law.command``
for its one robot and publishes ``cmd_vel``. At sample T it sends its whole trajectory on
``trajectory``; when it has its neighbours' trial-k trajectories it calls ``law.learn``
for its next memory and reports ready for trial k+1. Malformed, stale and out-of-order
messages are dropped and counted (``/formation/diagnostics``).

Realtime mode (the simulator ticks on the wall clock): the robot waits for sample t's
bundle at most ``BUNDLE_WAIT`` dT after its pose t arrived. If the bundle is late, it
commands with nothing delivered at t (the law's eq. (10) case: on those links it uses no
neighbour information this sample, as when the network delivers nothing) and counts it in
``late['bundle']``; the bundle is dropped when it comes (``late['bundle_after_command']``).
A bundle that comes before its pose is kept until the pose arrives. If the pose t+1 comes
before the robot could command sample t (its process was starved), sample t is counted in
``missed``, nothing is sent for it, and the robot records the previous command as applied
(the simulator's zero-order hold) for its learning. ``cmd_vel`` has no label, so a command
for t that reaches the simulator after its tick t+1 is applied at t+1 while this robot
records it at t: the simulator's ``missed`` counter names the robot when that happens.

Container mode: ``formation-ilc-robot --robots 1 2 3`` runs three robot nodes (each with
its own memory) in one process on one executor.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from typing import Any

import numpy as np
from geometry_msgs.msg import PoseStamped, Twist
from nav_msgs.msg import Path
from rclpy.node import Node
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.delays import measure_delay_ns
from formation_ilc.law import command, learn
from formation_ilc.nodes.common import (
    DropCounter,
    RunConfig,
    config_from_msg,
    make_config,
    matched,
    spin_main,
)
from formation_ilc.nodes.common import warm_up as _warm_up
from formation_ilc.simulate import Problem

#: realtime: how long [dT] a robot waits for a sample's bundle after its pose
BUNDLE_WAIT = 0.75


class RobotNode(Node):
    """One robot's controller. ``robot_id`` may be given here (container mode) or as the
    ROS parameter of the same name; ``**kwargs`` go to ``Node`` (context=,
    parameter_overrides=, ...)."""

    def __init__(self, robot_id: int | None = None, **kwargs: Any):
        super().__init__(ms.robot_name(robot_id) if robot_id else "robot",
                         namespace=ms.NAMESPACE, **kwargs)
        self.declare_parameter("robot_id", int(robot_id or 0))
        self.declare_parameter("scenario", "")
        self.declare_parameter("seed", -1)
        self.declare_parameter("noise", True)
        self.declare_parameter("delay", True)
        self.id = int(self.get_parameter("robot_id").value)
        if self.id < 1:
            raise ValueError("parameter robot_id: a robot number >= 1 is required")
        self.name = ms.robot_name(self.id)
        self.drops = DropCounter(self)
        self.configured = False
        self.ready_sent = -1
        scenario = str(self.get_parameter("scenario").value)
        if scenario:
            seed = int(self.get_parameter("seed").value)
            self._configure(make_config(scenario, seed=None if seed < 0 else seed,
                                        noise=bool(self.get_parameter("noise").value),
                                        delay=bool(self.get_parameter("delay").value)))
        else:
            self._config_sub = self.create_subscription(String, ms.CONFIG, self._on_config,
                                                        ms.LATCHED_QOS)

    # ------------------------------------------------------------------ set-up
    def _on_config(self, msg: String) -> None:
        if self.configured:
            return
        cfg = config_from_msg(msg, self.drops)
        if cfg is not None:
            self._configure(cfg)

    def _configure(self, cfg: RunConfig) -> None:
        sc = cfg.scenario
        if self.id > sc.n:
            raise ValueError(f"robot_id {self.id}: the scenario has robots 1..{sc.n}")
        pb = Problem.from_scenario(sc)
        self.cfg, self.pb, self.clock = cfg, pb, cfg.clock
        i = self.id - 1
        self.i, self.sl = i, slice(i, i + 1)
        n_t, n_l = pb.samples, pb.src.shape[1]
        self.T = n_t
        self.links = {ms.robot_name(int(j) + 1): ell for ell, j in enumerate(pb.src[i]) if j >= 0}
        self.link_src = {ell: int(j) for ell, j in enumerate(pb.src[i]) if j >= 0}
        self.sees_leader = bool(pb.leader[i] != 0.0)
        self.n_out = int(sum(1 for r in range(pb.n) if r != i and i in pb.src[r]))
        # learning memory and this trial's arrays, batch axis R = 1 for the core's kernels
        self.memory = np.zeros((1, n_t, 2))
        self.next_memory = np.zeros((1, n_t, 2))
        self.applied = np.zeros((1, n_t, 2))
        self.eta = np.zeros((1, n_t + 1, 3))
        self.nb_eta = np.zeros((1, n_l, 3))
        self.nb_s = np.full((1, n_l), -1, dtype=np.int64)
        self.lead_s = np.full(1, -1, dtype=np.int64)
        self.nb_full = np.zeros((1, n_l, n_t + 1, 3))
        self.u = np.zeros((1, 2))
        self.twist = Twist()
        self.own_msgs: list[PoseStamped | None] = [None] * (n_t + 1)
        self.k = -1          # current trial
        self.t = -1          # current sample (own pose received)
        self.commanded = True
        self.rt_ns = 0       # Rt: the robot's clock at the current sample
        self.finished = -1   # last trial whose own trajectory was sent
        self.learned = -1    # last trial learned from
        self.trajs: dict[int, dict[int, np.ndarray]] = {}
        self.delays: dict[str, Counter[int]] = {s: Counter() for s in self.links}
        if self.sees_leader:
            self.delays[ms.LEADER_FRAME] = Counter()
        self.missed = 0
        self.commands = 0
        self.realtime = cfg.mode == "realtime"
        self.late: Counter[str] = Counter({"bundle": 0, "bundle_after_command": 0})
        self.early: Path | None = None  # realtime: a bundle that came before its pose
        _warm_up(pb)

        name = self.name
        self.cmd_pub = self.create_publisher(Twist, ms.cmd_vel_topic(self.id), ms.SAMPLE_QOS)
        self.shared_pub = self.create_publisher(PoseStamped, ms.shared_pose_topic(self.id),
                                                ms.SAMPLE_QOS)
        self.traj_pub = self.create_publisher(Path, ms.trajectory_topic(self.id),
                                              ms.TRAJECTORY_QOS)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.diag_pub = self.create_publisher(String, ms.DIAGNOSTICS, ms.LATCHED_QOS)
        self.create_subscription(PoseStamped, ms.pose_topic(self.id), self._on_pose,
                                 ms.SAMPLE_QOS)
        self.create_subscription(Path, ms.neighbour_poses_topic(self.id), self._on_bundle,
                                 ms.SAMPLE_QOS)
        for sender, ell in self.links.items():
            self.create_subscription(
                Path, ms.trajectory_topic(self.link_src[ell] + 1),
                lambda m, ell=ell, sender=sender: self._on_trajectory(m, ell, sender),
                ms.TRAJECTORY_QOS)
        if self.realtime:
            self._deadline = self.create_timer(BUNDLE_WAIT * sc.dt, self._on_deadline)
            self._deadline.cancel()
        self.configured = True
        self._gate = self.create_timer(0.02, self._check_ready)
        self.get_logger().info(f"{name}: {len(self.links)} in-links"
                               f"{' + leader' if self.sees_leader else ''}, "
                               f"{self.n_out} out-neighbours, {n_t} samples")

    def _check_ready(self) -> None:
        """Ready for trial 0 once every publisher has its readers (nothing published before
        a reader is matched can be lost)."""
        need = [(self.cmd_pub, 1), (self.shared_pub, 1), (self.ready_pub, 1),
                (self.traj_pub, self.n_out + int(self.cfg.monitored))]
        if matched(need):
            self._gate.cancel()
            self._send_ready(0)

    def _send_ready(self, trial: int) -> None:
        self.ready_sent = trial
        self.ready_pub.publish(ms.json_to_msg({"node": self.name, "trial": trial}))

    # ------------------------------------------------------------------ per sample
    def _on_pose(self, msg: PoseStamped) -> None:
        topic = "pose"
        try:
            ns = ms.stamp_to_ns(msg.header.stamp)
            k, s = self.clock.decode(ns)
            if msg.header.frame_id != self.name:
                raise ms.MalformedMessage(f"frame {msg.header.frame_id!r} is not {self.name}")
            eta, _, _ = ms.msg_to_pose(msg, float(self.pb.eta_d[self.i, s, 2]))
        except ms.MalformedMessage as exc:
            self.drops.drop("malformed", topic, str(exc))
            return
        if k < self.k or (k == self.k and s <= self.t):
            self.drops.drop("stale", topic, f"sample ({k}, {s}) after ({self.k}, {self.t})")
            return
        if self.realtime:
            self._on_pose_realtime(msg, eta, ns, k, s)
            return
        if k > self.k:
            if s != 0 and self.cfg.mode == "lockstep":
                self.drops.drop("out_of_order", topic, f"trial {k} starts at sample {s}")
                return
            self._new_trial(k)
        elif s != self.t + 1:
            if self.cfg.mode == "lockstep":
                self.drops.drop("out_of_order", topic, f"sample {s} while {self.t + 1} is due")
                return
            self.missed += s - self.t - 1
        if not self.commanded and self.t >= 0:
            self.missed += 1  # realtime: the previous sample's bundle never came in time
        self.t = s
        self.rt_ns = ns
        self.eta[0, s] = eta
        self.own_msgs[s] = msg
        if s < self.T:
            self.commanded = False
            self.shared_pub.publish(msg)  # the same bits, the same label St
        else:
            self.commanded = True
            self._finish_trial()

    def _on_pose_realtime(self, msg: PoseStamped, eta: np.ndarray, ns: int, k: int,
                          s: int) -> None:
        if k > self.k:
            self._new_trial(k)
        elif not self.commanded:  # the pose t+1 overtook our command for t
            self.missed += 1
            self._hold(self.t)
        for skipped in range(self.t + 1, s):  # poses that never came
            self.missed += 1
            self._hold(skipped)
        self.t = s
        self.rt_ns = ns
        self.eta[0, s] = eta
        self.own_msgs[s] = msg
        if s == self.T:
            self.commanded = True
            self._deadline.cancel()
            self._finish_trial()
            return
        self.commanded = False
        self.shared_pub.publish(msg)
        self._deadline.reset()
        early, self.early = self.early, None
        if early is not None:
            self._on_bundle(early)

    def _hold(self, t: int) -> None:
        """Record what the simulator applied at a sample we did not command: the previous
        command (zero-order hold; 0 at sample 0)."""
        if t < self.T:
            self.applied[0, t] = self.applied[0, t - 1] if t > 0 else 0.0

    def _on_deadline(self) -> None:
        self._deadline.cancel()
        if self.commanded or self.t < 0:
            return
        self.late["bundle"] += 1
        self._command(self.k, self.t, [])

    def _new_trial(self, k: int) -> None:
        self.k = k
        self.t = -1
        self.own_msgs = [None] * (self.T + 1)
        self.applied[:] = 0.0

    def _on_bundle(self, msg: Path) -> None:
        topic = "neighbour_poses"
        try:
            tick_ns, receiver, poses = ms.msg_to_bundle(msg)
            k, t = self.clock.decode(tick_ns)
            if receiver != self.name:
                raise ms.MalformedMessage(f"bundle for {receiver!r}")
        except ms.MalformedMessage as exc:
            self.drops.drop("malformed", topic, str(exc))
            return
        if self.realtime:
            if (k, t) > (self.k, self.t):
                self.early = msg  # its pose is on the way
                return
            if (k, t) == (self.k, self.t) and self.commanded:
                self.late["bundle_after_command"] += 1
                return
            if (k, t) < (self.k, self.t):
                self.late["bundle_after_command"] += 1
                return
        if (k, t) != (self.k, self.t) or self.commanded:
            reason = "stale" if (k, t) <= (self.k, self.t) else "out_of_order"
            self.drops.drop(reason, topic, f"bundle for ({k}, {t}) at ({self.k}, {self.t})")
            return
        self._command(k, t, poses)

    def _command(self, k: int, t: int, poses: list[PoseStamped]) -> None:
        """Sample t's command from this tick's deliveries ``poses`` (eq. 11 per pose)."""
        topic = "neighbour_poses"
        # only this tick's deliveries count (as in simulate.run_trial)
        self.nb_s[0] = -1
        self.lead_s[0] = -1
        rt = self.rt_ns
        dt_ns = self.clock.dt_ns
        for ps in poses:
            sender = ps.header.frame_id
            try:
                st = ms.stamp_to_ns(ps.header.stamp)
                kl, _ = self.clock.decode(st)
                if sender == ms.LEADER_FRAME and self.sees_leader:
                    ell = -1
                elif sender in self.links:
                    ell = self.links[sender]
                else:
                    raise ms.MalformedMessage(f"pose from {sender!r}, not an in-link")
            except ms.MalformedMessage as exc:
                self.drops.drop("malformed", topic, str(exc))
                continue
            if kl != k or st > rt:
                self.drops.drop("stale" if kl < k else "out_of_order", topic,
                                f"label {st} ns at Rt {rt} ns")
                continue
            tau = measure_delay_ns(rt, st, dt_ns)  # eq. (11): Rt own clock, St the label
            s = t - tau
            if ell < 0:
                try:
                    ms.msg_to_pose(ps)  # validated; the law uses only the label
                except ms.MalformedMessage as exc:
                    self.drops.drop("malformed", topic, str(exc))
                    continue
                self.lead_s[0] = s
            else:
                j = self.link_src[ell]
                try:
                    e, _, _ = ms.msg_to_pose(ps, float(self.pb.eta_d[j, s, 2]))
                except ms.MalformedMessage as exc:
                    self.drops.drop("malformed", topic, str(exc))
                    continue
                self.nb_eta[0, ell] = e
                self.nb_s[0, ell] = s
            self.delays[sender][tau] += 1
        pb, sl = self.pb, self.sl
        command(t, pb.law, self.memory[:, t], self.eta, pb.eta_d[sl], self.nb_eta, self.nb_s,
                pb.src[sl], pb.weight[sl], pb.eta_d, self.lead_s, pb.leader[sl],
                pb.gain_prime[sl], pb.heading, self.u)
        self.applied[0, t] = self.u[0]
        self.commanded = True
        self.commands += 1
        self.cmd_pub.publish(ms.u_to_twist(self.u[0], self.twist))
        if self.realtime:
            self._deadline.cancel()

    # ------------------------------------------------------------------ trial end
    def _finish_trial(self) -> None:
        k = self.k
        for s, m in enumerate(self.own_msgs):
            if m is None:  # realtime: a lost sample is held from the one before it
                self.eta[0, s] = self.eta[0, max(s - 1, 0)]
                self.own_msgs[s] = ms.pose_to_msg(self.eta[0, s], self.clock.stamp_ns(k, s),
                                                  self.name)
        path = ms.bundle_to_msg(self.rt_ns, self.name, self.own_msgs)
        self.traj_pub.publish(path)
        self.finished = k
        self._try_learn(k)

    def _on_trajectory(self, msg: Path, ell: int, sender: str) -> None:
        topic = f"{sender}/trajectory"
        if not self.configured:
            return
        j = self.link_src[ell]
        try:
            eta, stamps, frame = ms.path_to_trajectory(msg, self.pb.eta_d[j, :, 2])
            if frame != sender:
                raise ms.MalformedMessage(f"frame {frame!r} on {sender}'s trajectory")
            k, s0 = self.clock.decode(int(stamps[0]))
            if s0 != 0 or any(self.clock.decode(int(x)) != (k, s) for s, x in enumerate(stamps)):
                raise ms.MalformedMessage("trajectory stamps are not samples 0..T of one trial")
        except ms.MalformedMessage as exc:
            self.drops.drop("malformed", topic, str(exc))
            return
        if k <= self.learned or k < self.k:
            self.drops.drop("stale", topic, f"trajectory of trial {k} in trial {self.k}")
            return
        self.trajs.setdefault(k, {})[ell] = eta
        self._try_learn(k)

    def _try_learn(self, k: int) -> None:
        have = self.trajs.get(k, {})
        if self.finished != k or self.learned >= k or len(have) < len(self.links):
            return
        pb, sl = self.pb, self.sl
        for ell, eta in have.items():
            self.nb_full[0, ell] = eta
        learn(pb.law, pb.memory, self.memory, self.applied, self.eta, pb.eta_d[sl],
              self.nb_full, pb.src[sl], pb.weight[sl], pb.eta_d, pb.leader[sl], pb.gain[sl],
              pb.heading, self.next_memory)
        self.memory, self.next_memory = self.next_memory, self.memory
        self.learned = k
        for old in [x for x in self.trajs if x <= k]:
            del self.trajs[old]
        self.publish_diagnostics()
        self._send_ready(k + 1)

    def publish_diagnostics(self) -> None:
        d = {"node": self.name, "trial": self.learned, "commands": self.commands,
             "missed": self.missed,
             **({"late": dict(self.late)} if self.realtime else {}),
             "delays": {s: {str(t): c for t, c in sorted(h.items())}
                        for s, h in self.delays.items()}}
        d.update(self.drops.as_dict())
        self.diag_pub.publish(ms.json_to_msg(d))


def main(args: list[str] | None = None) -> int:
    def build(argv: list[str]) -> list[Node]:
        ap = argparse.ArgumentParser(prog="formation-ilc-robot", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
        ap.add_argument("--robots", type=int, nargs="+", metavar="ID",
                        help="container mode: these robots as nodes of one process")
        ns = ap.parse_args(argv)
        if ns.robots:
            return [RobotNode(r) for r in ns.robots]
        return [RobotNode()]

    return spin_main(build, args)


if __name__ == "__main__":
    sys.exit(main())
