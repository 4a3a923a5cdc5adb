"""The sample grid of a run: time labels <-> (trial, sample), and why an input is refused.

Every pose, reference and trajectory of the stack carries a time label on one grid:
``stamp(k, s) = (k * period + s) * dT`` [ns] for trial ``k`` and sample ``s`` (``period``
samples per trial slot, longer than the trial, so the labels of one trial never mix with the
next one's). A plant stamps a robot's measured pose with the label of its sample: that is
the robot's clock Rt of eq. (11); a shared pose keeps it as the send label St.

On real robots (``mode: wallclock``) the stamps are real time instead (:class:`WallGrid`):
sample s of slot q is stamped with the wall time it was taken, ``start(q) + s * dT``, the
start agreed by the leader's ``start`` event; the label (q, s) follows from the stamp
without loss, so eq. (11) measures the same delays on either grid.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Rejected", "Malformed", "SampleClock", "WallGrid", "REASONS", "TrialWindow"]

#: why an input is refused (the drop counters of every node):
#: malformed (cannot be decoded into valid data), stale (of a trial or sample already past),
#: out_of_order (older than one already taken), duplicate (the same label again), future
#: (beyond the window the node accepts now: a later trial, or too far ahead in this one),
#: unexpected (well formed, but not what the node's protocol allows now: a command outside
#: a trial, a ready from a node nobody waits for), foreign (of another run on the same
#: domain and namespace: its configuration, events or readies), forged (not from the writer
#: its topic or its named sender has: ``protocol.writers``)
REASONS = ("malformed", "stale", "out_of_order", "duplicate", "future", "unexpected",
           "foreign", "forged")


class Rejected(ValueError):
    """An input that is refused, with the ``reason`` it is counted under (one of REASONS;
    ``foreign``: it belongs to another run on the same domain and namespace).

    Nodes drop such an input and count it; they never crash on one.
    """

    def __init__(self, reason: str, why: str):
        if reason not in REASONS:
            raise ValueError(f"unknown reason {reason!r}")
        super().__init__(why)
        self.reason = reason


class Malformed(Rejected):
    """An input that cannot be decoded into valid data (``msgs_schema.MalformedMessage``)."""

    def __init__(self, why: str):
        super().__init__("malformed", why)


@dataclass(frozen=True)
class SampleClock:
    """Sample grid of a run: stamp(k, s) = (k * period + s) * dT, integer nanoseconds.

    dt_ns : sample time [ns]; samples : T (a trial has samples 0..T); period : samples per
    trial slot (> T, so labels of consecutive trials never overlap).
    """

    dt_ns: int
    samples: int
    period: int

    @classmethod
    def for_run(cls, dt: float, samples: int, gap: int = 20) -> SampleClock:
        if dt <= 0 or samples < 1 or gap < 1:
            raise ValueError("dt > 0, samples >= 1 and gap >= 1 are required")
        return cls(int(round(dt * 1e9)), int(samples), int(samples) + 1 + int(gap))

    def stamp_ns(self, trial: int, sample: int) -> int:
        return (int(trial) * self.period + int(sample)) * self.dt_ns

    def decode(self, ns: int) -> tuple[int, int]:
        """(trial, sample) of the grid point nearest to ``ns``; Rejected (malformed) if off
        the trial (a negative time or a sample outside 0..T)."""
        if ns < 0:
            raise Malformed(f"negative stamp {ns} ns")
        q = (ns + self.dt_ns // 2) // self.dt_ns
        k, s = divmod(q, self.period)
        if s > self.samples:
            raise Malformed(f"stamp {ns} ns is between trials (sample {s} of {self.samples})")
        return int(k), int(s)

    def agree(self, slot: int, start_ns: int) -> None:
        """Nothing to learn: simulated-time labels do not depend on when a trial starts."""


class WallGrid:
    """Wall-clock stamps of a run on real robots: sample s of slot q is stamped with the
    time it is taken, ``start(q) + s * dT`` [ns since the Unix epoch], ``start(q)`` being
    the start the leader's ``start`` event agreed (:meth:`agree`).

    The leader picks every start with ``start(q) % dT == q`` (:meth:`start_for`, at most
    one sample later than it wanted), so a stamp names its slot by itself
    (``q = stamp % dT``) and, with the agreed start, its sample
    (``s = (stamp - start(q)) / dT``, exact): the labels of eq. (11) are those of
    :class:`SampleClock`, only their stamps are real time that other clocks (motion
    capture, cameras, another recording) line up with. A stamp of a slot whose start this
    node has not seen is refused (``unexpected``), as a stamp off a trial is (malformed).
    Same interface as :class:`SampleClock`.
    """

    def __init__(self, dt_ns: int, samples: int, period: int):
        if dt_ns < 1 or samples < 1:
            raise ValueError("dt_ns >= 1 and samples >= 1 are required")
        self.dt_ns, self.samples, self.period = int(dt_ns), int(samples), int(period)
        self.starts: dict[int, int] = {}

    def start_for(self, slot: int, earliest_ns: int) -> int:
        """The start of ``slot`` the leader agrees on: the first time at or after
        ``earliest_ns`` whose remainder by dT is the slot."""
        if not 0 <= slot < self.dt_ns:
            raise ValueError(f"slot {slot} does not fit a wall-clock grid of dT = "
                             f"{self.dt_ns} ns (at most {self.dt_ns - 1} slots)")
        return int(earliest_ns) + (slot - int(earliest_ns)) % self.dt_ns

    def agree(self, slot: int, start_ns: int) -> None:
        """Slot ``slot`` starts at ``start_ns`` (a start event taken). Rejected: a start
        that does not name its slot (malformed), or another start for a slot already
        agreed (unexpected)."""
        if start_ns <= 0 or start_ns % self.dt_ns != slot:
            raise Malformed(f"start {start_ns} ns of slot {slot} is not on the wall-clock "
                            f"grid (start % dT must be the slot)")
        known = self.starts.setdefault(int(slot), int(start_ns))
        if known != start_ns:
            raise Rejected("unexpected", f"slot {slot} was agreed to start at {known} ns, "
                                         f"not {start_ns} ns")

    def stamp_ns(self, trial: int, sample: int) -> int:
        start = self.starts.get(int(trial))
        if start is None:
            raise Rejected("unexpected", f"the start of slot {trial} is not known here")
        return start + int(sample) * self.dt_ns

    def decode(self, ns: int) -> tuple[int, int]:
        """(slot, sample) of the stamp ``ns``; Rejected if it is no sample of a slot whose
        start is known here (see the class)."""
        if ns <= 0:
            raise Malformed(f"stamp {ns} ns is not a wall-clock time")
        q = ns % self.dt_ns
        start = self.starts.get(q)
        if start is None:
            raise Rejected("unexpected", f"stamp {ns} ns is of slot {q}, whose start is not "
                                         f"known here")
        s = (ns - start) // self.dt_ns
        if not 0 <= s <= self.samples:
            raise Malformed(f"stamp {ns} ns is off slot {q} (sample {s} of {self.samples})")
        return int(q), int(s)


@dataclass
class TrialWindow:
    """Which trial's messages a node accepts now: the current trial, and the next one only
    once the protocol has opened it (``open_next``: this node finished the current trial
    and said ready for the next, or the leader started it).

    Every handler checks a label's trial here before it may move the node's state, so that
    one message of a later trial (a stray, a replay, a forgery) cannot make a node jump
    ahead and then refuse all real traffic as stale.
    """

    current: int = -1
    #: the next trial (current + 1) is open; trial 0 is open from the start
    next_open: bool = True

    def check(self, k: int, what: str = "label") -> bool:
        """Whether trial ``k`` is the next trial (True) or the current one (False);
        Rejected: an earlier trial (stale), or a later one than the window allows
        (future)."""
        if k < self.current:
            raise Rejected("stale", f"{what} of trial {k} in trial {self.current}")
        if k == self.current:
            return False
        if k == self.current + 1 and self.next_open:
            return True
        raise Rejected("future", f"{what} of trial {k} in trial {self.current}"
                                 f"{'' if self.next_open else ' (next trial not open)'}")

    def enter(self, k: int) -> None:
        """Trial ``k`` (the current or the next one) is now the current trial."""
        if k != self.current:
            self.current = k
            self.next_open = False

    def open_next(self) -> None:
        self.next_open = True
