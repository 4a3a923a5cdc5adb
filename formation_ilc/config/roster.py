"""The roster of a formation: every process of a run, from its options, in one place.

For a run's options (:class:`Lineup`: the team size and graph, the plant, the links, what
else runs) the roster gives each member its node name, the entry script that starts it,
whether the leader waits for its ready (each trial, once for the run, or never), whether
the launcher waits for its last report, its enclave, and the topics it publishes and
subscribes. Everything else reads it:

* the leader's team (``Team``, ``nodes_expected``): the members it waits for;
* the launcher's processes (``formation_ilc.plan.processes.node_specs``): the members with an
  entry script, in start order;
* each robot node (``formation_ilc.nodes.robot``): its publishers and subscriptions are its
  member's topics, its member built from the run configuration it runs (``Lineup.of_run``);
  every other node makes exactly its member's topics too (``tests/stack/test_secure.py``
  reads them from the live graph), so a member lists what its node uses in that lineup
  (``/clock`` only where it is read, true trajectories only where a plant writes them);
* the keystore's permissions (``Roster.grants``, signed by ``formation_ilc.store.keystore``):
  each enclave may publish and subscribe exactly its members' topics (least privilege,
  derived from the graph: ``adjacency[i, j] > 0``, robot i receives from robot j;
  ``leader[i] > 0``, robot i hears the leader);
* the report (which diagnostics the launcher waits for) and the refusals (which plant can
  run secure, on netns hosts, ...) through the plant's row (``formation_ilc.config.plants``).

Topic names are ``formation_ilc.core.names``'; a member's topics are relative to the
formation's namespace, or absolute (``/clock``, a driver's topics). This module is pure.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.enclaves import Grant, driver_enclave, enclave_path
from formation_ilc.config.plants import Plant, plant
from formation_ilc.core import names as nm
from formation_ilc.core.topology import Graph

if TYPE_CHECKING:
    from formation_ilc.config.runconfig import RunConfig

__all__ = ["TRIAL", "ONCE", "NEVER", "Member", "Lineup", "Roster", "Team", "roster",
           "DRIVER_NS", "ENTRY_SCRIPTS", "OPERATOR", "leader_clock_askers"]

#: whether the leader waits for a member's ready: before each trial, once for the whole
#: run (a passive reader: the monitor, the recorder), or never
TRIAL, ONCE, NEVER = "trial", "once", "never"

#: the ground station's operator: a client of its own (``ros2 service call``, a button)
#: in the monitor's enclave that presses the stop button (docs/real-robots.md, "Stopping");
#: no process of the launcher's
OPERATOR = "operator"

#: robot i's driver namespace by the bridges' driver kind (``{i}``: the robot's number)
DRIVER_NS = {"pioneer": "/pioneer_{i}", "base": "/base_{i}"}

#: the entry scripts of the processes the launcher starts (``pyproject.toml`` names their
#: modules; ``formation_ilc.plan.processes`` starts each as ``python -m MODULE``)
ENTRY_SCRIPTS = ("formation-ilc-virtual-leader", "formation-ilc-robot",
                 "formation-ilc-robot-sim", "formation-ilc-physics-sim",
                 "formation-ilc-link-emulator", "formation-ilc-recorder",
                 "formation-ilc-liveview", "formation-ilc-bridge",
                 "formation-ilc-fake-pioneer", "formation-ilc-physics-bases")


@dataclass(frozen=True)
class Member:
    """One node of the formation.

    name : its node name; also the launcher's process and log name.
    role : 'robot', 'plant', 'support' (the link emulator, the physics bases behind the
        bridges), 'leader', 'recorder', 'liveview', 'monitor' (in the launcher's process),
        'operator' (the stop button's client, in the monitor's enclave), 'driver' (a
        robot's driver).
    entry : the entry script the launcher starts it with; None: no process of the
        launcher's (the monitor runs inside it; an external plant or a real driver is
        started by someone else).
    waits : whether the leader waits for its ready (TRIAL, ONCE or NEVER).
    reports : whether the launcher waits for its last trial's diagnostics.
    enclave : its enclave's name in the formation's namespace (``enclave_path``).
    publish, subscribe : the ROS topics it may publish and subscribe: relative to the
        formation's namespace, or absolute.
    robot : the robot it belongs to (robots, bridges, drivers), else None.
    optional : no part of the run: nothing waits for it, and the run goes on without it
        once its restarts are used up (the live view).
    node_namespace : its own namespace when it is not the formation's (a driver's).
    dds_publish, dds_subscribe : services as DDS names (``rq/...Request``, ``rr/...Reply``).
    service_node : the node name its ROS housekeeping (services) runs under; ``*``: any
        node in its namespace (a driver whose node name is the driver's own).
    serves, calls : the formation's services (relative names) it offers, and calls
        (the leader offers ``stop``; only the ground station's monitor may call it).
    """

    name: str
    role: str
    entry: str | None
    waits: str
    reports: bool
    enclave: str
    publish: tuple[str, ...]
    subscribe: tuple[str, ...]
    robot: int | None = None
    optional: bool = False
    node_namespace: str | None = None
    dds_publish: tuple[str, ...] = ()
    dds_subscribe: tuple[str, ...] = ()
    service_node: str = ""
    serves: tuple[str, ...] = ()
    calls: tuple[str, ...] = ()


@dataclass(frozen=True)
class Lineup:
    """What the roster is built from: a run's options.

    n : robots; ``adjacency`` (n, n) and ``leader`` (n,): the scenario's graph (the topics
        each robot reads; without them every robot is taken to read nothing but its own:
        enough for names and processes, not for permissions).
    plant : a row of ``config.plants``; ``external``: an external plant's node names.
    links : 'emulated' (the link emulator runs), 'direct', or 'any' (a keystore's: every
        topic of both).
    mode : the trials' mode ('lockstep', 'realtime', 'wallclock'; 'any': a keystore's),
        or None: the plant's default (``run_mode``). It decides who reads ``/clock``: the
        leader in simulated time (lockstep, realtime), the link emulator in realtime.
    leader_in_step : the robots that see the leader take its link from their own sample
        (``RunConfig.leader_in_step``: lockstep with direct links), not from its messages.
    record, live : a recorder, the live view; ``monitor``: the launcher's monitor (a leader
        started alone has none).
    driver, driver_ns, base : the bridges' drivers: the Pioneer driver's kind, robot i's
        driver namespace (``{i}``; None: ``DRIVER_NS``'s), the base preset
        (``config.bases``).
    fake_drivers : a fake Pioneer driver per robot (the launcher starts them).
    physics_bases : physics robots behind the bases' interface (the launcher starts them).
    sensing : the robots' safety filter, and how it hears the others ('team': the plant's
        ``team/poses``; 'peers': every other robot's pose; 'any': a keystore's, both), or
        None without a filter.
    told : the robots tell each other their commands (``safety.motion: commands``).
    clocks : the clock exchanges of realtime and wall-clock runs (``protocol.timesync``):
        each robot asks the clocks it hears (its in-neighbours', the leader's if it sees
        it) and answers the robots that hear it; every bridge asks the leader's.
    """

    n: int
    plant: str = "sim"
    links: str = "emulated"
    mode: str | None = None
    record: bool = False
    live: bool = False
    monitor: bool = True
    external: tuple[str, ...] = ()
    driver: str = "rosaria"
    driver_ns: str | None = None
    base: str | None = None
    fake_drivers: bool = False
    physics_bases: bool = False
    sensing: str | None = None
    clocks: bool = False
    leader_in_step: bool = False
    told: bool = False
    adjacency: NDArray[np.float64] | None = field(default=None, compare=False)
    leader: NDArray[np.float64] | None = field(default=None, compare=False)

    @classmethod
    def of(cls, graph: Graph, **kw: Any) -> Lineup:
        """The lineup of a scenario's ``graph``."""
        a = np.asarray(graph.adjacency, dtype=float)
        return cls(n=a.shape[0], adjacency=a, leader=np.asarray(graph.leader, dtype=float),
                   **kw)

    @classmethod
    def of_run(cls, cfg: RunConfig, **kw: Any) -> Lineup:
        """The lineup of run configuration ``cfg``: its graph, its links, the robots'
        safety filter (how it hears the others, whether they tell their commands), the
        leader link taken in step, the clock exchanges. A robot's member follows from these
        alone: the planner builds the run's roster from them, and each robot node its own
        member from the configuration it runs (``nodes.robot``). ``kw``: the rest (the
        plant and its bridges, what else runs)."""
        safety = cfg.safety
        return cls.of(cfg.scenario.graph, links=cfg.links, mode=cfg.mode,
                      sensing=None if safety is None else safety.sensing,
                      told=safety is not None and safety.motion == "commands",
                      leader_in_step=cfg.leader_in_step, clocks=cfg.clock_exchanges, **kw)

    def for_keystore(self) -> Lineup:
        """Every member a run of this formation and plant may start, with every topic it
        may use: the link emulator, the recorder, the live view and the monitor too, every
        mode, and the safety filter's hearing and the clock exchanges (a keystore serves
        every run)."""
        return replace(self, links="any", mode="any", record=True, live=True, monitor=True,
                       sensing=None if self.row.sensing is None else "any", clocks=True,
                       leader_in_step=False, told=self.row.sensing is not None)

    @property
    def row(self) -> Plant:
        return plant(self.plant)

    @property
    def run_mode(self) -> str:
        """The trials' mode: ``mode``, else the plant's default (as the planner's): wall
        clock behind bridges, else lockstep."""
        return self.mode or ("wallclock" if self.row.per_robot else "lockstep")

    @property
    def true_state(self) -> bool:
        """Whether the robots' true trajectories are published (the metrics' true
        columns): by the plant (the simulator, the physics plant), or by each bridge of a
        physics base (``physics_bases``: the simulated bases report their true poses)."""
        return self.row.true_state or self.bases_truth

    @property
    def bases_truth(self) -> bool:
        """The bridges drive physics bases, which tell them their true poses."""
        return self.row.driver == "base" and self.physics_bases

    def driver_namespace(self, i: int) -> str:
        """Robot ``i``'s driver namespace (``{i}`` replaced; no trailing slash)."""
        pattern = self.driver_ns or DRIVER_NS.get(self.row.driver or "", "/")
        return pattern.replace("{i}", str(int(i))).rstrip("/") or ""


