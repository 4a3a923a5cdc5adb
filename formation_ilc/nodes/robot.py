"""Robot node: one robot's distributed learning controller (``formation-ilc-robot``).

Parameters
----------
robot_id : int (required)
    1-based robot number; the node is named ``robot_<id>`` and its topics are
    ``robot_<id>/...`` in its namespace (default ``/formation``).
scenario : str
    Scenario name or YAML file. Empty (default): take the run configuration from the
    latched ``config`` topic (published by the virtual leader).
seed, noise, delay, links, mode : used only with ``scenario`` (as for ``formation-ilc
    launch``).
init_memory : str
    A memory file written by ``formation-ilc simulate`` (memory.npz): the robot starts from
    its own row of the team's learned memory instead of u = 0 (sim-to-real). A file for
    another scenario or team size stops the node (status 2) naming what differs.
state_dir : str
    Where the robot keeps its learning state (``robot_<id>.npz``, written atomically each
    time it learns). A robot restarted with the same parameters after a crash continues
    from it: no learned trial is lost (``formation_ilc.protocol.schedule``). Empty: no state file.

Per sample t of trial k: the measured pose arrives on ``robot_<id>/pose`` (its stamp is
the robot's clock Rt), is shared on ``robot_<id>/shared_pose`` (stamp = send label St),
and the links deliver the neighbours' poses:

* ``links: direct``: the node subscribes to each in-neighbour's ``shared_pose`` (and, in
  realtime, to ``leader/reference`` if it sees the leader) and uses, on each link, the
  newest pose with St <= Rt. Lockstep: it waits for St = Rt on every link; the leader link
  is then the robot's own sample, with no message (``RunConfig.leader_in_step``).
  Realtime: it waits at most ``LINK_WAIT`` dT after its pose, then uses what has arrived.
* ``links: emulated``: the link emulator sends one message per link and tick on
  ``robot_<id>/links/<sender>``; the node commands when every link reported the tick
  (realtime: at most ``LINK_WAIT`` dT after its pose).

A trial the leader aborts (``abort`` on ``leader/trial_events``: a node restarted during
it) is forgotten, and the learning step undone if it was already taken. Starts and aborts
are taken by the rule every follower of the schedule applies
(``formation_ilc.protocol.schedule.Follower``; a start only moves the ``seen`` of the
robot's next ready: its trials follow its own poses).

It measures every delay by eq. (11) from Rt and St, calls the core's ``law.command`` for its
one robot (``formation_ilc.protocol.learner.RobotLearner``) and publishes ``cmd_vel``. At
sample T it sends its whole trajectory on ``trajectory``; when it has its in-neighbours'
trajectories of trial k it calls ``law.learn`` and reports ready for trial k+1. Malformed, stale,
out-of-order, duplicate and future-labelled messages, and any label outside the robot's
window (its current trial; the next one once it has learned the current one: see
``formation_ilc.protocol.learner``), are dropped and counted (``diagnostics``). A
neighbour's trajectory is taken from that robot's own writer only (``robot_j`` writes
``robot_j/trajectory``; ``protocol.writers``), the plant's ``team/poses`` from the plant's:
any other writer's is refused unread and counted as ``forged``, by topic and sender.

Container mode: ``formation-ilc-robot --robots 1 2 3`` runs three robot nodes (each with
its own memory) in one process on one executor.
"""

from __future__ import annotations

import sys
from collections import Counter
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, Twist, TwistStamped
from nav_msgs.msg import Path
from rclpy.node import Node
from std_msgs.msg import Bool, String

import msgs_schema as ms
from formation_ilc.config import params
from formation_ilc.core.clock import Rejected
from formation_ilc.core.links import LEADER
from formation_ilc.model.safety import spec_of
from formation_ilc.model.simulate import Problem
from formation_ilc.nodes.clocks import ClockExchange, NodeClock, node_clock
from formation_ilc.nodes.common import (
    ConfiguredNode,
    RunConfig,
    make_config,
    matched,
    node_parser,
    robot_node_from_args,
    spin_main,
    unmatched,
)
from formation_ilc.nodes.params import ParameterError, check, declare, effective
from formation_ilc.nodes.writers import REFRESH_TRIAL
from formation_ilc.protocol.learner import RobotLearner
from formation_ilc.protocol.schedule import Follower
from formation_ilc.protocol.writers import plant_writers
from formation_ilc.store.memoryfile import MemoryFileError, load_memory
from formation_ilc.store.robotstate import load_state, save_state, state_path
from msgs_schema import wire

