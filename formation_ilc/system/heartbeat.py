"""Heartbeats: each node process proves to its supervisor that it is alive, outside DDS.

A launcher's supervisor keeps one small file, the board (``logs/heartbeats``), with one
slot of ``SLOT`` bytes per process: a counter the process bumps and a short text, what it
does now ("importing", "at the gate", "joining the domain", "building its node",
"spinning"). The process finds its slot in its environment (``BEAT_ENV``:
``PATH:INDEX``), maps it, and bumps it from its main thread: once as it starts
(``system.lifetime``), at each step of its start-up, and after every slice of its
executor's spin (``nodes.common.spin_main``, every ``SPIN_SLICE`` seconds). So a process
whose main thread is stuck inside the executor stops beating even while its DDS threads
still answer the graph: the beat comes from the thread that does the work, not a side
thread. Nothing here needs ROS; the child's side is stdlib only (it runs before the
node's imports).

The supervisor (``Board.frozen``) calls a process frozen when its counter has not moved
for ``freeze_s`` seconds (``STARTUP_FACTOR`` times that while it starts) and the process
did no work in that time either: its main thread
used no CPU, and all its threads together less than ``WORK_SHARE`` of a core (a stopped
process, a deadlocked one; a DDS thread's periodic announcement is a tick now and then);
or when its counter has not moved for ``busy_s`` (a main thread busy elsewhere, a loop
that never returns to the executor, a main thread that waits for ever on threads that
work). The CPU conditions keep a process that is only slow (importing on a loaded
machine, or its main thread waiting on a lock its DDS threads hold while they process the
discovery of fifty participants) from being taken for frozen. While the
launcher holds its processes at the gate nothing is judged (they wait on purpose).
"""

from __future__ import annotations

import mmap
import os
import struct
import time
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["BEAT_ENV", "FREEZE_ENV", "FREEZE_S", "BUSY_S", "SLOT", "STARTUP_FACTOR",
           "WORK_SHARE", "Board",
           "Frozen", "beat", "main_thread_cpu", "process_cpu"]

#: environment variable of a supervised process: ``PATH:INDEX`` of its slot
BEAT_ENV = "FORMATION_ILC_BEAT"
#: environment variable of the launcher: the freeze bound [s] (default FREEZE_S)
FREEZE_ENV = "FORMATION_ILC_FREEZE_S"
#: [s] no beat and no CPU of the main thread for this long: frozen
FREEZE_S = 15.0
#: a process's beat stays away this many times the freeze bound with its main thread
#: busy: frozen too (a loop that never returns to the executor)
BUSY_FACTOR = 8.0
BUSY_S = FREEZE_S * BUSY_FACTOR
#: while a process starts (it has not said "spinning" yet) the idle bound is this many
#: times the freeze bound: a node joining the domain waits, idle, on Fast DDS's locks
#: between processes (shared-memory ports) that other starting processes hold; 50 robots
#: forked at once waited so 27 to 38 s (2026-12-07, load 16 to 21 on 2 cores)
STARTUP_FACTOR = 4.0
#: what a process says while it starts (``beat``'s texts before its executor spins)
STARTING = ("", "importing", "forked", "at the gate", "joining the domain",
            "building its node")
#: bytes of one slot: counter (8), pid (8), what it does (the rest, UTF-8, NUL-padded)
SLOT = 64
_HEAD = struct.Struct("<QQ")
_TEXT = SLOT - _HEAD.size


def freeze_bound() -> float:
    """The freeze bound of this launcher: ``FREEZE_ENV`` when set to a positive number,
    else FREEZE_S."""
    try:
        value = float(os.environ.get(FREEZE_ENV, ""))
    except ValueError:
        return FREEZE_S
    return value if value > 0 else FREEZE_S


# ---- the process's side -------------------------------------------------------------

class _Slot:
    def __init__(self, spec: str):
        path, _, index = spec.rpartition(":")
        self.offset = int(index) * SLOT
        fd = os.open(path, os.O_RDWR)
        try:
            page = self.offset - self.offset % mmap.ALLOCATIONGRANULARITY
            self.base = self.offset - page
            self.map = mmap.mmap(fd, self.base + SLOT, offset=page)
        finally:
            os.close(fd)
        self.count = _HEAD.unpack_from(self.map, self.base)[0]
        self.pid = os.getpid()

    def bump(self, what: str | None) -> None:
        if what is not None:
            text = what.encode("utf-8", "replace")[:_TEXT]
            self.map[self.base + _HEAD.size: self.base + SLOT] = text.ljust(_TEXT, b"\0")
        self.count += 1
        _HEAD.pack_into(self.map, self.base, self.count, self.pid)


