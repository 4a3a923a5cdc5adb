"""A wall-clock trial's progress on the launcher's console.

A trial of the Pioneer or base bridges runs in real time (paper-triangle3: 28 s of samples,
then the robots drive back); the console said nothing from the trial's start to its row.
:class:`TrialProgress` gives a line while its samples run: at most one every ``every``
seconds, from the leader's ``start`` (its ``start_wall_ns``, on the ground station's clock,
where the leader and this launcher run) until the trial's samples are over or its row is
in. Pure: the launcher gives it the events and rows its monitor has.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from typing import Any

__all__ = ["TrialProgress"]


class TrialProgress:
    """Lines for wall-clock trials of ``duration`` seconds of samples, out of ``trials``."""

    def __init__(self, duration: float, trials: int, every: float = 10.0):
        self.duration = float(duration)
        self.trials = int(trials)
        self.every = float(every)
        self.said: tuple[int, float] | None = None  # (slot, when it was last said [s])

    def update(self, now_ns: int, events: Sequence[dict[str, Any]],
               rows: Collection[int]) -> str | None:
        """The line to print now, or None: the newest event is a wall-clock start whose
        samples are under way, and none was said of it within ``every`` seconds."""
        if not events:
            return None
        ev = events[-1]
        wall = ev.get("start_wall_ns")
        if ev.get("event") != "start" or not isinstance(wall, int):
            return None
        trial, slot = int(ev.get("trial", -1)), int(ev.get("slot", ev.get("trial", -1)))
        elapsed = (now_ns - wall) / 1e9
        if trial in rows or elapsed < 0 or elapsed >= self.duration:
            return None
        if self.said is not None and self.said[0] == slot and elapsed - self.said[1] < self.every:
            return None
        self.said = (slot, elapsed)
        return (f"trial {trial} of 0..{self.trials - 1}: {elapsed:.0f} s of "
                f"{self.duration:.0f} s of samples")
