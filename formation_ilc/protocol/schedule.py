"""The trial schedule of a distributed run, and how it survives a process that dies.

Two numbers name a trial on the wire. The **iteration** ``i`` counts learning trials: the
plant draws its shifts, disturbances and noise, and the link emulator its delays, for
iteration ``i`` exactly as the batch simulator does. The **slot** ``q`` places a trial on the
sample grid (``SampleClock.stamp_ns(q, s)``): every label of the run belongs to one slot, and
slots only grow. Without faults ``q == i``. When a trial is interrupted (a node died and came
back), its slot is *aborted* and the same iteration runs again in the next slot: every label
of the broken attempt is then older than anything the new attempt sends, so no late message
of it can be mistaken for a new one.

Protocol (JSON on ``leader/trial_events``; ``ready`` from every node):

* ``start``  {trial: i, slot: q, seq, stamp_ns}: slot q runs iteration i. In simulated time
  the leader sends it again, unchanged, while the slot has had no new sample for a while
  (``StartRepeat``): for a follower whose reader matched after it went out.
* ``end``    {trial: i, slot: q, seq}: the leader's reference reached sample T.
* ``abort``  {trial: i, slot: q, seq, why}: forget slot q. A robot that already learned from it
  rolls back to the memory it had before (every robot keeps one step of history), so an
  aborted slot leaves no trace. The leader repeats the event until every node has
  answered it with a ``ready``.
Every event and ready also carries the run's identity (``run``, the configuration's
``run_id``): a node drops (``foreign``) those of another run on the same domain and
namespace. An ``abort`` also names the slot the team last committed (``kept``): that slot
stands, and a robot that undid its learning step on an abort the leader did not send
(a forgery, without sealed events) takes the step back (``RobotLearner.redo``).

**Sealed events.** DDS does not tell a reader which writer a sample came from: rclpy's
message info has no publisher GID (measured on Jazzy: source and received timestamps and
sequence numbers only, and the EventsExecutor the nodes spin cannot deliver it at all), and
a latched configuration's writer cannot be told from an events writer by anything a
sample carries. So the leader's events carry their writer's identity themselves: with a
run key (``seal``: HMAC-SHA256 of the event's JSON, ``tag``), which the launcher gives
every process it starts and nobody else. A follower with the key takes only events the key
sealed; anything else on the topic (a stale or second leader, a buggy node, a forger with
the run id) is ``foreign``. Without a key (nodes started by hand) events are taken
unsealed, as before: then the rules below still keep a forgery from taking back a
committed trial.

* ``ready``  {node, trial, boot, seen[, passive]} from a node that is idle: ``trial`` is, for
  a robot, the iteration it is ready to run (the number of iterations it has learned);
  ``boot`` identifies the process (a new value: the node restarted); ``seen`` is the
  ``seq`` of the last start or abort it has handled (every start and abort gets the next
  ``seq``, which survives a leader restart, so a ready sent before an event never counts as
  its answer); ``passive`` nodes (monitor, recorder) only watch and never hold the
  schedule. A ready counts once it arrives after the leader's last start or abort and
  answers it (``seen`` = its ``seq``), or comes from a process that has not seen any event
  (``seen`` = -1: it has just started and holds no trial).

Every node that follows the schedule (a plant, the link emulator, a bridge, a robot) takes
the leader's starts and aborts by one rule, ``Follower``: a start only of the slot after
the last one it started (a later one when every slot between was aborted), between trials,
once it has said ready since; each refusal is counted under one reason.

A slot is **committed** once every robot has learned from it (all report ``trial = i+1``).
Until then it can be aborted: a node that restarts while a slot is open (running, or ended
but not yet learned from by every robot) makes the leader abort it. The leader writes its
state (``committed``, last ``slot``, whether it is open) atomically at each change, and a
restarted leader aborts the slot it left open. No committed iteration is ever lost: robots
write their memory at each learning step (``formation_ilc.store.robotstate``).
"""

from __future__ import annotations

import hashlib
import hmac
import json
from collections.abc import Container
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from formation_ilc.core.clock import Malformed, Rejected, SampleClock, WallGrid
from formation_ilc.protocol.wallclock import check_start_wall
from formation_ilc.store.atomic import atomic_write_text
from formation_ilc.store.bounded import StateFileError, read_bounded