_slot: _Slot | None = None
_spec: str | None = None


def beat(what: str | None = None) -> None:
    """Say this process is alive (and, with ``what``, what it does now). Nothing when it
    has no slot (not started by a supervisor); a slot that cannot be opened is ignored
    too (the supervisor then sees no beat, and judges it by that)."""
    global _slot, _spec
    spec = os.environ.get(BEAT_ENV)
    if not spec:
        return
    if _slot is None or spec != _spec or _slot.pid != os.getpid():
        try:
            _slot, _spec = _Slot(spec), spec
        except (OSError, ValueError):
            return
    _slot.bump(what)


# ---- the supervisor's side ----------------------------------------------------------

def _ticks(path: str) -> int | None:
    try:
        with open(path, "rb") as fh:
            fields = fh.read().rsplit(b")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return int(fields[11]) + int(fields[12])


def main_thread_cpu(pid: int) -> int | None:
    """CPU ticks (user + system) of process ``pid``'s main thread, or None when it is
    gone. The main thread only: a node's DDS threads go on working while it is stuck."""
    return _ticks(f"/proc/{pid}/task/{pid}/stat")


def process_cpu(pid: int) -> int | None:
    """CPU ticks (user + system) of all of process ``pid``'s threads, or None."""
    return _ticks(f"/proc/{pid}/stat")


#: a process whose threads together use more than this share of a core while its main
#: thread waits is working (its main thread waits on a lock its DDS threads hold while they
#: process discovery: measured at 50 robots on a loaded machine), not frozen; a stopped or
#: deadlocked process uses none, or the few ticks of its DDS threads' periodic announcements
WORK_SHARE = 0.02
_HZ = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


@dataclass
class _Watched:
    index: int
    pid: int = 0
    count: int = -1
    beat_at: float = 0.0  # when the counter last moved (or the watch began)
    quiet_at: float = 0.0  # when the counter or the main thread's CPU last moved
    cpu: int | None = None
    all_cpu: int | None = None  # the process's CPU ticks when ``worked_at`` was set
    worked_at: float = 0.0  # since when its work share is measured (``Board.frozen``)
    said: str = ""  # what it said at its last beat
    spinning_at: float | None = None  # first seen spinning (``spinning_since``)
    watch: bool = True


@dataclass(frozen=True)
class Frozen:
    """A process that stopped beating: its ``name``, ``pid``, what it said it did last,
    the seconds since its last beat, and whether its main thread was idle all that time."""

    name: str
    pid: int
    doing: str
    silent_s: float
    idle: bool

    def line(self) -> str:
        why = ("the process idle" if self.idle else "the process busy elsewhere")
        return (f"{self.name} (pid {self.pid}) froze: no heartbeat for {self.silent_s:.0f} s, "
                f"{why}; last: {self.doing or 'nothing said'}")


@dataclass
class Board:
    """The supervisor's heartbeat file (``path``) and what it saw of each process."""

    path: Path
    freeze_s: float = field(default_factory=freeze_bound)
    #: [s] between two looks (a look reads every counter; /proc only for the quiet ones)
    every: float = 1.0
    slots: dict[str, _Watched] = field(default_factory=dict)
    held: bool = False
    #: processes that beat again after a silence past the bound while they worked
    #: (name, seconds, what they said they do now), for the supervisor to say
    late: list[tuple[str, float, str]] = field(default_factory=list)
    _map: mmap.mmap | None = None
    _size: int = 0
    _looked: float = 0.0

    @property
    def busy_s(self) -> float:
        return self.freeze_s * BUSY_FACTOR

    def slot(self, name: str) -> str:
        """The ``BEAT_ENV`` value of process ``name``, about to be (re)started: a slot of
        its own, kept across its restarts, cleared now (before the process can beat)."""
        w = self.slots.get(name)
        if w is None:
            w = self.slots[name] = _Watched(len(self.slots))
        self._grow(w.index + 1)
        assert self._map is not None
        self._map[w.index * SLOT:(w.index + 1) * SLOT] = bytes(SLOT)
        w.pid = 0
        return f"{self.path}:{w.index}"

    def _grow(self, n: int) -> None:
        size = max(n, 16) * SLOT
        size = -(-size // mmap.PAGESIZE) * mmap.PAGESIZE
        if size <= self._size:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "ab") as fh:
            fh.truncate(size)
        if self._map is not None:
            self._map.close()
        fd = os.open(self.path, os.O_RDWR)
        try:
            self._map = mmap.mmap(fd, size)
        finally:
            os.close(fd)
        self._size = size

    def started(self, name: str, pid: int, now: float | None = None,
                watch: bool = True) -> None:
        """Process ``name`` (its slot given by ``slot``) was (re)started as ``pid``: its
        watch begins now. ``watch`` False: only once it has beaten (a command that is not
        a node of this project's may never beat)."""
        now = time.monotonic() if now is None else now
        w = self.slots[name]
        w.watch, w.said, w.spinning_at = watch, "", None
        w.pid, w.count, w.beat_at, w.quiet_at, w.cpu, w.all_cpu = pid, -1, now, now, None, None

    def hold(self, held: bool, now: float | None = None) -> None:
        """While held (the launcher's gate is shut) nothing is judged; on release every
        watch begins anew."""
        now = time.monotonic() if now is None else now
        self.held = held
        if not held:
            for w in self.slots.values():
                w.beat_at = w.quiet_at = now
                w.cpu = w.all_cpu = None

    def doing(self, name: str) -> str:
        """What process ``name`` said it does, last."""
        w = self.slots.get(name)
        if w is None or self._map is None:
            return ""
        raw = self._map[w.index * SLOT + _HEAD.size:(w.index + 1) * SLOT]
        return raw.split(b"\0", 1)[0].decode("utf-8", "replace")

    def beats(self, name: str) -> int:
        """The counter of process ``name``'s slot."""
        w = self.slots[name]
        assert self._map is not None
        return int(_HEAD.unpack_from(self._map, w.index * SLOT)[0])

    def _bound(self, doing: str) -> float:
        """The idle bound of a process that said ``doing`` last."""
        return self.freeze_s * (STARTUP_FACTOR if doing in STARTING else 1.0)

    def spinning_since(self, name: str, now: float | None = None) -> float | None:
        """Since when process ``name`` has said ``spinning`` (its node built, its executor
        running), or None if it has not (or says something else now)."""
        now = time.monotonic() if now is None else now
        w = self.slots.get(name)
        if w is None or self.doing(name) != "spinning":
            if w is not None:
                w.spinning_at = None
            return None
        if w.spinning_at is None:
            w.spinning_at = now
        return w.spinning_at

    def frozen(self, alive: dict[str, int], now: float | None = None) -> list[Frozen]:
        """The processes of ``alive`` (name: pid) that froze; looks at most once every
        ``every`` seconds (an empty list in between)."""
        now = time.monotonic() if now is None else now
        if self.held or self._map is None or now - self._looked < self.every:
            return []
        self._looked = now
        out: list[Frozen] = []
        for name, pid in alive.items():
            w = self.slots.get(name)
            if w is None or w.pid != pid:
                continue
            count = self.beats(name)
            if not w.watch and count == 0:
                continue
            if count != w.count:
                if w.count >= 0 and now - w.beat_at >= self._bound(w.said):
                    # silent past its bound, but the process worked: it came back
                    self.late.append((name, now - w.beat_at, self.doing(name)))
                w.said = self.doing(name)
                w.count, w.beat_at, w.quiet_at, w.cpu, w.all_cpu = count, now, now, None, None
                continue
            if now - w.beat_at < self.every:
                continue
            cpu, all_cpu = main_thread_cpu(pid), process_cpu(pid)
            if cpu is None or all_cpu is None:  # gone: the supervisor's other watch sees it
                continue
            if w.cpu is None or w.all_cpu is None:
                w.all_cpu, w.worked_at = all_cpu, now  # the measure starts
            elif (cpu != w.cpu or all_cpu - w.all_cpu
                  > max(1.0, WORK_SHARE * (now - w.worked_at) * _HZ)):
                # its main thread ran, or its threads used more than WORK_SHARE of a core
                # since it last worked: measured over that whole time, not between two
                # looks (a thread that works on a loaded machine gets a few ticks a second,
                # none in many a tenth of one: it was taken for idle, CI 2026-12-07)
                w.quiet_at = now
                w.all_cpu, w.worked_at = all_cpu, now
            w.cpu = cpu
            silent = now - w.beat_at
            doing = self.doing(name)
            bound = self._bound(doing)
            if now - w.quiet_at >= bound or silent >= self.busy_s:
                out.append(Frozen(name, pid, doing, silent, now - w.quiet_at >= bound))
        return out

    def close(self) -> None:
        if self._map is not None:
            self._map.close()
            self._map = None
