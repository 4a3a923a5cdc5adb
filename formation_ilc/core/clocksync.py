"""Another robot's clock against this robot's own, from the time stamps the two exchange.

Eq. (11) measures a link's delay as the receive time minus the sender's label: that is the
delay only when the two clocks agree. ``LinkClock`` estimates, for one remote clock, its
offset and drift against the local clock from two-way exchanges (as NTP and PX4's
timesync do), so that a delay can be measured on corrected time:

* an exchange: the local node sends at t1 (local clock), the remote answers stamping t2
  (remote clock: when it answered), the answer arrives at t4 (local clock). If the two
  directions take equally long, the remote clock reads t2 - (t1 + t4) / 2 more than the
  local one at the local time (t1 + t4) / 2; the round trip t4 - t1 bounds how wrong that
  can be: by at most half of it, when the whole round trip went one way.
* the exchanges whose round trip is near the shortest seen (``gate``) carry the offset
  best (the others waited in a queue, on one side more than the other): a straight line
  through them over the last ``window`` exchanges (over at least 20 s) gives the drift,
  its slope. With the drift taken out, every exchange bounds the offset to within half
  its round trip; the bounds of all of them meet in an interval whose middle is the
  estimate and whose half-width, plus the drift's error times the time since, is its
  uncertainty (a bound that holds whatever the asymmetry, as long as the drift is right).
* an exchange far off the line that is near the shortest round trip is a clock step (a
  clock set by hand, a time source that came back): the estimate starts again from it and
  the step is counted.

Times are integer nanoseconds; offsets are remote minus local. Nothing here reads a clock:
the caller passes every time (``formation_ilc.protocol`` and the nodes own the clocks).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["ClockEstimate", "LinkClock", "EmulatedClock", "CONVERGED_NS", "corrected_delay_ns"]

#: [ns] an estimate with at least ``MIN_EXCHANGES`` behind it and an uncertainty under
#: this has converged (2 ms: a hundredth of the paper's dT)
CONVERGED_NS = 2_000_000
#: exchanges an estimate needs before it can have converged
MIN_EXCHANGES = 4
#: [ns] the least span of exchanges a drift is fitted over (below: the mean offset)
MIN_DRIFT_SPAN_NS = 20_000_000_000
#: the window is cut into this many pieces for the drift (the best exchange of each)
DRIFT_BINS = 8


def t99(dof: int) -> float:
    """The two-sided 99 % quantile of Student's t with ``dof`` degrees of freedom (a few
    exchanges' scatter says little of its own spread: the bound widens with few)."""
    table = {1: 63.66, 2: 9.92, 3: 5.84, 4: 4.60, 5: 4.03, 6: 3.71, 7: 3.50, 8: 3.36,
             9: 3.25, 10: 3.17, 12: 3.05, 15: 2.95, 20: 2.85, 30: 2.75, 60: 2.66}
    if dof < 1:
        return table[1]
    return next((v for k, v in table.items() if dof <= k), 2.58)


@dataclass(frozen=True)
class ClockEstimate:
    """The remote clock at local time ``at_ns``: ``offset_ns`` (remote minus local),
    ``drift`` (its rate against the local clock, remote seconds per local second minus 1,
    e.g. 1e-4 for 100 ppm), ``uncertainty_ns`` (a bound on the offset's error: half the
    shortest round trip, plus the fitted line's 99 % confidence half-width at ``at_ns``,
    which grows the farther ``at_ns`` is from the exchanges), the exchanges behind it, the
    shortest round trip [ns], the clock steps seen, and whether it has converged."""

    at_ns: int
    offset_ns: float
    drift: float
    uncertainty_ns: float
    exchanges: int
    rtt_min_ns: int
    steps: int
    converged: bool
    #: a bound on the drift's error (its 99 % confidence half-width; 0 before a drift is
    #: fitted, over 20 s of exchanges)
    drift_uncertainty: float = 0.0

    def to_json(self) -> dict[str, object]:
        return {"offset_ms": self.offset_ns / 1e6, "drift_ppm": self.drift * 1e6,
                "drift_uncertainty_ppm": self.drift_uncertainty * 1e6,
                "uncertainty_ms": self.uncertainty_ns / 1e6, "exchanges": self.exchanges,
                "rtt_min_ms": self.rtt_min_ns / 1e6, "steps": self.steps,
                "converged": self.converged}