__all__ = ["START", "END", "ABORT", "DONE", "TrialEvent", "Ready", "Schedule",
           "ScheduleError", "Follower", "StartRepeat", "is_repeat", "unexplained_gap",
           "seal", "sealed", "parse_key", "KEY_BYTES", "boot_id", "boot_launcher"]

START, END, ABORT, DONE = "start", "end", "abort", "done"
EVENTS = (START, END, ABORT, DONE)


#: bytes of a run key (``parse_key``); a tag is the first 16 bytes of the HMAC, in hex
KEY_BYTES = 16
_TAG_HEX = 32


def parse_key(text: str | None) -> bytes | None:
    """The run key written as hex (an environment variable's value), None when empty;
    ValueError naming what is wrong otherwise."""
    if not text:
        return None
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        raise ValueError("the run key must be hexadecimal") from None
    if len(key) < KEY_BYTES:
        raise ValueError(f"the run key must have at least {KEY_BYTES} bytes, got {len(key)}")
    return key


def _int(d: dict[str, Any], key: str, default: int | None = None) -> int:
    if key not in d and default is None:
        raise Malformed(f"{key!r} is missing")
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, int):
        raise Malformed(f"{key!r} must be an integer, got {v!r}")
    return v


@dataclass(frozen=True)
class TrialEvent:
    """One event of the schedule; ``slot`` defaults to ``trial`` (a run without faults)."""

    event: str
    trial: int
    slot: int
    seq: int = -1
    stamp_ns: int | None = None
    start_wall_ns: int | None = None
    why: str = ""
    run: str = ""
    #: an abort's: the slot the team last committed, which stands (-1: none known)
    kept: int = -1
    #: the leader's seal (``seal``); "" unsealed
    tag: str = ""

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> TrialEvent:
        """The event of a decoded JSON object; Malformed naming the field."""
        ev = d.get("event")
        if ev not in EVENTS:
            raise Malformed(f"unknown trial event {ev!r}")
        trial = _int(d, "trial")
        slot = _int(d, "slot", trial)
        if trial < 0 or slot < trial:
            raise Malformed(f"trial {trial}, slot {slot}: need 0 <= trial <= slot")
        stamp = d.get("stamp_ns")
        wall = d.get("start_wall_ns")
        tag = d.get("tag", "")
        if not isinstance(tag, str) or len(tag) > 128:
            raise Malformed("'tag' must be a text of at most 128 characters")
        kept = _int(d, "kept", -1)
        if kept < -1 or kept >= slot and kept >= 0:
            raise Malformed(f"kept slot {kept} of an event of slot {slot}: need -1 <= kept "
                            f"< slot")
        return cls(str(ev), trial, slot, _int(d, "seq", -1),
                   None if stamp is None else _int(d, "stamp_ns"),
                   None if wall is None else _int(d, "start_wall_ns"), str(d.get("why", "")),
                   str(d.get("run", "")), kept, tag)

    def agree(self, clock: SampleClock | WallGrid) -> None:
        """A start of a wall-clock trial tells ``clock`` its slot's agreed start (then the
        slot's stamps decode); nothing for any other event. Rejected as ``clock.agree``."""
        if self.event == START and self.start_wall_ns is not None:
            clock.agree(self.slot, self.start_wall_ns)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"event": self.event, "trial": self.trial, "slot": self.slot,
                             "seq": self.seq}
        if self.stamp_ns is not None:
            d["stamp_ns"] = self.stamp_ns
        if self.start_wall_ns is not None:
            d["start_wall_ns"] = self.start_wall_ns
        if self.why:
            d["why"] = self.why
        if self.run:
            d["run"] = self.run
        if self.kept >= 0:
            d["kept"] = self.kept
        if self.tag:
            d["tag"] = self.tag
        return d


def _tag(ev: TrialEvent, key: bytes) -> str:
    body = ev.to_json()
    body.pop("tag", None)
    text = json.dumps(body, sort_keys=True, separators=(",", ":"))
    return hmac.new(key, text.encode(), hashlib.sha256).hexdigest()[:_TAG_HEX]


def seal(ev: TrialEvent, key: bytes | None) -> TrialEvent:
    """``ev`` sealed with the run key (its ``tag``); unchanged without a key."""
    if key is None:
        return ev
    return replace(ev, tag=_tag(ev, key))


