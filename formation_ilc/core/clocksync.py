"""Another robot's clock against this robot's own, from the time stamps the two exchange.

Eq. (11) measures a link's delay as the receive time minus the sender's label: that is the
delay only when the two clocks agree. ``LinkClock`` estimates, for one remote clock, its
offset and drift against the local clock from two-way exchanges (as NTP and PX4's
timesync do), so that a delay can be measured on corrected time:

* an exchange: the local node sends at t1 (local clock), the remote receives it at t2 and
  answers at t3 (remote clock; t3 = t2 when the answer's own time is not known), the
  answer arrives at t4 (local clock). If the two directions take equally long, the remote
  clock reads ((t2 - t1) + (t3 - t4)) / 2 more than the local one at the local time
  (t1 + t4) / 2; the round trip (t4 - t1) - (t3 - t2) (the time the answerer held the
  question left out) bounds how wrong that can be: by at most half of it, when the whole
  round trip went one way.
* the exchanges whose round trip is near the shortest seen (``gate``; at least the
  ``DRIFT_POINTS`` shortest) carry the offset best (the others waited in a queue, on one
  side more than the other): a straight line through them over the last ``window``
  exchanges (spread over at least 2 s) gives the drift, its slope, with a bound (its 99 %
  confidence half-width; before there is a line, the prior ``DRIFT_PRIOR``). With the
  drift taken out, every exchange bounds the offset to within half its round trip; the
  bounds of all of them meet in an interval whose middle is the estimate and whose
  half-width, plus the drift's bound times the time since, is its uncertainty (a bound
  that holds whatever the asymmetry, as long as the drift is within its bound).
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
from numpy.typing import NDArray

__all__ = ["ClockEstimate", "LinkClock", "EmulatedClock", "CONVERGED_NS", "corrected_delay_ns"]

#: [ns] an estimate with at least ``MIN_EXCHANGES`` behind it and an uncertainty under
#: this has converged (2 ms: a hundredth of the paper's dT)
CONVERGED_NS = 2_000_000
#: exchanges an estimate needs before it can have converged
MIN_EXCHANGES = 4
#: [ns] the least span of exchanges a drift is fitted over (below: none, and the prior
#: bounds it)
MIN_DRIFT_SPAN_NS = 2_000_000_000
#: the least number of exchanges the drift's line goes through (the shortest round trips)
DRIFT_POINTS = 8
#: a bound on the drift [s/s] before one is fitted: 500 ppm (crystal clocks are made to
#: within +-100 ppm of their rate; two of them differ by at most twice that)
DRIFT_PRIOR = 500e-6
#: [ns] the longest round trip, and the longest an answer may be held, of an exchange taken
LONGEST_NS = 10_000_000_000


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
    interval the exchanges' bounds leave, plus the drift's bound times the time from the
    exchanges' centre to ``at_ns``), the exchanges behind it, the shortest round trip
    [ns], the clock steps seen, and whether it has converged (at least ``MIN_EXCHANGES``
    and an uncertainty within the ``LinkClock``'s ``converged_ns``)."""

    at_ns: int
    offset_ns: float
    drift: float
    uncertainty_ns: float
    exchanges: int
    rtt_min_ns: int
    steps: int
    converged: bool
    #: a bound on the drift's error (its 99 % confidence half-width; ``DRIFT_PRIOR`` before
    #: a drift is fitted, over 2 s of exchanges)
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
    gate this far off the line (and 5 uncertainties) is a clock step. converged_ns : the
    uncertainty an estimate has converged within (``CONVERGED_NS`` by default).
    """

    def __init__(self, window: int = 64, gate: int = 1_000_000, step_ns: int = 20_000_000,
                 converged_ns: int = CONVERGED_NS):
        if window < MIN_EXCHANGES or gate < 0 or step_ns <= 0 or converged_ns <= 0:
            raise ValueError("window >= 4, gate >= 0, step_ns > 0 and converged_ns > 0 are "
                             "required")
        self.window, self.gate, self.step_ns = window, gate, step_ns
        self.converged_ns = converged_ns
        #: (local midpoint, offset, round trip) of the exchanges kept
        self.kept: deque[tuple[int, float, int]] = deque(maxlen=window)
        self.steps = 0
        #: [ns] the size of the last clock step found (the offset's jump)
        self.last_step_ns = 0.0
        self.refused = 0
        self._fit: tuple[float, float, float, int, int] | None = None  # t0, a, b, rtt, n
        self._err = (0.0, 0.0, 0.0)  # the offset's half-width, the drift's bound, t99

    def exchange(self, t1: int, t2: int, t4: int, t3: int | None = None) -> bool:
        """Take one exchange (t1 sent, local; t2 received and t3 answered, remote: t3 =
        t2 when None; t4 received, local). False if refused: a round trip below zero or
        above 10 s, or an answer before its question (t3 < t2) or held more than 10 s (a
        stale or forged answer). A clock step restarts the estimate from this exchange
        (``steps`` counts them, ``last_step_ns`` is the size of the last one)."""
        t1, t2, t4 = int(t1), int(t2), int(t4)
        t3 = t2 if t3 is None else int(t3)
        held = t3 - t2
        rtt = (t4 - t1) - held
        if rtt < 0 or rtt > LONGEST_NS or not 0 <= held <= LONGEST_NS:
            self.refused += 1
            return False
        mid = (t1 + t4) // 2 + ((t1 + t4) % 2) / 2
        off = ((t2 - t1) + (t3 - t4)) / 2
        fit = self._fit
        if fit is not None and rtt <= fit[3] + self.gate:
            predicted = fit[1] + fit[2] * (mid - fit[0])
            unc = self._uncertainty(mid)
            if abs(off - predicted) > max(self.step_ns, 5 * unc):
                self.steps += 1
                self.last_step_ns = off - predicted
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
        b, k, bound = 0.0, 1.0, DRIFT_PRIOR
        fitted = self._drift(t, y, rtt, best)
        # a line no better than the prior (a jittery path, a short span) says less than
        # the prior does: then the drift is taken as 0 within the prior's bound
        if fitted is not None and t99(fitted[2]) * fitted[1] < DRIFT_PRIOR:
            b, se_b, dof = fitted
            k = t99(dof)
            bound = k * se_b
        # every exchange bounds the offset: the truth lies within half its round trip of
        # what it measured (one-way delays are >= 0); the bounds of all of them, with the
        # drift taken out, meet in an interval around the offset at t0; the drift's error
        # (its bound: the fit's 99 % half-width, or the prior before a fit) tilts them by
        # up to that bound times their distance from t0
        level = y - b * (t - t0)
        lo, hi = float((level - rtt / 2).max()), float((level + rtt / 2).min())
        tilt = bound * float(np.abs(t - t0).max())
        if lo <= hi:
            a, half = 0.5 * (lo + hi), 0.5 * (hi - lo) + tilt
        else:  # they do not meet (a drift misjudged): the shortest round trips' mean
            near = rtt <= best + self.gate
            a, half = float(level[near].mean()), best / 2 + tilt
        self._fit = (t0, float(a), float(b), best, n)
        self._err = (half, bound, k)

    def _drift(self, t: NDArray[np.float64], y: NDArray[np.float64],
               rtt: NDArray[np.float64], best: int) -> tuple[float, float, int] | None:
        """(slope, its standard error, degrees of freedom) of a straight line through the
        exchanges near the shortest round trip (within ``gate`` of it; at least the
        DRIFT_POINTS shortest: the others waited in queues), spread over at least
        MIN_DRIFT_SPAN_NS; None before there are such."""
        if float(t.max() - t.min()) < MIN_DRIFT_SPAN_NS:
            return None
        pick = np.flatnonzero(rtt <= best + self.gate)
        if pick.size < DRIFT_POINTS:
            pick = np.argsort(rtt, kind="stable")[:DRIFT_POINTS]
        tp = t[pick]
        if pick.size < 3 or float(tp.max() - tp.min()) < MIN_DRIFT_SPAN_NS / 2:
            return None
        tc = tp - tp.mean()
        b, a0 = np.polyfit(tc, y[pick], 1)
        resid = y[pick] - (a0 + b * tc)
        dof = int(pick.size) - 2
        se_b = math.sqrt(float(resid @ resid) / max(dof, 1) / float((tc ** 2).sum()))
        return float(b), se_b, dof

    def _uncertainty(self, at_ns: float | None = None) -> float:
        """Half the interval every exchange's bound leaves for the offset at the line's
        centre, plus the drift's bound times the time from there to ``at_ns`` (the centre
        when None)."""
        assert self._fit is not None
        half, bound, _ = self._err
        far = 0.0 if at_ns is None else abs(at_ns - self._fit[0])
        return half + bound * far

    def estimate(self, at_ns: int) -> ClockEstimate | None:
        """The estimate at local time ``at_ns``; None before the first exchange."""
        fit = self._fit
        if fit is None:
            return None
        t0, a, b, best, n = fit
        unc = self._uncertainty(at_ns)
        return ClockEstimate(int(at_ns), a + b * (at_ns - t0), b, unc, len(self.kept), best,
                             self.steps, len(self.kept) >= MIN_EXCHANGES
                             and unc <= self.converged_ns, self._err[1])

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
    the true time at true time ``origin_ns``: what a robot without a time source shows.
    ``read(true_ns)`` is its reading; ``true(reading_ns)`` the inverse."""

    offset_ns: int = 0
    drift: float = 0.0
    #: [ns] the true time at which the clock is ``offset_ns`` off (its drift counts from
    #: there: a run's start, so that a wall-clock time of 1.8e18 ns does not turn 100 ppm
    #: into days)
    origin_ns: int = 0

    def __post_init__(self) -> None:
        if not math.isfinite(self.drift) or abs(self.drift) >= 0.01:
            raise ValueError(f"drift must be below 1 % (1e4 ppm), got {self.drift}")

    def read(self, true_ns: int) -> int:
        return int(true_ns + self.offset_ns + round(self.drift * (true_ns - self.origin_ns)))

    def true(self, reading_ns: int) -> int:
        return int(self.origin_ns + round((reading_ns - self.offset_ns - self.origin_ns)
                                          / (1.0 + self.drift)))

    def offset_at(self, true_ns: int) -> int:
        """How far it reads from the true time at ``true_ns`` [ns]."""
        return self.read(true_ns) - int(true_ns)

    def to_json(self) -> dict[str, float]:
        return {"offset_ms": self.offset_ns / 1e6, "drift_ppm": self.drift * 1e6,
                "origin_ns": self.origin_ns}

    @classmethod
    def seeded(cls, seed: int, robot: int, offset_ms: float, drift_ppm: float,
               origin_ns: int = 0) -> EmulatedClock:
        """Robot ``robot``'s clock of run seed ``seed``: offset uniform in [-offset_ms,
        offset_ms], drift uniform in [-drift_ppm, drift_ppm] (the same for every process
        that draws it), off by that offset at true time ``origin_ns``."""
        rng = np.random.default_rng([int(seed), int(robot), 0xC10C])
        off = rng.uniform(-offset_ms, offset_ms) if offset_ms > 0 else 0.0
        dr = rng.uniform(-drift_ppm, drift_ppm) if drift_ppm > 0 else 0.0
        return cls(int(round(off * 1e6)), dr * 1e-6, int(origin_ns))