class LinkClock:
    """One remote clock against the local one.

    window : exchanges kept (the newest). gate : [ns] an exchange counts for the offset if
    its round trip is at most the shortest kept + gate. step_ns : an exchange inside the
    gate this far off the line (and 5 uncertainties) is a clock step.
    """

    def __init__(self, window: int = 64, gate: int = 1_000_000, step_ns: int = 20_000_000):
        if window < MIN_EXCHANGES or gate < 0 or step_ns <= 0:
            raise ValueError("window >= 4, gate >= 0 and step_ns > 0 are required")
        self.window, self.gate, self.step_ns = window, gate, step_ns
        #: (local midpoint, offset, round trip) of the exchanges kept
        self.kept: deque[tuple[int, float, int]] = deque(maxlen=window)
        self.steps = 0
        self.refused = 0
        self._fit: tuple[float, float, float, int, int] | None = None  # t0, a, b, rtt, n
        self._err = (0.0, 0.0, 0.0)  # standard errors of a and b, t quantile

    def exchange(self, t1: int, t2: int, t4: int) -> bool:
        """Take one exchange (t1 sent, local; t2 answered, remote; t4 received, local).
        False if refused: a round trip below zero or above 10 s (a stale or forged
        answer). A clock step restarts the estimate from this exchange."""
        rtt = int(t4) - int(t1)
        if rtt < 0 or rtt > 10_000_000_000:
            self.refused += 1
            return False
        mid = (int(t1) + int(t4)) // 2 + ((int(t1) + int(t4)) % 2) / 2
        off = int(t2) - mid
        fit = self._fit
        if fit is not None and rtt <= fit[3] + self.gate:
            predicted = fit[1] + fit[2] * (mid - fit[0])
            unc = self._uncertainty(mid)
            if abs(off - predicted) > max(self.step_ns, 5 * unc):
                self.steps += 1
                self.kept.clear()
        self.kept.append((int(mid), float(off), rtt))
        self._refit()
        return True

    def _refit(self) -> None:
        kept = np.array(self.kept, dtype=float)  # (n, 3): midpoint, offset, round trip
        t, y, rtt = kept[:, 0], kept[:, 1], kept[:, 2]
        best = int(rtt.min())
        n = len(kept)
        t0 = float(t.mean())
        span = float(t.max() - t.min())
        se_b, dof, b = 0.0, max(n - 1, 1), 0.0
        if span >= MIN_DRIFT_SPAN_NS:
            # the drift: the slope through the shortest round trip of each eighth of the
            # window (spread over it; the others waited in queues)
            edges = np.linspace(t.min(), t.max(), DRIFT_BINS + 1)
            pick = []
            for lo_t, hi_t in zip(edges[:-1], edges[1:], strict=True):
                inside = np.flatnonzero((t >= lo_t) & (t <= hi_t))
                if inside.size:
                    pick.append(int(inside[np.argmin(rtt[inside])]))
            if len(pick) >= 3:
                tp, yp = t[pick] - t0, y[pick]
                b, a0 = np.polyfit(tp, yp, 1)
                resid = yp - (a0 + b * tp)
                dof = len(pick) - 2
                se_b = math.sqrt(float(resid @ resid) / max(dof, 1) / float((tp ** 2).sum()))
        k = t99(dof)
        # every exchange bounds the offset: the truth lies within half its round trip of
        # what it measured (one-way delays are >= 0); the bounds of all of them, with the
        # drift taken out, meet in an interval around the offset at t0; the drift's error
        # tilts them by up to its bound times half the window
        level = y - b * (t - t0)
        lo, hi = float((level - rtt / 2).max()), float((level + rtt / 2).min())
        tilt = k * se_b * span / 2
        if lo <= hi:
            a, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + tilt
        else:  # they do not meet (a drift misjudged): the shortest round trips' mean
            near = rtt <= best + self.gate
            a, half = float(level[near].mean()), best / 2 + tilt
        self._fit = (t0, float(a), float(b), best, n)
        self._err = (half, se_b, k)

    def _uncertainty(self, at_ns: float | None = None) -> float:
        """Half the interval every exchange's bound leaves for the offset at the line's
        centre, plus the drift's 99 % confidence half-width times the time from there to
        ``at_ns`` (the centre when None)."""
        assert self._fit is not None
        half, se_b, k = self._err
        far = 0.0 if at_ns is None else abs(at_ns - self._fit[0])
        return half + k * se_b * far

    def estimate(self, at_ns: int) -> ClockEstimate | None:
        """The estimate at local time ``at_ns``; None before the first exchange."""
        fit = self._fit
        if fit is None:
            return None
        t0, a, b, best, n = fit
        unc = self._uncertainty(at_ns)
        return ClockEstimate(int(at_ns), a + b * (at_ns - t0), b, unc, len(self.kept), best,
                             self.steps, len(self.kept) >= MIN_EXCHANGES
                             and unc <= CONVERGED_NS, self._err[2] * self._err[1])

    def to_local(self, remote_ns: int, at_ns: int) -> float | None:
        """A remote clock reading on the local clock (None without an estimate)."""
        est = self.estimate(at_ns)
        return None if est is None else remote_ns - est.offset_ns


def corrected_delay_ns(receive_ns: int, send_ns: int, est: ClockEstimate | None) -> float:
    """A link's delay: the local receive time minus the remote send time carried over to
    the local clock (the send time as it is without an estimate)."""
    return receive_ns - send_ns + (0.0 if est is None else est.offset_ns)


@dataclass(frozen=True)
class EmulatedClock:
    """A clock that runs ``drift`` fast (1e-4: 100 ppm) and reads ``offset_ns`` more than
    the true time at true time 0: what a robot without a time source shows.
    ``read(true_ns)`` is its reading; ``true(reading_ns)`` the inverse."""

    offset_ns: int = 0
    drift: float = 0.0

    def __post_init__(self) -> None:
        if not math.isfinite(self.drift) or abs(self.drift) >= 0.01:
            raise ValueError(f"drift must be below 1 % (1e4 ppm), got {self.drift}")

    def read(self, true_ns: int) -> int:
        return int(true_ns + self.offset_ns + round(self.drift * true_ns))

    def true(self, reading_ns: int) -> int:
        return int(round((reading_ns - self.offset_ns) / (1.0 + self.drift)))

    @classmethod
    def seeded(cls, seed: int, robot: int, offset_ms: float, drift_ppm: float) -> EmulatedClock:
        """Robot ``robot``'s clock of run seed ``seed``: offset uniform in [-offset_ms,
        offset_ms], drift uniform in [-drift_ppm, drift_ppm] (the same for every process
        that draws it)."""
        rng = np.random.default_rng([int(seed), int(robot), 0xC10C])
        off = rng.uniform(-offset_ms, offset_ms) if offset_ms > 0 else 0.0
        dr = rng.uniform(-drift_ppm, drift_ppm) if drift_ppm > 0 else 0.0
        return cls(int(round(off * 1e6)), dr * 1e-6)
