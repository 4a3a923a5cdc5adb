"""Wall-clock trials: the sample instants agreed by the leader's ``start`` event.

In ``mode: wallclock`` no node publishes ``/clock``. The leader's ``start`` event of trial
k carries ``start_wall_ns``; sample s is due at ``start_wall_ns + s * dT`` on every
machine's (synchronised) wall clock and is stamped with that time
(``core.clock.WallGrid``, from which the label (k, s) follows exactly), so the robots'
eq. (11) compares grid labels exactly as in simulated time.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from formation_ilc.core.clock import Malformed, Rejected

__all__ = ["WallSchedule", "start_wall_ns", "check_start_wall", "START_AHEAD_MAX"]

#: [s] the latest a start event's agreed start time may be ahead of a follower's clock
START_AHEAD_MAX = 60.0


def start_wall_ns(event: dict[str, object]) -> int:
    """The agreed start of a wall-clock trial from a ``start`` event; Malformed if absent."""
    v = event.get("start_wall_ns")
    if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
        raise Malformed(f"start event without a valid start_wall_ns: {v!r}")
    return v


def check_start_wall(start_ns: int | None, now_ns: int, trial_ns: int) -> int:
    """The agreed start [ns] of a wall-clock trial lasting ``trial_ns``, seen at ``now_ns``
    on the follower's wall clock. Rejected: absent or not positive (malformed), more than
    ``START_AHEAD_MAX`` ahead (future: the robot would wait that long), or so long ago that
    the trial would be over (stale)."""
    start = start_wall_ns({"start_wall_ns": start_ns})
    if start > now_ns + int(START_AHEAD_MAX * 1e9):
        raise Rejected("future", f"start {(start - now_ns) / 1e9:.3g} s ahead")
    if start + trial_ns < now_ns:
        raise Rejected("stale", f"start {(now_ns - start) / 1e9:.3g} s ago: the trial "
                                f"would be over")
    return start


@dataclass
class WallSchedule:
    """Samples 0..T due at ``start_ns + s * dt_ns`` [ns, wall clock].

    ``due(now)`` returns the newest sample due at ``now`` that was not returned yet (None if
    none); samples overtaken by a later one are counted in ``skipped`` (the caller's timer
    fell behind by more than a sample) and never returned late.
    """

    start_ns: int
    dt_ns: int
    samples: int
    next: int = 0
    skipped: int = field(default=0)

    def due(self, now_ns: int) -> int | None:
        if self.next > self.samples or now_ns < self.start_ns + self.next * self.dt_ns:
            return None
        s = min(self.samples, (now_ns - self.start_ns) // self.dt_ns)
        self.skipped += s - self.next
        self.next = s + 1
        return int(s)

    @property
    def finished(self) -> bool:
        return self.next > self.samples

    def time_of(self, s: int) -> int:
        return self.start_ns + s * self.dt_ns