def sealed(ev: TrialEvent, key: bytes | None) -> bool:
    """Whether ``ev`` carries the seal of ``key`` (always True without a key: a node
    started without one takes events unsealed)."""
    if key is None:
        return True
    return bool(ev.tag) and hmac.compare_digest(ev.tag, _tag(ev, key))


def boot_id(launcher: str | None = None) -> str:
    """A new node process's ``boot`` (``Ready.boot``): new for each process and, when a
    launcher started it, ``LAUNCHER.PROCESS`` with the launcher's own identity, so that a
    ground station tells a host whose launcher started again (every member's launcher
    new, even when it came back faster than the graph saw it go) from a member that host's
    launcher restarted (the same launcher)."""
    import uuid

    own = uuid.uuid4().hex[:12]
    tag = "".join(c for c in (launcher or "") if c.isalnum())[:16]
    return f"{tag}.{own}" if tag else own


def boot_launcher(boot: str) -> str | None:
    """The launcher's identity in a ``boot`` (:func:`boot_id`), or None."""
    tag, dot, _ = boot.partition(".")
    return tag if dot and tag else None


@dataclass(frozen=True)
class Ready:
    """A node's ``ready`` message."""

    node: str
    trial: int
    boot: str = ""
    seen: int = -1
    passive: bool = False
    run: str = ""
    #: said by a supervisor (the launcher), not the node: process ``boot`` of ``node`` died
    down: bool = False
    #: a plant asks the leader to abort slot ``abort_slot`` of the trial, saying why (its
    #: robots touched: ``--on-contact stop``); -1: no request
    abort_slot: int = -1
    why: str = ""
    #: what the node runs with, when it configured itself from its own parameters
    #: (``RunConfig.agreement``, or the part of it the node uses): the leader compares it
    #: with its own
    config: dict[str, Any] | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Ready:
        node = d.get("node")
        if not isinstance(node, str) or not node:
            raise Malformed(f"ready: node must be a name, got {node!r}")
        why = d.get("why", "")
        if not isinstance(why, str) or len(why) > 2000:
            raise Malformed("ready: why must be a text of at most 2000 characters")
        config = d.get("config")
        if config is not None and not (isinstance(config, dict) and len(config) <= 32
                                       and len(json.dumps(config)) <= 4000):
            raise Malformed("ready: config must be an object of at most 32 fields")
        return cls(node, _int(d, "trial"), str(d.get("boot", "")), _int(d, "seen", -1),
                   bool(d.get("passive", False)), str(d.get("run", "")),
                   bool(d.get("down", False)), _int(d, "abort_slot", -1), why, config)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {"node": self.node, "trial": self.trial, "boot": self.boot,
                             "seen": self.seen}
        if self.passive:
            d["passive"] = True
        if self.run:
            d["run"] = self.run
        if self.down:
            d["down"] = True
        if self.abort_slot >= 0:
            d["abort_slot"] = self.abort_slot
            d["why"] = self.why
        if self.config is not None:
            d["config"] = self.config
        return d


def unexplained_gap(k: int, slot: int, aborted: Container[int]) -> bool:
    """Whether a follower at slot ``k`` (-1: none yet, it takes any) must refuse the start of
    ``slot`` as too far ahead: a later slot than the next one is taken only when every slot
    between was aborted (their starts lost with a leader that was killed as it sent them;
    the restarted leader aborts the slot it left open)."""
    return k >= 0 and slot > k + 1 and not all(s in aborted for s in range(k + 1, slot))


