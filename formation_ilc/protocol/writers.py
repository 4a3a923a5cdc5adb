"""Each topic from its own writer: the writers a node accepts a message from, by topic.

DDS delivers to a reader every matched writer's samples; the ROS graph names each writer
(its GID, 16 bytes) with the node that created it. A node that takes a message with its
writer's GID (``formation_ilc.nodes.writers``) asks this table whether that writer may
write the topic:

* a topic of one owner (a robot's ``pose`` from the plant, the plant's ``team/poses``, a
  base's ``truth`` from the physics bases): only writers of the owner's node, in the
  formation's namespace (``owned``);
* a shared topic (``ready``, ``diagnostics``: every node writes them, each in its own
  name): only a writer of the node the message names (``claims``); the launcher's monitor
  may also say that another node is ``down`` (it saw its process die).

A writer the graph does not list yet, or lists without its node's name (the node's
``ros_discovery_info`` comes after its endpoints), is ``UNKNOWN``: the caller holds the
message, learns the topic's writers again (``learn``, at most every ``REFRESH`` seconds a
topic) and asks again, for up to ``HOLD`` seconds. A writer the graph still lists without
a name then (``patient``) is taken as the node the message is for only when no named writer
of the topic can be that node: the graph loses a participant's node names for good when the
participant is dropped on its lease and found again (``nodes.common.readers_wanting``), and
a member must not be shut out of its run for that.

The graph's node names are what each participant says of itself: a second process may
name its node after another (``robot_1``). On a shared topic each node name is therefore
pinned to one DDS participant (the first 12 bytes of a writer's GID, its GUID prefix in
Fast DDS; one rclpy context, one participant): the participant first seen writing under a
name holds it while the graph lists it on that topic. A writer of another participant
under the same name is held (UNKNOWN) while the holder is listed: a restarted node's new
participant comes while its killed predecessor is still listed, until that one's lease
runs out (20 s, measured). It is refused as an impostor (sender ``NAME (second
participant)``, and every later message of its participant under that name) as soon as
the holder is heard again after it came (the holder lives), or after ``PIN_HOLD`` seconds
of the holder still listed; it takes the name when the holder leaves the graph first, or
when the launcher's monitor says the name's node is ``down`` (it restarts it). Owned
topics are judged by name only: a restarted plant's samples must not wait for its
predecessor's lease, and no ``down`` reaches the robots.

With ``--secure``, a writer exists only where its enclave's permissions grant the topic
(the owners' topics), and the participant behind a GID is authenticated: its GUID prefix
begins with bits of its certificate's subject (``enclave_prefix``), which the handshake
checks. A table given the formation's enclaves (``enclaves``) pins each of those names
to its enclave instead of to a first participant: an insider with one robot's enclave
that names its node after another robot is refused at its first message, and a
restarted node is taken at once (docs/security.md).

Everything refused is counted by topic and sender (``forged``), for the node's diagnostics,
the launcher's console and the report. Pure: no ROS.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from formation_ilc.config.enclaves import enclave_prefix
from formation_ilc.config.plants import PLANT_TABLE
from formation_ilc.core import names as nm

__all__ = ["WriterTable", "UNKNOWN", "OK", "REFRESH", "HOLD", "PIN_HOLD", "UNKNOWN_NODE",
           "full_name", "participant", "enclave_prefix", "plant_writers", "forged_line"]

#: the verdicts besides a refusal's text
OK, UNKNOWN = "ok", "unknown"
#: [s] at most this often a topic's writers are asked of the graph again
REFRESH = 0.05
#: [s] a message of a writer the graph does not name yet is held this long, then refused
HOLD = 5.0
#: [s] a message of a second participant under a held node name is held this long while the
#: holder is listed and silent (longer than Fast DDS's participant lease, 20 s: a killed
#: node's participant stays listed that long after its restart)
PIN_HOLD = 30.0
#: bytes of a GID that name its participant (Fast DDS: the GUID prefix; the last 4 are the
#: entity id; measured: the writers of one rclpy context share them, two processes do not)
PARTICIPANT = 12
#: participants, pins and impostors a table keeps at most (a flood of fake participants)
_MAX = 4096
#: the node name the ROS graph gives an endpoint whose participant's node list it lacks
#: (rmw_dds_common's GraphCache)
UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"


def full_name(namespace: str, name: str) -> str:
    """``/ns/name`` of a node."""
    return f"{namespace.rstrip('/')}/{name}"


def participant(gid: bytes) -> bytes:
    """The participant of writer ``gid`` (its GUID prefix)."""
    return bytes(gid[:PARTICIPANT])


def plant_writers() -> frozenset[str]:
    """The node names a plant of one node publishes the robots' poses and ``team/poses``
    under (the plant table's rows with a node of their own)."""
    return frozenset(r.node for r in PLANT_TABLE if r.node)


@dataclass
class WriterTable:
    """The writers one node accepts, and what it refused.

    namespace : the formation's namespace (a writer elsewhere is never an owner).
    owners : topic (absolute) -> the node names that may write it; a topic not in it is
        shared (each message names its node: ``claims``).
    """

    namespace: str
    owners: dict[str, frozenset[str]] = field(default_factory=dict)
    #: topic -> writer GID -> the writer's node, as the graph names it (``/ns/name``)
    gids: dict[str, dict[bytes, str]] = field(default_factory=dict)
    #: topic -> GIDs the graph lists without their node's name
    unnamed: dict[str, set[bytes]] = field(default_factory=dict)
    #: (topic, sender) -> messages refused; sender: the writer's node, "?" if never named
    forged: Counter[tuple[str, str]] = field(default_factory=Counter)
    #: topic -> the participants of its writers, as last learnt
    listed: dict[str, set[bytes]] = field(default_factory=dict)
    #: (topic, node /ns/name) -> the participant that holds the node's name on a shared topic
    holders: dict[tuple[str, str], bytes] = field(default_factory=dict)
    #: node /ns/name -> participants refused as impostors under its name
    impostors: dict[str, set[bytes]] = field(default_factory=dict)
    #: node /ns/name -> participants that held the name until the node went ``down``: the
    #: last messages of a killed predecessor, still in a reader's queue, are its own and
    #: taken, but never take the name back from its successor
    retired: dict[str, set[bytes]] = field(default_factory=dict)
    #: node /ns/name -> the GUID prefix bytes of a participant authenticated in the
    #: node's enclave (``enclave_prefix``; ``--secure``: ``store.keystore.enclave_prefixes``):
    #: such a node's name is pinned to its enclave, not to the first participant
    enclaves: dict[str, bytes] = field(default_factory=dict)
    #: (node /ns/name, boot) of every down taken: a latched down heard again (a reader that
    #: matched its writer anew) frees the name of the node's successor no more
    downs: set[tuple[str, str]] = field(default_factory=set)
    #: (node /ns/name, participant) -> the message count when a second participant's first
    #: message under the name was held
    pending: dict[tuple[str, bytes], int] = field(default_factory=dict)
    #: participant -> the message count of the last message taken from it as a holder
    spoke: dict[bytes, int] = field(default_factory=dict)
    _count: int = 0
    _asked: dict[str, float] = field(default_factory=dict)
    _first: set[tuple[str, bytes]] = field(default_factory=set)

    def own(self, topic: str, *nodes: str) -> None:
        """Only ``nodes`` (names in the formation's namespace) may write ``topic``."""
        self.owners[topic] = frozenset(nodes)

    # -------------------------------------------------------------------- the graph
    def due(self, topic: str, now: float, gid: bytes | None = None) -> bool:
        """Whether the graph may be asked for ``topic``'s writers again (at most every
        REFRESH seconds; at once for a writer ``gid`` not asked about before, so that a
        new writer's first message is not held), marking it asked."""
        key = (topic, bytes(gid)) if gid is not None else None
        if key is not None and key not in self._first and len(self._first) < 4096:
            self._first.add(key)
        elif now - self._asked.get(topic, -1e9) < REFRESH:
            return False
        self._asked[topic] = now
        return True

    def learn(self, topic: str, endpoints: Iterable[tuple[bytes, str, str]]) -> None:
        """The graph's writers of ``topic``: (GID, node name, node namespace) each; a
        writer it names without its node's name is left out (still unknown)."""
        known = self.gids.setdefault(topic, {})
        unnamed = self.unnamed.setdefault(topic, set())
        endpoints = list(endpoints)
        # the participants listed now: a holder not among them has left (a named or an
        # unnamed writer of it keeps it)
        self.listed[topic] = {participant(g) for g, _, _ in endpoints[:_MAX]}
        for gid, name, ns in endpoints:
            if name and name != UNKNOWN_NODE:
                known[bytes(gid)] = full_name(ns, name)
                unnamed.discard(bytes(gid))
            elif len(unnamed) < 4096:
                unnamed.add(bytes(gid))
        if len(known) > 4096:  # writers come and go over a long run: keep the newest
            for g in list(known)[:len(known) - 4096]:
                del known[g]

    def writer(self, topic: str, gid: bytes) -> str | None:
        """The node (``/ns/name``) of writer ``gid`` of ``topic``, None if not known."""
        return self.gids.get(topic, {}).get(bytes(gid))

    # -------------------------------------------------------------------- verdicts
    def _named(self, topic: str, node: str) -> bool:
        """Whether a writer of ``topic`` the graph names is ``node`` (formation's
        namespace)."""
        return full_name(self.namespace, node) in self.gids.get(topic, {}).values()

    def not_named(self, topic: str, nodes: Iterable[str]) -> list[str]:
        """The ``nodes`` (formation's namespace) of which the graph names no writer of
        ``topic`` yet (as last learnt)."""
        return [n for n in nodes if not self._named(topic, n)]

    def judge(self, topic: str, gid: bytes, patient: bool = False) -> str:
        """OK when writer ``gid`` may write ``topic`` (an owned topic: one of its owners;
        a shared one: any node of the formation's namespace, ``claims`` decides the
        rest), UNKNOWN when the graph does not name it yet, else why not (counted).
        ``patient``: the message waited HOLD seconds; a writer the graph lists without a
        name passes for an owner no named writer is (a shared topic: ``claims``)."""
        who = self.writer(topic, gid)
        if who is None:
            if not patient or bytes(gid) not in self.unnamed.get(topic, set()):
                return UNKNOWN
            owners = self.owners.get(topic)
            if owners is None or not any(self._named(topic, o) for o in owners):
                return OK
            return self.refuse(topic, "(unnamed)", f"{topic} from a writer the graph does "
                                                   f"not name, beside its named owner")
        ns, _, name = who.rpartition("/")
        if (ns or "/") != (self.namespace.rstrip("/") or "/"):
            return self.refuse(topic, who, f"{topic} from {who}, outside the formation's "
                                           f"namespace {self.namespace}")
        owners = self.owners.get(topic)
        if owners is not None and name not in owners:
            return self.refuse(topic, who, f"{topic} from {who}: only "
                                           f"{', '.join(sorted(owners))} write it")
        if owners is None:  # a shared topic: the name is its participant's
            return self._pinned(topic, gid, who, patient)
        return OK

    def _pinned(self, topic: str, gid: bytes, who: str, patient: bool) -> str:
        """OK when writer ``gid``'s participant holds node name ``who`` on ``topic`` (or
        takes it: nobody holds it, or its holder left the graph); UNKNOWN while a second
        participant's message waits for its holder to leave; else it is an impostor.
        Where ``enclaves`` names the node's enclave (``--secure``), only a participant
        authenticated in it is the node, from its first message on."""
        self._count += 1
        p = participant(gid)
        if p in self.impostors.get(who, ()):
            return self._impostor(topic, who, p, "")
        expected = self.enclaves.get(who)
        if expected is not None:
            if p[:len(expected)] == expected:
                return OK
            return self._impostor(topic, who, p, ": not authenticated in its enclave")
        if p in self.retired.get(who, ()):
            return OK
        key = (topic, who)
        holder = self.holders.get(key)
        if holder is None or holder == p or holder not in self.listed.get(topic, ()):
            if holder != p and len(self.holders) < _MAX:
                self.holders[key] = p
            self.pending.pop((who, p), None)
            if len(self.spoke) < _MAX or p in self.spoke:
                self.spoke[p] = self._count
            return OK
        since = self.pending.get((who, p))
        if since is None:
            if len(self.pending) >= _MAX:
                return self._impostor(topic, who, p, "")
            since = self.pending[(who, p)] = self._count
        if self.spoke.get(holder, -1) > since:
            return self._impostor(topic, who, p, ": its holder spoke after it came")
        if not patient:
            return UNKNOWN
        return self._impostor(topic, who, p, f": its holder is still listed after "
                                             f"{PIN_HOLD:g} s")

    def _impostor(self, topic: str, who: str, p: bytes, why: str) -> str:
        """Refuse (and count) a message of participant ``p`` under node name ``who``,
        which another participant holds; ``p`` is an impostor of ``who`` from now on."""
        self.pending.pop((who, p), None)
        known = self.impostors.setdefault(who, set())
        if len(known) < _MAX:
            known.add(p)
        return self.refuse(topic, f"{who} (second participant)",
                           f"{topic} from a second participant named {who} "
                           f"({p.hex()}){why}")

    def hold_for(self, topic: str, gid: bytes) -> float:
        """[s] how long a message of writer ``gid`` that ``judge`` found UNKNOWN is held:
        PIN_HOLD for a second participant under a held name, else HOLD."""
        who = self.writer(topic, gid)
        return PIN_HOLD if who is not None and (who, participant(gid)) in self.pending \
            else HOLD

    def release(self, node: str, boot: str = "") -> None:
        """Node ``node`` (formation's namespace; its process ``boot``, as the launcher's
        down names it: once for each) went down and is started again: its name
        is free on every topic (the next participant seen under it that is no impostor
        takes it); what its holder's participant still sends under it is its last words,
        taken but holding nothing (``retired``)."""
        who = full_name(self.namespace, node)
        if boot:
            if (who, boot) in self.downs or len(self.downs) >= _MAX:
                return
            self.downs.add((who, boot))
        retired = self.retired.setdefault(who, set())
        for key in [k for k in self.holders if k[1] == who]:
            if len(retired) < _MAX:
                retired.add(self.holders[key])
            del self.holders[key]

    def claims(self, topic: str, gid: bytes, claimed: str, down: bool = False,
               boot: str = "") -> str:
        """OK when the writer of a message on a shared topic is the node it names
        (``claimed``), or the launcher's monitor saying that node (its process ``boot``)
        is ``down``; UNKNOWN or why not, as ``judge``."""
        if self.writer(topic, gid) is None and bytes(gid) in self.unnamed.get(topic, set()):
            # held HOLD seconds, still unnamed: only for a node no named writer is
            if isinstance(claimed, str) and claimed and not self._named(topic, claimed):
                return OK
            return self.refuse(topic, "(unnamed)", f"{topic} in the name of "
                                                   f"{str(claimed)[:100]!r} from a writer the "
                                                   f"graph does not name")
        verdict = self.judge(topic, gid)
        if verdict != OK:
            return verdict
        who = self.writer(topic, gid) or "?"
        name = who.rpartition("/")[2]
        if name == claimed:
            return OK
        if down and name == nm.MONITOR_NODE:
            # the launcher starts it again: its next participant takes the name
            self.release(claimed, boot)
            return OK
        return self.refuse(topic, who, f"{topic} in the name of {claimed[:100]!r} "
                                       f"from {who}")

    def refuse(self, topic: str, sender: str, why: str) -> str:
        """Count a refused message of ``sender`` on ``topic``; returns ``why``."""
        self.forged[(topic, sender[:200])] += 1
        return why

    def expire(self, topic: str) -> str:
        """A message held HOLD seconds whose writer the graph never named: refused."""
        return self.refuse(topic, "?", f"{topic} from a writer the graph never named "
                                       f"within {HOLD:g} s")

    # -------------------------------------------------------------------- reports
    @property
    def total(self) -> int:
        return sum(self.forged.values())

    def report(self) -> dict[str, dict[str, int]]:
        """What was refused: {topic: {sender: count}} (diagnostics ``forged``)."""
        out: dict[str, dict[str, int]] = {}
        for (topic, sender), n in sorted(self.forged.items()):
            out.setdefault(topic, {})[sender] = int(n)
        return out


def forged_line(reports: Mapping[str, Mapping[str, Any]]) -> str:
    """One line for the console: the messages refused for their writer, by topic and
    sender, summed over the nodes' ``forged`` reports ("" when none)."""
    total: Counter[tuple[str, str]] = Counter()
    for rep in reports.values():
        for topic, senders in (rep or {}).items():
            if isinstance(senders, Mapping):
                for sender, n in senders.items():
                    if isinstance(n, int) and not isinstance(n, bool) and n > 0:
                        total[(str(topic), str(sender))] += n
    if not total:
        return ""
    parts = [f"{n} on {t} from {s}" for (t, s), n in total.most_common(6)]
    more = len(total) - len(parts)
    return (f"forged: {sum(total.values())} messages refused, not from their topic's "
            f"writer: {'; '.join(parts)}" + (f"; {more} more" if more > 0 else ""))
