"""A run's clock settings, as the nodes share them in the run configuration.

The launcher decides them (``formation-ilc launch --clock-offset-ms MS --clock-drift-ppm P
--no-clock-sync --clock-fallback F``) and the leader broadcasts them inside the run
configuration, so every robot and bridge knows whether to exchange clock stamps and, in an
emulated run, which clock it runs on.

sync : the robots and bridges estimate the clocks they depend on from two-way exchanges
    (``protocol.timesync``), and the bridges sample on the leader's clock by it. False
    (``--no-clock-sync``): the exchanges still run and measure each link's delay, but
    nothing is estimated or corrected (every node reads its own clock as it is). Realtime
    and wall-clock runs only: in simulated time no node reads a clock.
fallback : what a bridge samples on while its estimate of the leader's clock has not
    converged: ``estimate`` (the best estimate so far, whatever its uncertainty; the
    machine's clock before the first answer) or ``own`` (the machine's clock as it is:
    what the stack did before it estimated clocks).
offset_ms, drift_ppm : emulated clocks (one machine standing in for several): robot i's
    clock (its node's and its bridge's) reads an offset uniform in [-offset_ms, offset_ms]
    and runs a drift uniform in [-drift_ppm, drift_ppm] fast, drawn from the run's seed
    (``core.clocksync.EmulatedClock.seeded``); 0 and 0: the machine's clock.
origin_ns : [ns, wall clock] where the emulated drift counts from (the launch).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from formation_ilc.core.clock import Rejected
from formation_ilc.core.clocksync import EmulatedClock
from formation_ilc.core.names import LEADER, bridge_name, robot_name

__all__ = ["ClockSettings", "FALLBACKS", "OFFSET_MAX_MS", "DRIFT_MAX_PPM"]

FALLBACKS = ("estimate", "own")
#: the largest emulated offset [ms] (an hour) and drift [ppm] (under 1 %)
OFFSET_MAX_MS = 3_600_000.0
DRIFT_MAX_PPM = 9_999.0


@dataclass(frozen=True)
class ClockSettings:
    sync: bool = True
    fallback: str = "estimate"
    offset_ms: float = 0.0
    drift_ppm: float = 0.0
    origin_ns: int = 0

    def __post_init__(self) -> None:
        if self.fallback not in FALLBACKS:
            raise ValueError(f"clock fallback: one of {', '.join(FALLBACKS)}, got "
                             f"{self.fallback!r}")
        if not (math.isfinite(self.offset_ms) and 0 <= self.offset_ms <= OFFSET_MAX_MS):
            raise ValueError(f"clock offset: 0 to {OFFSET_MAX_MS:g} ms, got {self.offset_ms!r}")
        if not (math.isfinite(self.drift_ppm) and 0 <= self.drift_ppm <= DRIFT_MAX_PPM):
            raise ValueError(f"clock drift: 0 to {DRIFT_MAX_PPM:g} ppm, got {self.drift_ppm!r}")

    @property
    def emulated(self) -> bool:
        """The robots' clocks are emulated (an offset or a drift asked for)."""
        return self.offset_ms > 0 or self.drift_ppm > 0

    def robot_clock(self, seed: int, robot: int) -> EmulatedClock | None:
        """Robot ``robot``'s (1-based) emulated clock in a run of seed ``seed``; None: the
        machine's clock."""
        if not self.emulated:
            return None
        return EmulatedClock.seeded(seed, robot, self.offset_ms, self.drift_ppm,
                                    self.origin_ns)

    def truth(self, seed: int, n: int) -> dict[str, EmulatedClock] | None:
        """Every node's clock of an emulated run by node name (robot i's node and its
        bridge, on one robot, read robot i's; the leader reads the machine's): what
        scores the estimates. None when not emulated (the clocks are whatever the
        machines read)."""
        if not self.emulated:
            return None
        out = {LEADER: EmulatedClock(0, 0.0, self.origin_ns)}
        for i in range(1, n + 1):
            c = self.robot_clock(seed, i)
            assert c is not None
            out[robot_name(i)] = out[bridge_name(i)] = c
        return out

    def to_json(self) -> dict[str, Any]:
        return {"sync": self.sync, "fallback": self.fallback, "offset_ms": self.offset_ms,
                "drift_ppm": self.drift_ppm, "origin_ns": self.origin_ns}

    @classmethod
    def from_json(cls, d: Any) -> ClockSettings:
        """Settings of a JSON object; Rejected (malformed) naming what is wrong."""
        if not isinstance(d, dict):
            raise Rejected("malformed", f"clock settings: an object, got {type(d).__name__}")
        try:
            sync, origin = d.get("sync", True), d.get("origin_ns", 0)
            if not isinstance(sync, bool) or isinstance(origin, bool) or not isinstance(
                    origin, int):
                raise ValueError("sync must be true or false and origin_ns an integer")
            return cls(sync, str(d.get("fallback", "estimate")),
                       float(d.get("offset_ms", 0.0)), float(d.get("drift_ppm", 0.0)), origin)
        except (TypeError, ValueError) as exc:
            raise Rejected("malformed", f"clock settings: {exc}") from None