@dataclass
class Follower:
    """What a node that follows the schedule (a plant, the link emulator, a bridge, a robot)
    makes of the leader's events: the one rule for taking a ``start`` or an ``abort``.

    ``take`` returns the start or abort to act on, None for an event that needs nothing (an
    ``end`` or ``done``, or an abort already answered: the leader repeats an abort until
    every node has answered it), and raises Rejected, with the reason it is counted under,
    for an event the node must not obey:

    * ``foreign``: of another run (``run``) on the same domain and namespace, or (with the
      run ``key``) not sealed by this run's leader;
    * ``stale``: a start whose ``seq`` was handled already, or of a slot not after the last
      one started here (the start taken, again, is the leader's repeat: None, not counted);
    * ``future``: a start beyond the next slot while a slot between was not aborted
      (``unexplained_gap``);
    * ``unexpected``: a start while the node is inside a trial (``idle`` False) or has not
      said ready since the last start it took;
    * wall-clock followers (``wall_trial_ns``, the length of a trial [ns]) also check the
      agreed start (``check_start_wall``): ``malformed`` without one, ``future`` too far
      ahead, ``stale`` if the trial would be over.

    A start taken names the slot the node runs (``slot``) and its iteration (``trial``);
    ``seen`` is the ``seq`` of the last start or abort taken, which the node's ready
    carries. ``said_ready`` must be called with every ready the node sends.
    """

    run: str = ""
    wall_trial_ns: int | None = None
    #: the node's sample grid: a start taken tells it the slot's agreed wall-clock start
    clock: SampleClock | WallGrid | None = None
    #: the run key: only events it sealed are taken (None: unsealed ones too)
    key: bytes | None = None
    seen: int = -1           # seq of the last start or abort taken
    start_seq: int = -1      # seq of the last start taken, while no abort followed it
    slot: int = -1           # the last slot started here (-1: none, any slot is next)
    trial: int = -1          # its iteration
    ready: bool = False      # a ready was said since the last start taken
    aborted: set[int] = field(default_factory=set)

    def take(self, ev: TrialEvent, idle: bool = True,
             now_wall_ns: int | None = None) -> TrialEvent | None:
        """The start or abort ``ev`` if the node acts on it (its state moves), else None or
        Rejected (see the class). ``idle``: the node is between trials; ``now_wall_ns``:
        the wall clock [ns], for wall-clock followers."""
        if ev.run and self.run and ev.run != self.run:
            raise Rejected("foreign", f"event of run {ev.run}")
        if not sealed(ev, self.key):
            raise Rejected("foreign", f"{ev.event} of slot {ev.slot} (seq {ev.seq}) not "
                                      f"sealed by this run's leader")
        if ev.event not in (START, ABORT):
            return None
        if ev.seq <= self.seen:
            if ev.event == START and not self.repeat(ev):
                raise Rejected("stale", f"start seq {ev.seq} again")
            return None  # an abort answered, or the start taken: repeats (StartRepeat)
        if ev.event == ABORT:
            self.seen, self.start_seq = ev.seq, -1
            self.aborted.add(ev.slot)
            return ev
        if self.wall_trial_ns is not None:
            if now_wall_ns is None:
                raise ValueError("a wall-clock follower needs the wall clock")
            check_start_wall(ev.start_wall_ns, now_wall_ns, self.wall_trial_ns)
        where = f"start of slot {ev.slot} in slot {self.slot}"
        if ev.slot <= self.slot:
            raise Rejected("stale", where)
        if unexplained_gap(self.slot, ev.slot, self.aborted):
            raise Rejected("future", where)
        if not idle or not self.ready:
            raise Rejected("unexpected", f"{where} ({'running' if not idle else 'not ready'})")
        if self.clock is not None:
            ev.agree(self.clock)
        self.seen, self.slot, self.trial, self.ready = ev.seq, ev.slot, ev.trial, False
        self.start_seq = ev.seq
        return ev

    def ran(self, slot: int) -> None:
        """The node ran ``slot`` without taking its start (a robot follows its own poses;
        the start was lost on its way): the slot is behind it, and the next slot's start
        is no gap (``future``) but the next one."""
        if slot > self.slot:
            self.slot, self.start_seq = slot, -1

    def repeat(self, ev: TrialEvent) -> bool:
        """Whether ``ev`` is the last start taken here, again (and no abort since)."""
        return is_repeat(ev, self.slot, self.start_seq)

    def said_ready(self) -> None:
        """The node sent a ready (it may take the next start once it is idle)."""
        self.ready = True


def is_repeat(ev: TrialEvent, slot: int, seq: int) -> bool:
    """Whether ``ev`` is the start of ``slot`` with ``seq`` (the last one a reader took; -1:
    none, or an abort since) again: the leader repeats a start while its slot does not
    move (``StartRepeat``), and a reader takes the repeat as no news."""
    return ev.event == START and ev.seq == seq >= 0 and ev.slot == slot


