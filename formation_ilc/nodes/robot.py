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

Its topics are its member of the run's roster (``config.roster``: ``Lineup.of_run`` of the
configuration it runs), the one list the launcher and the keystore's grants read too: each
publisher and subscription is made by its topic's kind (``names.topic_kind``) with the
schema's type and QoS (``msgs_schema.kinds``); a topic it has no handler for stops it,
named (status 2).

Container mode: ``formation-ilc-robot --robots 1 2 3`` runs three robot nodes (each with
its own memory) in one process on one executor.
"""

from __future__ import annotations

import sys
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from rclpy.node import Node

import msgs_schema as ms
from formation_ilc.config import params
from formation_ilc.config.roster import Lineup, Member, roster
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

if TYPE_CHECKING:  # the types come from the schema (msgs_schema.kinds); these annotate
    from geometry_msgs.msg import PoseStamped, TwistStamped
    from nav_msgs.msg import Path
    from std_msgs.msg import Bool, String

#: realtime: how long [dT] a robot waits for its links after its pose
LINK_WAIT = 0.75
#: the command while the e-stop is latched
ZERO = (0.0, 0.0)
#: teams from this size read the plant's team/poses as arrays (``learner.on_team_poses``):
#: per sample 64 us against 334 us one pose at a time at 50 robots, 59 against 165 at 24,
#: but 52 against 41 at 6 (numpy's cost per call; measured 2026-11-28)
TEAM_BLOCK_FROM = 8
#: the kinds of topic a robot publishes (``names.topic_kind``): whether it makes the writer
#: from its member here (True), or another part of it does (False: the node's diagnostics,
#: made at its start; the clock exchange's questions and answers, made with the clocks it
#: asks and the robots that ask its)
_WRITES = {"cmd_vel": True, "shared_pose": True, "trajectory": True, ms.READY: True,
           "applied": True, ms.DIAGNOSTICS: False, ms.ROS_DIAGNOSTICS: False,
           "clock/ping": False, "clock/pong": False}
#: the writers every robot has: its command, its shared pose, its trajectory, its ready
_OWN = ("cmd_vel", "shared_pose", "trajectory", ms.READY)


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
        #: the e-stop is latched: every command is zero (the learner still runs its trial)
        self.estopped = False
        #: what this robot publishes and reads: its member of the run's roster
        self.member = roster(Lineup.of_run(cfg)).member(self.name)
        clock = node_clock(cfg, self.id)
        self._wire(self.member, cfg, clock)
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

    # ------------------------------------------------------------------ wiring
    def _wire(self, member: Member, cfg: RunConfig, clock: NodeClock) -> None:
        """Every publisher and subscription of this robot's roster member (``member``),
        each made by its kind (``names.topic_kind``) with the schema's type and QoS
        (``msgs_schema.kinds``): one list says what a robot publishes and reads, for its
        node, the launcher and the keystore's grants alike. A topic this node has no
        writer or reader for is refused, named (the node stops: status 2).

        Why the node builds its member itself rather than taking it from the launcher:
        a robot's member follows from the run configuration alone (``Lineup.of_run``: the
        graph, the links, the filter's hearing, told commands, the leader link in step,
        the clock exchanges), and the node runs that very configuration (the leader's
        latched one, or its own parameters' when started by hand). Topics passed as
        parameters could disagree with the configuration the node learns by; built from
        it, they cannot."""
        #: (slot, the shared poses sent in it, in order): what a repeat sends again
        self.shared_sent: tuple[int, list[bytes]] = (-1, [])
        self.applied_sent = b""  # the last command told, sent again with a repeat
        #: the per-sample subscriptions (each matched to its writer before ready)
        self.sample_subs: list[Any] = []
        #: realtime with the plant's team/poses: taken before each command (_take_team)
        self._team_sub: Any = None
        self._taking_team = False
        #: told commands (``safety.motion: commands``): the others', in
        self._told_subs: list[Any] = []
        #: the clocks this robot asks (peers) and the robots that ask its (askers)
        self._peers: list[str] = []
        self._askers: list[str] = []
        made = self._writers(member.publish)
        self.cmd_pub, self.shared_pub, self.traj_pub, self.ready_pub = (made[k] for k in _OWN)
        self.applied_pub: Any = made.get("applied")
        self._base_frame = f"{self.name}/base_link"
        for topic in member.subscribe:
            kind, node, sender = ms.topic_kind(topic)
            read = self._READS.get(kind)
            if read is None:
                raise ValueError(f"{self.name}: its roster member reads {topic}, which this "
                                 f"node has no reader for")
            read(self, topic, node, sender)
        self.clocks: ClockExchange | None = None
        if cfg.clock_exchanges:
            # its clock words go out on a writer of their own: the report's writer keeps
            # one message (latched), and a word sent just after a report would replace it
            # before a reader that was behind had taken it
            k = ms.kind_of(ms.DIAGNOSTICS)
            self.word_pub = self.create_publisher(k.type, ms.DIAGNOSTICS, k.offered)
            # its questions (clock/ping) when it asks any clock, its answers (clock/pong)
            # when any robot asks its (protocol.timesync)
            self.clocks = ClockExchange(
                self, self.name, cfg, clock, peers=self._peers, askers=self._askers,
                drops=self.drops, on_event=self._clock_event, on_report=self._clock_word)

    def _writers(self, topics: tuple[str, ...]) -> dict[str, Any]:
        """The writers of ``topics`` (its member's) that this node makes, by kind; a topic
        of another node's name, or of a kind it does not write, is refused, named."""
        made = {}
        for topic in topics:
            kind, node, _ = ms.topic_kind(topic)
            if node not in ("", self.name) or kind not in _WRITES:
                raise ValueError(f"{self.name}: its roster member publishes {topic}, which "
                                 f"this node has no writer for")
            if _WRITES[kind]:
                k = ms.kind_of(kind)
                made[kind] = self.create_publisher(k.type, topic, k.offered)
        missing = [k for k in _OWN if k not in made]
        if missing:
            raise ValueError(f"{self.name}: its roster member publishes no "
                             f"{', '.join(missing)}")
        return made

    def _sender(self, topic: str, sender: str) -> str:
        """``sender``, a link of this robot's learner (ValueError naming ``topic`` when
        the scenario's graph has no such link: the roster and the learner disagree)."""
        if sender not in self.learner.slots:
            raise ValueError(f"{self.name}: its roster member reads {topic}, but the "
                             f"scenario's graph has no link {sender} -> {self.name}")
        return sender

    def _sample(self, topic: str, kind: str, callback: Any) -> None:
        """A per-sample subscription, as bytes (``msgs_schema.wire``: no message objects;
        a tick longer than one pose is refused before it is read)."""
        k = ms.kind_of(kind)
        self.sample_subs.append(self.create_subscription(k.type, topic, callback, k.read,
                                                         raw=True))

    def _owned(self, topic: str, kind: str, handler: Any, owners: Any, **kw: Any) -> Any:
        """A subscription, as bytes, whose every message comes from one of ``owners``
        (``protocol.writers``: another writer's is refused unread and counted as forged)."""
        k = ms.kind_of(kind)
        return self.checked_subscription(k.type, topic, handler, k.read, raw=True,
                                         owners=owners, **kw)

    def _read_pose(self, topic: str, node: str, _: str) -> None:
        """Its own pose (per sample), or with a safety filter robot j's (``sensing:
        peers``)."""
        if node == self.name:
            self._sample(topic, "pose", self._on_pose)
        else:
            j = ms.robot_index(node) - 1
            self._sample(topic, "pose", lambda m: self._on_peer(m, j))

    def _read_link(self, topic: str, node: str, sender: str) -> None:
        """A link: the emulator's ticks (``links/S``), or on direct links the sender's
        shared pose or the leader's reference."""
        if sender:  # only an emulated link's topic names a sender
            s = self._sender(topic, sender)
            self._sample(topic, ms.LINKS, lambda m: self._on_link_tick(m, s))
        elif topic == ms.REFERENCE:
            s = self._sender(topic, LEADER)
            self._sample(topic, ms.REFERENCE, lambda m: self._on_link_pose(m, s))
        else:
            s = self._sender(topic, node)
            self._sample(topic, "shared_pose", lambda m: self._on_link_pose(m, s))

    def _read_team(self, topic: str, node: str, _: str) -> None:
        """The plant's team/poses, for the safety filter: from the plant only
        (protocol.writers): forged poses 1 km away switched the filter off."""
        team = self._owned(topic, ms.TEAM_POSES, lambda m, gid: self._on_team(m),
                             plant_writers())
        self.sample_subs.append(team)
        if self.realtime:
            self._team_sub = team

    def _read_told(self, topic: str, node: str, _: str) -> None:
        """Robot j's told command, from robot j's own writer only (protocol.writers): a
        command another writer tells in robot j's name would let the filter keep less room
        than j needs; taken before each realtime command, as the plant's team/poses."""
        j = ms.robot_index(node) - 1
        sub = self._owned(topic, "applied", lambda m, gid: self._on_told(m, j), (node,))
        self._told_subs.append(sub)
        self.sample_subs.append(sub)

    def _read_trajectory(self, topic: str, node: str, _: str) -> None:
        """An in-neighbour's trajectory: bytes (one longer than a trial is refused before
        it is deserialized), from that robot's own writer only (protocol.writers): one
        another writer sends in its topic is refused and counted as forged, never learned
        from."""
        s = self._sender(topic, node)
        self._owned(topic, "trajectory", lambda m, gid: self._on_trajectory(m, s), (s,),
                      poll=REFRESH_TRIAL)

    def _read_events(self, topic: str, node: str, _: str) -> None:
        k = ms.kind_of(ms.TRIAL_EVENTS)
        self.create_subscription(k.type, topic, self._on_event, k.read)

    def _read_estop(self, topic: str, node: str, _: str) -> None:
        k = ms.kind_of(ms.ESTOP)
        self.create_subscription(k.type, topic, self._on_estop, k.read)

    def _read_config(self, topic: str, node: str, _: str) -> None:
        """The leader's latched configuration: read by ``ConfiguredNode.follow_config``
        before the node is configured (none when it configured itself from its own
        parameters: it has the configuration it runs)."""

    def _read_clock(self, topic: str, node: str, _: str) -> None:
        """A clock this robot asks (its answers, ``X/clock/pong``) or a robot that asks
        its clock (its questions, ``X/clock/ping``): read by the clock exchange."""
        (self._peers if topic.endswith("pong") else self._askers).append(node)

    #: kind of topic (``names.topic_kind``) -> how this robot reads it
    _READS: dict[str, Callable[[RobotNode, str, str, str], None]] = {
        "pose": _read_pose, ms.LINKS: _read_link, "shared_pose": _read_link,
        ms.REFERENCE: _read_link, ms.TEAM_POSES: _read_team, "applied": _read_told,
        "trajectory": _read_trajectory, ms.TRIAL_EVENTS: _read_events,
        ms.ESTOP: _read_estop, ms.CONFIG: _read_config, "clock/pong": _read_clock,
        "clock/ping": _read_clock}

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
