"""The sample grid of a run: time labels <-> (trial, sample), and why an input is refused.

Every pose, reference and trajectory of the stack carries a time label on one grid:
``stamp(k, s) = (k * period + s) * dT`` [ns] for trial ``k`` and sample ``s`` (``period``
samples per trial slot, longer than the trial, so the labels of one trial never mix with the
next one's). A plant stamps a robot's measured pose with the label of its sample: that is
the robot's clock Rt of eq. (11); a shared pose keeps it as the send label St.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["Rejected", "Malformed", "SampleClock", "REASONS", "TrialWindow"]

#: why an input is refused (the drop counters of every node):
#: malformed (cannot be decoded into valid data), stale (of a trial or sample already past),
#: out_of_order (older than one already taken), duplicate (the same label again), future
#: (beyond the window the node accepts now: a later trial, or too far ahead in this one),
#: unexpected (well formed, but not what the node's protocol allows now: a command outside
#: a trial, a ready from a node nobody waits for), foreign (of another run on the same
#: domain and namespace: its configuration, events or readies)
REASONS = ("malformed", "stale", "out_of_order", "duplicate", "future", "unexpected",
           "foreign")


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