class StartRepeat:
    """Simulated time: the running slot's ``start`` goes out again while its trial does not
    move.

    The events topic keeps nothing for a reader that comes late, and DDS matches each side
    on its own: a follower that came back (the link emulator restarted, say) may say ready
    before the leader's events writer has matched its reader, and then never gets the next
    start. In lockstep the trial then waits for that node until the plant's time-out, and
    the plant's re-sent sample cannot help: a follower not told of a slot does not run it
    (a restarted one refuses its samples). So once a slot has had no new sample for
    ``every`` seconds since its start or its last sample, the leader sends the same start
    again (the same ``seq``), every ``every`` seconds, until the slot moves, ends or is
    aborted. A follower that took it ignores the repeat (``Follower.take``); one that lost
    it takes it then.
    """

    def __init__(self, every: float):
        self.every = every
        self.event: TrialEvent | None = None
        self.due = 0.0
        self.count = 0  # starts sent again (the leader's diagnostics)

    def sent(self, ev: TrialEvent, now: float) -> None:
        """The start ``ev`` went out at ``now``."""
        self.event, self.due = ev, now + self.every

    def moved(self, now: float) -> None:
        """The running slot's next sample came at ``now``."""
        self.due = now + self.every

    def stop(self) -> None:
        """The slot ended or was aborted: nothing to repeat."""
        self.event = None

    def again(self, now: float) -> TrialEvent | None:
        """The start to send again now, or None."""
        if self.event is None or now < self.due:
            return None
        self.due = now + self.every
        self.count += 1
        return self.event


class ScheduleError(RuntimeError):
    """The team cannot go on (a robot came back without its memory, say)."""


#: the most bytes a leader state file can hold (four small numbers)
STATE_LIMIT = 4096
#: slots and seqs above this are no run's (they travel as JSON numbers, exact to 2^53)
MAX_COUNT = 1 << 53


def read_state(path: Path, trials: int) -> dict[str, Any] | None:
    """The leader state in ``path`` (committed, slot, seq, open), None if there is no file.

    ScheduleError naming the file and the cause when it is not a regular file of at most
    STATE_LIMIT bytes (read without waiting on a FIFO, never a device read whole), not the
    JSON object the leader writes, or holds counters no run of ``trials`` trials can have
    written: ``0 <= committed <= trials``, ``seq >= slot`` (every slot's start took a
    seq)."""
    try:
        raw = read_bounded(path, STATE_LIMIT, "a leader state file")
    except StateFileError as exc:
        raise ScheduleError(f"unreadable schedule state: {exc}") from None
    if raw is None:
        return None
    try:
        d = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        raise ScheduleError(f"{path}: unreadable schedule state: {exc}") from None
    if not isinstance(d, dict):
        raise ScheduleError(f"{path}: bad schedule state: expected a JSON object, got "
                            f"{type(d).__name__}")
    try:
        out = {k: _int(d, k) for k in ("committed", "slot", "seq")}
    except Malformed as exc:
        raise ScheduleError(f"{path}: bad schedule state: {exc}") from None
    if "open" not in d:
        raise ScheduleError(f"{path}: bad schedule state: 'open' is missing")
    if not isinstance(d["open"], bool):
        raise ScheduleError(f"{path}: bad schedule state: 'open' must be true or false, got "
                            f"{str(d['open'])[:40]!r}")
    c, q, seq = out["committed"], out["slot"], out["seq"]
    why = (f"committed {c} is not in 0..{trials} (the run has {trials} trials)"
           if not 0 <= c <= trials else
           f"slot {q} is out of range" if not -1 <= q < MAX_COUNT else
           f"seq {seq} is out of range" if not -1 <= seq < (1 << 63) else
           f"seq {seq} below slot {q}: every slot's start took a seq" if seq < q else "")
    if why:
        raise ScheduleError(f"{path}: impossible schedule state: {why}")
    kept = d.get("kept")  # the slot last committed (files written before it have none)
    if kept is not None and (isinstance(kept, bool) or not isinstance(kept, int)
                             or not -1 <= kept <= q):
        raise ScheduleError(f"{path}: impossible schedule state: kept slot {kept!r} is not "
                            f"in -1..{q}")
    return out | {"open": d["open"], "kept": None if kept is None or kept < 0 else kept}