#: realtime: how long [dT] a robot waits for its links after its pose
LINK_WAIT = 0.75
#: the command while the e-stop is latched
ZERO = (0.0, 0.0)
#: teams from this size read the plant's team/poses as arrays (``learner.on_team_poses``):
#: per sample 64 us against 334 us one pose at a time at 50 robots, 59 against 165 at 24,
#: but 52 against 41 at 6 (numpy's cost per call; measured 2026-11-28)
TEAM_BLOCK_FROM = 8


class RobotNode(ConfiguredNode):
    """One robot's controller. ``robot_id`` may be given here (container mode), else it is
    the ROS parameter of the same name, read before the node is named; ``**kwargs`` go to
    ``Node`` (context=, parameter_overrides=, ...)."""

    def __init__(self, robot_id: int | None = None, **kwargs: Any):
        if robot_id is None:
            for p in kwargs.get("parameter_overrides") or ():
                if p.name == "robot_id":
                    robot_id = p.value
        if robot_id is None:
            raise ParameterError("parameter robot_id: a robot number >= 1 is required "
                                 "(--ros-args -p robot_id:=I)")
        robot_id = int(check(params.ROBOT[0], robot_id))
        super().__init__(ms.robot_name(robot_id), **kwargs)
        declare(self, params.ROBOT, robot_id=robot_id)
        self.id = int(robot_id)
        self.name = ms.robot_name(self.id)
        self.ready_sent = -1
        g = lambda name: self.get_parameter(name).value  # noqa: E731
        cfg = None
        if g("scenario"):
            seed = int(g("seed"))
            cfg = make_config(str(g("scenario")), seed=None if seed < 0 else seed,
                              noise=bool(g("noise")), delay=bool(g("delay")),
                              links=str(g("links")), mode=str(g("mode")))
        self.follow_config(cfg)

    # ------------------------------------------------------------------ set-up
    def configure(self, cfg: RunConfig) -> None:
        pb = Problem.from_scenario(cfg.scenario)
        self.cfg, self.pb = cfg, pb
        sc = cfg.scenario
        # the parameters read what runs: the leader's configuration overrides them
        effective(self, {"scenario": cfg.scenario_param, "seed": sc.seed,
                         "noise": sc.uncertainty.noisy,
                         "delay": sc.uncertainty.delay.kind != "none", "links": cfg.links,
                         "mode": cfg.mode})
        self.realtime = cfg.wall
        self.learner = lrn = self._make_learner(cfg, pb)
        #: the robots that learn from this one's trajectory (its out-neighbours)
        self.out_names = tuple(ms.robot_name(r + 1) for r in range(pb.n)
                               if r != lrn.i and lrn.i in pb.src[r])
        self.n_out = len(self.out_names)
        self.late: Counter[str] = Counter({"links": 0})

        self._wire_samples(cfg, lrn)
        self._wire_team(cfg, pb, lrn)
        clock = node_clock(cfg, self.id)
        self._wire_trajectories(cfg, lrn, clock)
        #: whether the deadline timer runs (realtime: from a pose whose links are not in)
        self._armed = False
        if self.realtime:
            # the wait runs on the robot's own clock (an emulated one runs fast or slow)
            self._deadline = self.create_timer(LINK_WAIT * cfg.scenario.dt * clock.scale,
                                               self._on_deadline)
            self._deadline.cancel()
        #: the checked subscriptions carry trajectories only (no safety filter's
        #: team/poses): their re-check sleeps inside a trial (``polls_idle``)
        self._idle_polls = self.poll_period() >= REFRESH_TRIAL
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)
        #: the e-stop is latched: every command is zero (the learner still runs its trial)
        self.estopped = False
        self.create_subscription(Bool, ms.ESTOP, self._on_estop, ms.LATCHED_READER_QOS)
        self._gate = self.create_timer(0.05, self._check_ready)
        self.get_logger().info(f"{self.name}: {len(lrn.neighbours)} in-links"
                               f"{' + leader' if lrn.sees_leader else ''} ({cfg.links}), "
                               f"{self.n_out} out-neighbours, {pb.samples} samples")

    def _make_learner(self, cfg: RunConfig, pb: Problem) -> RobotLearner:
        """The learner of this robot (its initial memory, its safety filter), restored from
        its state file when there is one; and the follower of the leader's events."""
        memory = None
        path = str(self.get_parameter("init_memory").value)
        if path:
            memory = load_memory(path, cfg.scenario)[self.id - 1]
            self.get_logger().info(f"{self.name}: initial memory from {path}")
        safety = (None if cfg.safety is None
                  else spec_of(cfg.safety, cfg.scenario.dt, cfg.scenario.uncertainty))
        lrn = RobotLearner(pb, self.id - 1, cfg.clock, realtime=self.realtime,
                           direct=cfg.links == "direct", memory=memory,
                           leader_in_step=cfg.leader_in_step, safety=safety)
        self.follower = Follower(cfg.run_id, clock=cfg.clock)
        sdir = str(self.get_parameter("state_dir").value)
        self.state_file = state_path(sdir, self.id) if sdir else None
        if self.state_file is not None:
            try:
                st = load_state(self.state_file, cfg.scenario, self.id)
            except MemoryFileError as exc:
                raise ValueError(str(exc)) from None
            if st is not None:
                lrn.restore(st)
                self.get_logger().info(f"{self.name}: continues from {self.state_file}: "
                                       f"{st.iterations} trials learned")
        return lrn

    def _wire_samples(self, cfg: RunConfig, lrn: RobotLearner) -> None:
        """The per-sample publishers (command, shared pose, trajectory, ready) and
        subscriptions: its own pose, and each link (emulated ticks or direct poses)."""
        self.cmd_pub = self.create_publisher(Twist, ms.cmd_vel_topic(self.id), ms.SAMPLE_QOS)
        self.shared_pub = self.create_publisher(PoseStamped, ms.shared_pose_topic(self.id),
                                                ms.SAMPLE_QOS)
        #: (slot, the shared poses sent in it, in order): what a repeat sends again
        self.shared_sent: tuple[int, list[bytes]] = (-1, [])
        self.traj_pub = self.create_publisher(Path, ms.trajectory_topic(self.id),
                                              ms.TRAJECTORY_QOS)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        # the per-sample messages as bytes (msgs_schema.wire: no message objects)
        self.sample_subs = [self.create_subscription(
            PoseStamped, ms.pose_topic(self.id), self._on_pose, ms.SAMPLE_QOS, raw=True)]
        for sender in lrn.slots:
            if sender == LEADER and cfg.leader_in_step:
                continue  # the leader link is the robot's own sample (RunConfig.leader_in_step)
            if cfg.links == "emulated":
                # a tick longer than one pose is refused before it is read
                self.sample_subs.append(self.create_subscription(
                    Path, ms.link_topic(self.id, sender),
                    lambda m, s=sender: self._on_link_tick(m, s), ms.SAMPLE_QOS, raw=True))
            else:
                topic = (ms.REFERENCE if sender == LEADER
                         else ms.shared_pose_topic(ms.robot_index(sender)))
                self.sample_subs.append(self.create_subscription(
                    PoseStamped, topic, lambda m, s=sender: self._on_link_pose(m, s),
                    ms.SAMPLE_QOS, raw=True))

    def _wire_team(self, cfg: RunConfig, pb: Problem, lrn: RobotLearner) -> None:
        """With a safety filter: the other robots' poses (the plant's team/poses, or each
        robot's), and the commands the robots tell each other."""
        #: realtime with the plant's team/poses: taken before each command (below)
        self._team_sub: Any = None
        self._taking_team = False
        if cfg.safety is not None:  # the other robots' poses, for the safety filter
            if cfg.safety.sensing == "team":
                # from the plant only (protocol.writers): forged poses 1 km away switched
                # the filter off
                team = self.checked_subscription(
                    Path, ms.TEAM_POSES, lambda m, gid: self._on_team(m), ms.SAMPLE_QOS,
                    raw=True, owners=plant_writers())
                self.sample_subs.append(team)
                if self.realtime:
                    self._team_sub = team
            else:
                self.sample_subs += [self.create_subscription(
                    PoseStamped, ms.pose_topic(j + 1), lambda m, j=j: self._on_peer(m, j),
                    ms.SAMPLE_QOS, raw=True) for j in range(pb.n) if j != lrn.i]
        #: told commands (``safety.motion: commands``): this robot's, out; the others', in
        self.applied_pub: Any = None
        self.applied_sent = b""  # the last command told, sent again with a repeat
        self._told_subs: list[Any] = []
        if cfg.safety is not None and cfg.safety.motion == "commands":
            self.applied_pub = self.create_publisher(TwistStamped, ms.applied_topic(self.id),
                                                     ms.SAMPLE_QOS)
            self._base_frame = f"{self.name}/base_link"
            # from robot j's own writer only (protocol.writers): a command another writer
            # tells in robot j's name would let the filter keep less room than j needs;
            # taken before each realtime command, as the plant's team/poses
            self._told_subs = [self.checked_subscription(
                TwistStamped, ms.applied_topic(j + 1),
                lambda m, gid, j=j: self._on_told(m, j), ms.SAMPLE_QOS, raw=True,
                owners=(ms.robot_name(j + 1),)) for j in range(pb.n) if j != lrn.i]
            self.sample_subs += self._told_subs

    def _wire_trajectories(self, cfg: RunConfig, lrn: RobotLearner,
                           clock: NodeClock) -> None:
        """The in-neighbours' trajectories, and the clock exchanges (on the robot's
        ``clock``)."""
        for sender in lrn.neighbours:
            # raw: a trajectory longer than a trial is refused before it is deserialized;
            # from robot j's own writer only (protocol.writers): a trajectory another
            # writer sends in robot j's topic is refused and counted as forged, never
            # learned from
            self.checked_subscription(
                Path, ms.trajectory_topic(ms.robot_index(sender)),
                lambda m, gid, s=sender: self._on_trajectory(m, s),
                ms.TRAJECTORY_READER_QOS, raw=True, owners=(sender,), poll=REFRESH_TRIAL)
        self.clocks: ClockExchange | None = None
        if cfg.clock_exchanges:
            # its clock words go out on a writer of their own: the report's writer keeps
            # one message (latched), and a word sent just after a report would replace it
            # before a reader that was behind had taken it
            self.word_pub = self.create_publisher(DiagnosticArray, ms.DIAGNOSTICS,
                                                  ms.LATCHED_QOS)
            # the clocks this robot hears (its in-neighbours', the leader's if it sees it),
            # and its own for the robots that hear it (protocol.timesync)
            self.clocks = ClockExchange(
                self, self.name, cfg, clock,
                peers=[*lrn.neighbours, *([LEADER] if lrn.sees_leader else [])],
                askers=self.out_names, drops=self.drops, on_event=self._clock_event,
                on_report=self._clock_word)

    def _check_ready(self) -> None:
        """Ready for trial 0 once every publisher has its readers and every per-sample
        subscription its writer (nothing published before both ends are matched can be
        lost)."""
        shared_readers = self.n_out if self.cfg.links == "direct" else 1
        # the trajectory's readers by name: the out-neighbours, which learn from it, and
        # the results' readers (a count would let the recorder stand in for one of them)
        need = [(self.cmd_pub, 1), (self.shared_pub, shared_readers), (self.ready_pub, 1),
                (self.traj_pub, self.out_names + self.cfg.result_readers)]
        need += [(sub, 1) for sub in self.sample_subs]
        if self.applied_pub is not None:  # every other robot filters with it
            need.append((self.applied_pub, self.pb.n - 1))
        if matched(need, self):
            self._gate.cancel()
            self._send_ready()
            return
        self.not_ready(unmatched(need, self))

    def _send_ready(self) -> None:
        """Idle: ready for the next iteration (the number of trials learned)."""
        self.ready_sent = self.learner.iterations
        self.ready_pub.publish(self.ready_msg(self.learner.iterations))

    def _on_event(self, msg: String) -> None:
        lrn = self.learner
        # the robot's trials follow its own poses: a start taken only moves the ``seen``
        # its next ready carries; it is idle once done with the slot started last (or run
        # without its start: Follower.ran)
        self.follower.ran(lrn.learned)
        ev = self.take_event(msg, lambda ev: self.follower.take(
            ev, idle=lrn.done_with(self.follower.slot)))
        if ev is None:
            return
        if ev.event == ms.ABORT:
            if self._idle_polls:
                self.polls_idle(False)
            rolled = self.learner.abort(ev.slot)
            # the slot the leader last committed stands: a step undone on an abort the
            # leader did not send is taken back
            redone = ev.kept >= 0 and self.learner.redo(ev.kept)
            if rolled or redone:
                self._save_state()
            back = f"; the step of slot {ev.kept} taken back" if redone else ""
            self.get_logger().warning(f"{self.name}: trial {ev.trial} (slot {ev.slot}) "
                                      f"aborted: {ev.why}"
                                      f"{'; learning step undone' if rolled else ''}{back}")
            if not self._gate.is_canceled():
                return  # not yet ready at all: the gate says ready once it is
            self._send_ready()

    def _save_state(self) -> None:
        if self.state_file is not None:
            save_state(self.state_file, self.learner.state(), self.cfg.scenario, self.id)

    # ------------------------------------------------------------------ per sample
    def _on_pose(self, msg: PoseStamped | bytes) -> None:
        lrn = self.learner
        data = wire.as_bytes(msg)
        ns = -1
        try:
            p = wire.read_pose(data)
            ns = p.label_ns
            eta = wire.world_eta(p, lrn.expected_heading(self.name, ns))
            ev = lrn.on_pose(ns, eta)
        except Rejected as exc:
            self.drops.reject(exc, "pose")
            if lrn.is_repeat(ns):
                self._repeat(data)
            return
        if ev.new_trial and self._idle_polls:
            self.polls_idle(True)  # a trial runs: no trajectory is due before its end
        if ev.last:
            self._disarm()
            self._finish_trial()
            return
        # the same bits, the same label St; with direct links a robot without out-neighbours
        # has no reader, and a publish costs more CPU than the rest of the sample
        if self.shared_pub.get_subscription_count():
            self.shared_pub.publish(data)
            if not self.realtime:
                slot, sent = self.shared_sent
                if slot != lrn.k:
                    self.shared_sent = slot, sent = lrn.k, []
                sent.append(data)
        self._maybe_command()
        if self.realtime and not self.learner.commanded:
            # armed only when the links are not in yet: a reset and a cancel of a timer
            # each sample wake the executor's timer thread twice
            self._deadline.reset()
            self._armed = True

    def _repeat(self, data: bytes) -> None:
        """The plant sent the current sample again (lockstep; a command of it is still due):
        every shared pose this robot sent in the trial goes out again, the same bits, and
        the current one if it was not sent yet. The links may have lost any of them: a
        flood on a shared-pose topic overwrites the link emulator's reader history, and a
        robot that commanded the current sample may hold up another whose delivery is an
        earlier pose of its (the links drop what they have as duplicates). A command is
        never sent twice: ``cmd_vel`` carries no label, and a second copy reaching the plant
        after it moved on would be taken as the next sample's command."""
        slot, sent = self.shared_sent
        again = sent if slot == self.learner.k else []
        for d in again:
            self.shared_pub.publish(d)
        if not self.learner.commanded and (not again or again[-1] != data):
            self.shared_pub.publish(data)
        if self.applied_pub is not None and self.applied_sent:
            # the command it told last (labelled: a second copy is a duplicate, refused):
            # another robot's filter may be waiting for it
            self.applied_pub.publish(self.applied_sent)

    def _on_link_pose(self, msg: PoseStamped | bytes, sender: str) -> None:
        topic = f"{sender}/shared_pose" if sender != LEADER else ms.REFERENCE
        try:
            p = wire.read_pose(wire.as_bytes(msg))
            st = p.label_ns
            eta = wire.world_eta(p, self.learner.expected_heading(sender, st))
            self.learner.on_link_pose(sender, st, eta)
        except Rejected as exc:
            self.drops.reject(exc, topic)
            return
        self._maybe_command()

    def _on_link_tick(self, msg: Path | bytes, sender: str) -> None:
        try:
            tick, ps = wire.read_link_tick(ms.within_path_limit(wire.as_bytes(msg), 1,
                                                                "link tick"))
            pose = None
            if ps is not None:
                st = ps.label_ns
                eta = wire.world_eta(ps, self.learner.expected_heading(sender, st))
                pose = (st, eta)
            self.learner.on_link_tick(sender, tick, pose)
        except Rejected as exc:
            self.drops.reject(exc, f"links/{sender}")
            return
        self._maybe_command()

    def _on_team(self, msg: Path | bytes) -> None:
        """Every robot's pose of a sample (the plant's ``team/poses``), for the filter."""
        lrn, heard = self.learner, False
        data = wire.as_bytes(msg)
        if self.pb.n >= TEAM_BLOCK_FROM:
            block = wire.read_pose_block(data, self.pb.n)
            if block is not None and lrn.on_team_poses(*block):  # all at once
                self._maybe_command()
                return
        try:
            _, poses = wire.read_pose_set(data, self.pb.n)
        except Rejected as exc:
            self.drops.reject(exc, ms.TEAM_POSES)
            return
        for j, p in enumerate(poses):
            if j == lrn.i:
                continue
            try:
                st = p.label_ns
                lrn.on_team_pose(j, st, wire.world_eta(
                    p, lrn.expected_team_heading(j, st)))
                heard = True
            except Rejected as exc:
                self.drops.reject(exc, ms.TEAM_POSES)
        if heard:
            self._maybe_command()

    def _on_peer(self, msg: PoseStamped | bytes, j: int) -> None:
        """Robot j's (0-based) own pose, for the filter (``sensing: peers``)."""
        lrn = self.learner
        try:
            p = wire.read_pose(wire.as_bytes(msg))
            st = p.label_ns
            lrn.on_team_pose(j, st, wire.world_eta(p, lrn.expected_team_heading(j, st)))
        except Rejected as exc:
            self.drops.reject(exc, ms.pose_topic(j + 1))
            return
        self._maybe_command()

    def _on_told(self, msg: TwistStamped | bytes, j: int) -> None:
        """The command robot j (0-based) applied over a sample, for the filter."""
        try:
            label, v, w = wire.read_applied(wire.as_bytes(msg))
            self.learner.on_told(j, label, v, w)
        except Rejected as exc:
            self.drops.reject(exc, ms.applied_topic(j + 1))
            return
        self._maybe_command()

    def _maybe_command(self) -> None:
        if self._taking_team or not self.learner.can_command():
            return
        self._take_team()
        if self.learner.can_command():  # (still: nothing taken commands meanwhile)
            self._command()

    def _take_team(self) -> None:
        """Realtime: the plant's team/poses of this tick, which it sends before the robots'
        own poses, taken from rcl before the command. Its writer-checked subscription is
        served by a timer the executor may run after this pose's callback: the filter then
        had only the poses of the tick before, a sample old, and widened its distance by
        the other robots' speed over it at every sample (a realtime triangle braked or
        flagged 30-40 samples a trial on poses 200 ms old and did not learn)."""
        if self._team_sub is not None or self._told_subs:
            self._taking_team = True
            try:
                if self._team_sub is not None:
                    self._team_sub.take_waiting()
                if self.realtime:  # the others' told commands of the sample before
                    for sub in self._told_subs:
                        sub.take_waiting()
            finally:
                self._taking_team = False

    def _on_deadline(self) -> None:
        self._disarm()
        if not self.learner.commanded:
            self.late["links"] += 1
            self._take_team()
            self._command()

    def _disarm(self) -> None:
        if self._armed:
            self._deadline.cancel()
            self._armed = False

    def _on_estop(self, msg: Bool) -> None:
        if bool(msg.data) != self.estopped:
            self.estopped = bool(msg.data)
            self.get_logger().warning(f"{self.name}: e-stop: every command zero" if msg.data
                                      else f"{self.name}: e-stop released")
            if self.estopped:  # zero at once, not at the next sample
                self.cmd_pub.publish(wire.twist_bytes(ZERO))

    def _command(self) -> None:
        u = self.learner.command()
        if self.estopped:
            u = ZERO
        self.cmd_pub.publish(wire.twist_bytes(u))
        if self.applied_pub is not None:
            self.applied_sent = wire.applied_bytes(u, self.learner.rt_ns, self._base_frame)
            self.applied_pub.publish(self.applied_sent)
        self._disarm()

    # ------------------------------------------------------------------ trial end
    def _finish_trial(self) -> None:
        lrn = self.learner
        if self._idle_polls:
            self.polls_idle(False)  # the in-neighbours' trajectories are due
        k, eta = lrn.finish_trial()
        if lrn.safety is not None:
            # what the filter changed in this trial, before the trajectory that completes
            # the trial's row for the monitor (protocol.trialrows)
            self.publish_diagnostics()
        # bytes (msgs_schema.wire): no T+1 message objects to build
        self.traj_pub.publish(wire.path_bytes(eta, lrn.trajectory_stamps(k), ms.WORLD_FRAME))
        if lrn.try_learn():
            self._learned()

    def _on_trajectory(self, data: bytes | Path, sender: str) -> None:
        if not self.configured:
            return
        lrn = self.learner
        try:
            j = ms.robot_index(sender) - 1
            eta, stamps, frame = ms.trajectory_from_raw(data, self.pb.samples + 1,
                                                        self.pb.eta_d[j, :, 2])
            if frame != ms.WORLD_FRAME:
                raise ms.MalformedMessage(f"trajectory in frame {frame!r}")
            learned = lrn.on_trajectory(sender, stamps, eta)
        except Rejected as exc:
            self.drops.reject(exc, f"{sender}/trajectory")
            return
        if learned:
            self._learned()

    def _learned(self) -> None:
        self._save_state()  # before ready: what the leader commits is on disk
        self.publish_diagnostics()
        self._send_ready()

    def publish_diagnostics(self) -> None:
        d = self.learner.diagnostics()
        if self.realtime:
            d["late"] = dict(self.late)
        if self.clocks is not None:
            d["clock"] = self.clocks.report()
        d.update(self.drops.as_dict())
        self._publish(d, self.diag_pub)

    def _publish(self, d: dict[str, Any], pub: Any) -> None:
        pub.publish(ms.diagnostics_to_msg(
            d, self.get_clock().now().nanoseconds, self.cfg.scenario.dt, self.pb.samples,
            self.name))

    def _clock_word(self, events: list[list[str]] | None = None) -> None:
        """Where this robot's clock estimates are, as a word on diagnostics between its
        reports (``clock_word``: the monitor prints its events, the recording keeps it)."""
        assert self.clocks is not None
        self.diag_pub.word(ms.diagnostics_to_msg(
            {"node": self.name, "trial": self.learner.iterations - 1,
             "clock": self.clocks.report(), "clock_word": {"events": events or []}},
            self.get_clock().now().nanoseconds, self.cfg.scenario.dt, self.pb.samples,
            self.name), self.word_pub, "clock")

    def _clock_event(self, level: str, text: str) -> None:
        if level == "warn":
            self._clock_word([[level, text]])


def main(args: list[str] | None = None) -> int:
    parser = node_parser("formation-ilc-robot", __doc__)
    parser.add_argument("--robots", type=int, nargs="+", metavar="ID",
                        help="container mode: these robots as nodes of one process")

    def build(ns: Any, argv: list[str]) -> list[Node]:
        if ns.robots:
            return [RobotNode(r) for r in ns.robots]
        return [robot_node_from_args(RobotNode, argv, "formation-ilc-robot")]

    return spin_main(build, parser, args)


if __name__ == "__main__":
    sys.exit(main())