@dataclass(frozen=True)
class Team:
    """The nodes the leader waits for, by role, in the order the schedule lists them.

    robots : ``robot_1`` .. ``robot_n``.
    plants : the plant's nodes (``robot_sim``; ``physics_sim``; ``bridge_i`` per robot; or
        an external plant's names).
    support : the link emulator with emulated links.
    passive : readers that say ready once for the whole run (monitor, recorder).
    """

    robots: tuple[str, ...]
    plants: tuple[str, ...]
    support: tuple[str, ...] = ()
    passive: tuple[str, ...] = ()

    @property
    def expected(self) -> list[str]:
        """Every node the schedule waits for (the leader's ``nodes_expected``)."""
        return [*self.robots, *self.plants, *self.support, *self.passive]


@dataclass(frozen=True)
class Roster:
    """Every member of a run, in the launcher's start order: the monitor (inside the
    launcher, it joins first), the recorder (it listens before the run starts), the live
    view, the leader, the plant (and what it drives), the link emulator, the robots."""

    lineup: Lineup
    members: tuple[Member, ...]

    @property
    def plant(self) -> Plant:
        return self.lineup.row

    def by_role(self, *roles: str) -> tuple[Member, ...]:
        return tuple(m for m in self.members if m.role in roles)

    def member(self, name: str) -> Member:
        """The member named ``name`` (ValueError naming the members when none is)."""
        for m in self.members:
            if m.name == name:
                return m
        raise ValueError(f"no member {name!r} in the roster "
                         f"({', '.join(m.name for m in self.members)})")

    @property
    def team(self) -> Team:
        """The members the leader waits for, by role."""
        each = [m for m in self.members if m.waits == TRIAL]
        return Team(robots=tuple(m.name for m in each if m.role == "robot"),
                    plants=tuple(m.name for m in each if m.role == "plant"),
                    support=tuple(m.name for m in each if m.role == "support"),
                    passive=tuple(m.name for m in self.members if m.waits == ONCE))

    @property
    def processes(self) -> tuple[Member, ...]:
        """The members the launcher starts, in start order."""
        return tuple(m for m in self.members if m.entry is not None)

    @property
    def contact_watchers(self) -> tuple[str, ...]:
        """The members that watch the robots' bodies and report contacts: the physics
        plant's node, the physics bases (``physics_bases`` behind bridges)."""
        out = [self.plant.node] if self.plant.physics and self.plant.node else []
        if self.lineup.bases_truth:
            out.append(nm.BASES_NODE)
        return tuple(n for n in out if n is not None)

    @property
    def reporters(self) -> tuple[str, ...]:
        """Members besides the robots whose last trial's diagnostics the launcher waits for
        (timing, missed samples, injected delays, the bridges' returns, the recording)."""
        return tuple(m.name for role in ("plant", "support", "recorder")
                     for m in self.members if m.role == role and m.reports)

    @property
    def report_writers(self) -> tuple[str, ...]:
        """The members that write reports on the formation's ``diagnostics``, each in its
        own name (the launcher's monitor takes a report only from the writer of the node
        it names, and waits for the graph to name these writers before it says ready)."""
        return tuple(m.name for m in self.members
                     if nm.DIAGNOSTICS in m.publish and m.node_namespace is None)

    def writers_of(self, topic: str) -> tuple[str, ...]:
        """The members in the formation's namespace that publish ``topic`` (relative to
        the namespace): the nodes a reader takes it from (``protocol.writers``)."""
        return tuple(m.name for m in self.members
                     if topic in m.publish and m.node_namespace is None)

    def trajectory_writers(self) -> dict[str, tuple[str, ...]]:
        """Each robot's ``trajectory`` and ``true_trajectory`` topic -> its writers: the
        launcher's monitor takes a trial's rows from them only."""
        out = {}
        for i in range(1, self.lineup.n + 1):
            for topic in (nm.trajectory_topic(i), nm.true_trajectory_topic(i)):
                writers = self.writers_of(topic)
                if writers:
                    out[topic] = writers
        return out

    def enclave_of(self, process: str) -> str:
        """The enclave of a launcher process (a member's name), or ``process`` itself when
        no member has that name."""
        for m in self.members:
            if m.name == process:
                return m.enclave
        return process

    @staticmethod
    def topics(member: Member, namespace: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
        """(publish, subscribe) of ``member``: absolute in ``namespace``, sorted, ``/clock``
        as the launcher remaps it there (what its node's graph shows)."""
        clock = nm.clock_topic(namespace)

        def absolute(topics: Sequence[str]) -> tuple[str, ...]:
            return tuple(sorted({nm.absolute(clock if t == nm.CLOCK else t, namespace)
                                 for t in topics}))

        return absolute(member.publish), absolute(member.subscribe)

    def grants(self, namespace: str) -> dict[str, Grant]:
        """Every enclave's grant, by enclave path: its members' topics (``topics``) and
        services (the monitor's enclave holds the operator's too), under the node name
        and namespace of its first member."""

        def dds(serves: Sequence[str], calls: Sequence[str]) -> tuple[list[str], list[str]]:
            """A server reads requests and writes replies; a client the other way."""
            rq = [nm.service_dds_topics(nm.absolute(x, namespace)) for x in serves]
            cl = [nm.service_dds_topics(nm.absolute(x, namespace)) for x in calls]
            return [r[1] for r in rq] + [c[0] for c in cl], [r[0] for r in rq] + [c[1] for c in cl]

        out: dict[str, Grant] = {}
        for m in self.members:
            path = enclave_path(namespace, m.enclave)
            srv_pub, srv_sub = dds(m.serves, m.calls)
            pub, sub = self.topics(m, namespace)
            g = Grant(path, m.name if m.role != "driver" or m.robot is None else m.enclave,
                      m.node_namespace or namespace, pub, sub,
                      tuple(sorted({*m.dds_publish, *srv_pub})),
                      tuple(sorted({*m.dds_subscribe, *srv_sub})), m.service_node or m.name)
            out[path] = g if path not in out else _joined(out[path], g)
        return out


# --------------------------------------------------------------------------- building

def roster(lineup: Lineup) -> Roster:
    """The roster of ``lineup`` (ValueError for a plant that is not in the table)."""
    row = lineup.row
    n = lineup.n
    robots = range(1, n + 1)
    a = (np.zeros((n, n)) if lineup.adjacency is None
         else np.asarray(lineup.adjacency, dtype=float))
    w = np.zeros(n) if lineup.leader is None else np.asarray(lineup.leader, dtype=float)
    senders = [[int(j) + 1 for j in np.flatnonzero(a[i] > 0)] for i in range(n)]
    hears = [bool(w[i] > 0) for i in range(n)]
    protocol = (nm.READY, nm.DIAGNOSTICS, nm.ROS_DIAGNOSTICS)
    mode = lineup.run_mode
    members: list[Member] = []
    if lineup.monitor:
        # the launcher's monitor: the trajectories (the true ones where a plant has them)
        # for metrics.csv, the reports, the leader's events; it says ready, and answers a
        # forged 'down' of itself by saying ready again
        true = [nm.true_trajectory_topic(i) for i in robots] if lineup.true_state else []
        members.append(Member(
            nm.MONITOR_NODE, "monitor", None, ONCE, False, nm.MONITOR_NODE, (nm.READY,),
            (*(nm.trajectory_topic(i) for i in robots), *true, nm.DIAGNOSTICS,
             nm.TRIAL_EVENTS, nm.READY)))
        # the ground station's enclave is the one that may press the stop button (call
        # the leader's stop, latch the e-stop, see it latched): an operator's client of its
        # own does, beside the monitor, which does neither (docs/real-robots.md)
        members.append(Member(OPERATOR, "operator", None, NEVER, False, nm.MONITOR_NODE,
                              (nm.ESTOP,), (nm.ESTOP,), calls=(nm.STOP_SERVICE,)))
    if lineup.record:
        members.append(Member(
            nm.RECORDER_NODE, "recorder", "formation-ilc-recorder", ONCE, True,
            nm.RECORDER_NODE, (*protocol, *nm.view_topics(n)), tuple(nm.recorded_topics(n))))
    if lineup.live:
        # the live view reads what the recording holds and serves it on 127.0.0.1
        members.append(Member(
            nm.LIVEVIEW_NODE, "liveview", "formation-ilc-liveview", NEVER, False,
            nm.LIVEVIEW_NODE, tuple(nm.view_topics(n)),
            (*nm.recorded_topics(n), *nm.view_topics(n), nm.PREVIEW), optional=True))
    # the clocks' questions and answers (lineup.clocks): the leader answers the robots
    # that see it and every bridge
    leader_pub: list[str] = []
    leader_sub: list[str] = []
    if lineup.clocks:
        bridges = [nm.bridge_name(i) for i in robots] if row.per_robot else []
        leader_sub += [nm.clock_ping_topic(a) for a in leader_clock_askers(w, bridges)]
        if leader_sub:
            leader_pub.append(nm.clock_pong_topic(nm.LEADER))
    members.append(Member(
        nm.LEADER_NODE, "leader", "formation-ilc-virtual-leader", NEVER, False, nm.LEADER_NODE,
        (nm.CONFIG, nm.REFERENCE, nm.TRIAL_EVENTS, nm.DIAGNOSTICS, nm.ROS_DIAGNOSTICS,
         nm.ESTOP, nm.TF, *leader_pub),
        # its own events too: it re-asserts against a start or abort it did not send (a
        # buggy node's, or a lossy link's replay); the nodes' reports, for the endpoints
        # a node still waits for at start-up (its watchdog names them); the e-stop (one
        # the ground station latched ends the run too); the plant's /clock in simulated
        # time (wall-clock trials have none: it samples on its own timer)
        (nm.READY, nm.CONFIG, *([nm.CLOCK] if mode != "wallclock" else []), nm.TRIAL_EVENTS,
         nm.DIAGNOSTICS, nm.ESTOP, *leader_sub), serves=(nm.STOP_SERVICE,)))
    members += _plant(lineup, row)
    if lineup.links in ("emulated", "any"):
        links_pub = [nm.link_topic(i, nm.robot_name(j)) for i in robots
                     for j in senders[i - 1]]
        links_pub += [nm.link_topic(i, nm.LEADER) for i in robots if hears[i - 1]]
        members.append(Member(
            nm.LINKS_NODE, "support", "formation-ilc-link-emulator", TRIAL, True, nm.LINKS_NODE,
            (*links_pub, *protocol),
            # every robot's shared pose, the leaves' too; /clock ticks it in realtime (in
            # lockstep the poses themselves do)
            (*(nm.shared_pose_topic(j) for j in robots), nm.REFERENCE, nm.TRIAL_EVENTS,
             nm.CONFIG, *([nm.CLOCK] if mode in ("realtime", "any") else []))))
    hearers = [[i for i in robots if j in senders[i - 1]] for j in robots]
    for i in robots:
        members.append(_robot(i, senders[i - 1], hears[i - 1], lineup, hearers[i - 1]))
    return Roster(lineup, tuple(members))


def _joined(a: Grant, b: Grant) -> Grant:
    """Grant ``a`` with ``b``'s topics and services too (two members of one enclave)."""
    def union(x: Sequence[str], y: Sequence[str]) -> tuple[str, ...]:
        return tuple(sorted({*x, *y}))

    return replace(a, publish=union(a.publish, b.publish),
                   subscribe=union(a.subscribe, b.subscribe),
                   dds_publish=union(a.dds_publish, b.dds_publish),
                   dds_subscribe=union(a.dds_subscribe, b.dds_subscribe))


def leader_clock_askers(leader: Iterable[float], bridges: Sequence[str]) -> list[str]:
    """Who asks the leader's clock, the team's clock reference (``protocol.timesync``):
    each robot that hears the leader (``leader``: the graph's weights), and every bridge
    (``bridges``), which samples on the leader's clock. The roster grants these questions
    and the leader answers them (``virtual_leader.node``): one rule for both."""
    return [*(nm.robot_name(i + 1) for i, wi in enumerate(leader) if wi > 0), *bridges]


def _robot(i: int, senders: list[int], hears_leader: bool, lineup: Lineup,
           hearers: list[int]) -> Member:
    """Robot i (1-based), exactly what its node publishes and reads: its own topics
    out; its pose, its in-neighbours' trajectories and its links in (the emulator's ticks,
    or their shared poses and the leader's reference on direct links, the reference not
    when the leader link is its own sample); with a safety filter the others' poses too
    (the plant's ``team/poses``, or each other robot's pose) and, told, their commands;
    with the clock exchanges its questions to the clocks it hears (``senders``, the
    leader) and its answers to the robots that hear it (``hearers``)."""
    others = [j for j in range(1, lineup.n + 1) if j != i]
    sub = [nm.pose_topic(i), nm.CONFIG, nm.TRIAL_EVENTS, nm.ESTOP]
    sub += [nm.trajectory_topic(j) for j in senders]
    leader_link = hears_leader and not lineup.leader_in_step
    if lineup.links in ("emulated", "any"):
        sub += [nm.link_topic(i, nm.robot_name(j)) for j in senders]
        sub += [nm.link_topic(i, nm.LEADER)] if leader_link else []
    if lineup.links in ("direct", "any"):
        sub += [nm.shared_pose_topic(j) for j in senders]
        sub += [nm.REFERENCE] if leader_link else []
    pub = [nm.cmd_vel_topic(i), nm.shared_pose_topic(i), nm.trajectory_topic(i), nm.READY,
           nm.DIAGNOSTICS, nm.ROS_DIAGNOSTICS]
    if lineup.sensing in ("team", "any"):  # the plant's team/poses
        sub.append(nm.TEAM_POSES)
    if lineup.sensing in ("peers", "any"):  # every other robot's pose
        sub += [nm.pose_topic(j) for j in others]
    if lineup.sensing is not None and lineup.told:  # ``safety.motion: commands``
        sub += [nm.applied_topic(j) for j in others]
        pub.append(nm.applied_topic(i))
    if lineup.clocks:  # each node publishes on topics of its own name only
        me = nm.robot_name(i)
        asks = [nm.robot_name(j) for j in senders] + ([nm.LEADER] if hears_leader else [])
        if asks:
            pub.append(nm.clock_ping_topic(me))
            sub += [nm.clock_pong_topic(a) for a in asks]
        if hearers:
            pub.append(nm.clock_pong_topic(me))
            sub += [nm.clock_ping_topic(nm.robot_name(k)) for k in hearers]
    return Member(nm.robot_name(i), "robot", "formation-ilc-robot", TRIAL, True,
                  nm.robot_name(i), tuple(pub), tuple(sub), robot=i)


def _plant(lineup: Lineup, row: Plant) -> list[Member]:
    """The plant's members: its node (or external names), or the bridges with what they
    drive (the physics bases first, else each robot's driver before its bridge)."""
    robots = range(1, lineup.n + 1)
    if row.node is not None:
        pub = [*(nm.pose_topic(i) for i in robots),
               *(nm.robot_description_topic(i) for i in robots)]
        if row.true_state:
            pub += [nm.true_trajectory_topic(i) for i in robots]
        if row.clock:
            pub.append(nm.CLOCK)
        pub += [nm.READY, nm.DIAGNOSTICS, nm.ROS_DIAGNOSTICS, nm.TF, nm.TF_STATIC]
        if row.true_state:
            pub.append(nm.PREVIEW)
        if lineup.sensing in ("team", "any"):
            pub.append(nm.TEAM_POSES)
        return [Member(row.node, "plant", row.entry, TRIAL, row.reports, row.node, tuple(pub),
                       (*(nm.cmd_vel_topic(i) for i in robots), nm.TRIAL_EVENTS, nm.CONFIG))]
    if not row.per_robot:  # external: its nodes are the user's, granted nothing here
        return [Member(name, "plant", None, TRIAL, row.reports, name, (), ())
                for name in lineup.external]
    out: list[Member] = []
    cmd, odom, motors, kind = _driver_topics(lineup)
    truth = lineup.bases_truth
    if truth:
        # the physics bases follow the trials (their contacts are counted per trial and
        # return, and a contact asks the leader to abort its trial): the leader waits for
        # them as for the link emulator
        out.append(Member(
            nm.BASES_NODE, "support", "formation-ilc-physics-bases", TRIAL, True,
            nm.BASES_NODE,
            (*(f"{lineup.driver_namespace(i)}/{odom}" for i in robots),
             *(f"{lineup.driver_namespace(i)}/{nm.BASE_TRUTH}" for i in robots),
             nm.READY, nm.DIAGNOSTICS, nm.ROS_DIAGNOSTICS),
            (*(f"{lineup.driver_namespace(i)}/cmd_vel" for i in robots), nm.TRIAL_EVENTS,
             nm.CONFIG)))
    for i in robots:
        ns = lineup.driver_namespace(i)
        c, o, mo = f"{ns}/{cmd}", f"{ns}/{odom}", f"{ns}/{motors}"
        bridge_pub = [nm.pose_topic(i), nm.READY, nm.DIAGNOSTICS, nm.ROS_DIAGNOSTICS, c, nm.TF,
                      nm.TF_STATIC, nm.robot_description_topic(i)]
        bridge_sub = [nm.cmd_vel_topic(i), nm.TRIAL_EVENTS, nm.CONFIG, nm.ESTOP, o]
        if truth:  # the simulated base's true pose in, the trial's true trajectory out
            bridge_pub.append(nm.true_trajectory_topic(i))
            bridge_sub.append(f"{ns}/{nm.BASE_TRUTH}")
        if lineup.sensing is not None:  # the returns' filter: where every robot is
            bridge_pub.append(nm.whereabouts_topic(i))
            bridge_sub += [nm.whereabouts_topic(j) for j in robots if j != i]
        if lineup.clocks:  # it asks the leader's time
            bridge_pub.append(nm.clock_ping_topic(nm.bridge_name(i)))
            bridge_sub.append(nm.clock_pong_topic(nm.LEADER))
        # (not a fake driver's truth report: only a test that starts one by hand asks for
        # it, -p truth_period:=S; the launcher's do not, and a real driver has none)
        driver_pub, driver_sub = [o], [c]
        rq = rr = ""
        if kind == "p2os_motor_state":
            bridge_pub.append(mo)
            driver_sub.append(mo)
        elif kind != "none":  # a service: requests from the bridge, replies from the driver
            rq, rr = f"rq{mo}Request", f"rr{mo}Reply"
        if not truth:
            fake = lineup.fake_drivers and row.driver == "pioneer"
            out.append(Member(
                nm.fake_driver_name(i) if fake else driver_enclave(i), "driver",
                "formation-ilc-fake-pioneer" if fake else None, NEVER, False,
                driver_enclave(i), tuple(driver_pub), tuple(driver_sub), robot=i,
                node_namespace=ns or "/", dds_publish=(rr,) if rr else (),
                dds_subscribe=(rq,) if rq else (), service_node="*"))
        out.append(Member(
            nm.bridge_name(i), "plant", row.entry, TRIAL, row.reports, nm.bridge_name(i),
            tuple(bridge_pub), tuple(bridge_sub), robot=i, dds_publish=(rq,) if rq else (),
            dds_subscribe=(rr,) if rr else ()))
    return out


def _driver_topics(lineup: Lineup) -> tuple[str, str, str, str]:
    """(cmd, odom, motors, motors kind) of the bridges' drivers, relative to each driver's
    namespace: a Pioneer driver's (``names.DRIVERS``), or the base preset's."""
    if lineup.row.driver == "base":
        from formation_ilc.config.bases import base_preset

        spec = nm.DRIVERS["base"]
        preset = base_preset(lineup.base) if lineup.base else None
        if preset is not None:
            return preset.cmd_topic, preset.odom_topic, spec.motors, spec.motors_kind
        return spec.cmd, spec.odom, spec.motors, spec.motors_kind
    spec = nm.DRIVERS[lineup.driver]
    return spec.cmd, spec.odom, spec.motors, spec.motors_kind