@dataclass
class Schedule:
    """The leader's bookkeeping, without ROS: who is ready, which slot is open, when the
    next trial may start, and when a slot must be aborted.

    expected : every node whose ``ready`` the schedule waits for.
    robots : the robot nodes among them (they carry the learning state).
    trials : iterations of the run.
    """

    expected: list[str]
    robots: set[str]
    trials: int
    committed: int = 0       # iterations every robot has learned
    slot: int = -1           # last slot started
    seq: int = -1            # sequence number of the last start or abort
    open: bool = False       # slot started and not committed (or aborted)
    running: bool = False    # slot started and its reference not at sample T
    abort_pending: int | None = None  # slot aborted, acks still awaited
    why: str = ""
    boots: dict[str, str] = field(default_factory=dict)
    ready: dict[str, Ready] = field(default_factory=dict)
    restarted: dict[str, int] = field(default_factory=dict)
    answered: set[str] = field(default_factory=set)  # idle since the last start or abort
    #: what this leader process sent: seq -> (event, trial, slot)
    sent: dict[int, tuple[str, int, int]] = field(default_factory=dict)
    #: the slot of the last committed iteration (saved with the state), None: unknown
    committed_slot: int | None = None
    #: foreign starts and aborts seen (events this leader did not send)
    foreign_events: int = 0
    #: robots asked to take back a learning step they undid, by (node, boot): asked once
    redo_asked: set[tuple[str, str]] = field(default_factory=set)

    # ------------------------------------------------------------------ persistence
    def state(self) -> dict[str, Any]:
        return {"committed": self.committed, "slot": self.slot, "seq": self.seq,
                "open": self.open or self.abort_pending is not None,
                "kept": -1 if self.committed_slot is None else self.committed_slot}

    def save(self, path: Path | None) -> None:
        if path is not None:
            atomic_write_text(path, json.dumps(self.state()) + "\n")

    def restore(self, path: Path) -> bool:
        """Continue from a state file (a restarted leader, ``launch --resume``): a slot
        left open is aborted first. False if there is no file. ScheduleError naming the
        file when it cannot be this run's state (see :func:`read_state`)."""
        st = read_state(path, self.trials)
        if st is None:
            return False
        self.committed, self.slot, self.seq = st["committed"], st["slot"], st["seq"]
        self.committed_slot = st["kept"] if self.committed else None
        self.open = self.running = False
        if st["open"]:
            self.begin_abort("the leader restarted")
        return True

    # ------------------------------------------------------------------ events
    def on_ready(self, r: Ready) -> str | None:
        """Take a node's ready. Returns why the open slot must be aborted (a node
        restarted while it was open, or a plant asked for it: its robots touched), else
        None."""
        if r.node not in self.expected:
            return None
        if r.down:
            # the process that said ready is gone: wait for the one that replaces it (a
            # recorder restarted before the next start loses nothing of the trials after)
            # only a passive node's (its death is seen by nobody else): an active node's
            # restart shows in its new ready, and a forged "down" must not make the
            # schedule wait for a robot that is alive and has said all it will say
            last = self.ready.get(r.node)
            if self.boots.get(r.node) == r.boot and last is not None and last.passive:
                self.ready.pop(r.node, None)
                self.answered.discard(r.node)
            return None
        old = self.boots.get(r.node)
        self.boots[r.node] = r.boot
        self.ready[r.node] = r
        abort = None
        if (r.abort_slot >= 0 and r.abort_slot == self.slot and r.node not in self.robots
                and not r.passive and (self.open or self.running)
                and self.abort_pending is None):
            # a plant asks: its robots touched in this slot (it stopped them)
            abort = f"{r.node}: {r.why}" if r.why else f"{r.node} asked"
            self.begin_abort(abort)
        if r.seen < 0 or r.seen >= self.seq:
            self.answered.add(r.node)
        if old is not None and old != r.boot:
            self.restarted[r.node] = self.restarted.get(r.node, 0) + 1
            # a passive node (monitor, recorder) holds nothing of the trial
            if self.open and self.abort_pending is None and not r.passive:
                abort = f"{r.node} restarted during slot {self.slot}"
                self.begin_abort(abort)
                if r.seen < 0:  # the new process holds nothing of the aborted slot
                    self.answered.add(r.node)
        self._maybe_commit()
        return abort

    def seen_unsent(self, r: Ready) -> str | None:
        """After :meth:`on_ready`: a ready whose ``seen`` is beyond the last ``seq`` this
        leader gave out comes from a node that handled a start or abort the leader never
        sent nor saw (a forged one, or one of a buggy node). ``on_ready`` takes it as an
        answer (it is idle); the leader then re-asserts its schedule (:meth:`reassert`).
        Returns why (an abort is then pending), else None."""
        if r.down or r.node not in self.expected or r.seen <= self.seq:
            return None
        self.foreign_events += 1
        return self.reassert(r.seen, f"{r.node} saw seq {r.seen}, which the leader did not "
                                     f"send")

    def begin_abort(self, why: str, slot: int | None = None) -> None:
        """Abort the open slot (or ``slot``): it gets the next ``seq``; every node must
        answer."""
        self.abort_pending = self.slot if slot is None else slot
        self.slot = max(self.slot, self.abort_pending)
        self.why = why
        self.open = self.running = False
        self.seq += 1
        self.answered.clear()
        self.sent[self.seq] = (ABORT, self.committed, self.abort_pending)

    @property
    def kept(self) -> int:
        """The slot the team last committed, which an abort names (-1: none known)."""
        return -1 if self.committed_slot is None else self.committed_slot

    def undone(self) -> str | None:
        """Robots that report one trial fewer than the team committed, idle: each undid
        the learning step of the committed slot on an abort the leader did not send (one
        it never saw). They are asked once per process to take it back (an abort of the
        next slot, naming the committed one as ``kept``); returns why, else None."""
        if self.abort_pending is not None or self.open or self.running \
                or self.committed_slot is None:
            return None
        behind = [n for n in sorted(self.robots) if n in self.ready
                  and self.ready[n].trial == self.committed - 1 and self._idle(n)
                  and (n, self.ready[n].boot) not in self.redo_asked]
        if not behind:
            return None
        self.redo_asked.update((n, self.ready[n].boot) for n in behind)
        why = (f"{', '.join(behind)} undid trial {self.committed - 1} (slot "
               f"{self.committed_slot}), which every robot had learned: it stands")
        self.begin_abort(why, self.slot + 1)
        return why

    def foreign(self, ev: TrialEvent) -> str | None:
        """Check a start or abort of this run seen on the events topic. One this leader did
        not send (a forger, a buggy node: followers take it if its ``seq`` is new to them)
        makes the leader re-assert its schedule (:meth:`reassert`); returns why (an abort
        is then pending, to be published), else None."""
        if ev.event not in (START, ABORT) or self.sent.get(ev.seq) == (ev.event, ev.trial,
                                                                       ev.slot):
            return None
        self.foreign_events += 1
        return self.reassert(ev.seq, f"a {ev.event} of slot {ev.slot} (seq {ev.seq}) that "
                                     f"the leader did not send", ev)

    def reassert(self, seq: int, why: str, ev: TrialEvent | None = None) -> str:
        """A follower took (or may have taken) an event this leader did not send, with
        ``seq``: the next event gets a larger ``seq`` (followers ignore anything not newer
        than what they saw), and the slot the event could have moved is aborted, so that
        every node answers and the same iteration runs again in a fresh slot:

        * a slot open or being aborted: aborted (again);
        * a start of a later slot, an abort of a slot already committed, or an unknown
          event (seen only as a follower's ``seen``): the next slot, which the leader never
          started, is aborted and skipped.

        A committed trial is never taken back: the abort names the slot the team last
        committed (``kept``), and a robot that undid its learning step on a forged abort
        of that slot takes the step back (``RobotLearner.redo``): the run goes on from
        the trial every robot learned, equal to batch."""
        self.seq = max(self.seq, seq)
        if ev is not None and ev.event == ABORT and ev.slot == self.committed_slot:
            why += f" (trial {self.committed - 1}, committed: it stands)"
        if self.abort_pending is not None:
            self.begin_abort(f"{self.why}; {why}", self.abort_pending)
        elif self.open or self.running:
            self.begin_abort(why)
        else:
            # a start of the next slot (followers take no other), or an unknown event: that
            # slot never ran for the leader; aborting it moves every follower out of it
            self.begin_abort(why, self.slot + 1)
        return why

    def _idle(self, name: str) -> bool:
        r = self.ready.get(name)
        if r is None:
            return False
        return r.passive or name in self.answered

    def _maybe_commit(self) -> None:
        if not self.open or self.running:
            return
        i = self.committed
        if all(name in self.ready and self.ready[name].trial >= i + 1
               and (self._idle(name) or self._learned_open_slot(name))
               for name in self.robots):
            self.committed = i + 1
            self.committed_slot = self.slot
            self.open = False
            self.answered.update(self.robots)  # every robot is idle for the next start

    def _learned_open_slot(self, name: str) -> bool:
        """A robot's trials follow its own poses: it may run and learn a slot whose start
        it never took (the start was lost on its way, say while the robot's process was
        stopped), and its ready then names an older ``seq``. A ready that says it learned
        one trial more than the team while the open slot has ended answers that slot all
        the same: at that slot's start every robot had learned exactly ``committed`` trials
        (``next_start``; an aborted slot's learning step is rolled back before the next
        start), so only this slot can have taught it the one more."""
        return (self.abort_pending is None and not self.running
                and self.ready[name].trial == self.committed + 1)

    def acks_missing(self) -> list[str]:
        """Nodes that have not answered the pending abort. A robot has answered once it is
        idle and no longer holds a learning step of the aborted slot (``trial`` back at
        ``committed``): a robot process restarted from a state file written after it
        learned from that slot must still roll it back."""
        return [n for n in self.expected if not self._idle(n)
                or (n in self.robots and self.ready[n].trial > self.committed)]

    def abort_done(self) -> bool:
        """Every node answered the pending abort: the slot is gone."""
        if self.abort_pending is None:
            return True
        if self.acks_missing():
            return False
        self.abort_pending = None
        return True

    def ended(self, slot: int) -> None:
        if slot == self.slot:
            self.running = False
            self._maybe_commit()

    def waiting_for(self) -> list[str]:
        """Expected nodes that are not (yet) idle for the next start."""
        return [n for n in self.expected if not self._idle(n)]

    def explain_wait(self, refused: dict[str, str] | None = None,
                     waiting: dict[str, str] | None = None) -> list[str]:
        """Whom the schedule waits for, each with why (``refused``: the last ready the
        leader refused from a node, with its reason; ``waiting``: what a node not yet
        ready said it waits for, its endpoints not yet matched), for a user."""
        out = []
        names = self.acks_missing() if self.abort_pending is not None else self.waiting_for()
        for n in names:
            r = self.ready.get(n)
            if r is None:
                why = "has not said ready" + ("" if n in self.boots else " (never seen)")
            elif self.abort_pending is not None and n in self.answered:
                why = (f"still holds the learning step of the aborted slot (ready for trial "
                       f"{r.trial}, the team has learned {self.committed})")
            else:
                why = (f"has not answered seq {self.seq} (its last ready saw seq {r.seen})"
                       if r.seen < self.seq else "is not idle")
            if refused and n in refused:
                why += f"; its last ready was refused: {refused[n]}"
            if waiting and n in waiting:
                why += f"; it waits for {waiting[n]}"
            out.append(f"{n} {why}")
        return out

    def next_start(self) -> tuple[int, int] | None:
        """(iteration, slot) of the trial to start now, or None (not everybody is ready).
        ScheduleError when the robots' learning states disagree with the schedule."""
        if self.open or self.running or not self.abort_done() or self.waiting_for():
            return None
        robots = {n: self.ready[n].trial for n in self.robots}
        behind = {n: t for n, t in robots.items() if t < self.committed}
        if behind:
            undid = [n for n in behind if (n, self.ready[n].boot) in self.redo_asked]
            raise ScheduleError(
                "; ".join(f"{n} is ready for trial {t}" for n, t in sorted(behind.items()))
                + f", but the team has learned {self.committed} trials: "
                + (f"{', '.join(sorted(undid))} undid a committed learning step on an abort "
                   f"the leader did not send and could not take it back (run with the "
                   f"launcher's sealed events, or SROS2)" if undid else
                   "a robot came back without its memory (give every robot the run's "
                   "state_dir)"))
        ahead = set(robots.values())
        if robots and ahead != {self.committed}:
            if len(ahead) == 1 and self.slot < 0:
                # a leader started afresh next to robots that have learned (no leader state)
                self.committed = ahead.pop()
            else:
                raise ScheduleError(f"the robots' learned trials disagree: {robots}, "
                                    f"schedule at {self.committed}")
        return self.committed, self.slot + 1

    def started(self, slot: int) -> int:
        """Slot ``slot`` starts now; returns its ``seq``."""
        self.slot = slot
        self.open = self.running = True
        self.seq += 1
        self.answered.clear()
        self.sent[self.seq] = (START, self.committed, slot)
        return self.seq

    @property
    def done(self) -> bool:
        return self.committed >= self.trials and not self.open
