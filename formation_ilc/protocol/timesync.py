"""A node's clock exchanges: questions out, answers in, an estimate per clock it hears.

Free of ROS: the robot node, the bridge and the leader wrap it (``nodes.robot``,
``nodes.pioneer_bridge``, ``virtual_leader.node``), reading their own clock and passing
every time in.

A node asks each **peer** (a robot it hears, the leader) for its time: question ``seq``
sent at t1 on its own clock; the peer takes it at t2 and answers at t3 on the peer's clock
(``answer``); the answer arrives at t4. Each exchange goes into the peer's
``core.clocksync.LinkClock`` (round trips gated, the drift fitted, the offset bounded by
every exchange; clock steps found). The receiver asks, so a link that goes one way in the
graph (robot j to robot i) still gets its estimate: robot i asks robot j, which answers
anyone who hears it.

The answers also measure the **one-way delay** from the peer to this node, the direction
of the graph's link: ``measured`` = t4 - t3 (the two clocks as they read), ``corrected`` =
t4 - (t3 carried to this node's clock by the estimate made before this answer came), and in
an emulated run ``injected`` = the same delay in true time (the emulation's truth, kept for
scoring; the estimator never reads it).

Questions go out ``BURST_HZ`` a second to a peer for its first ``BURST_S`` seconds (an
estimate within seconds), ``PING_HZ`` after. What a node reports (``report``), and what it
warns of once per occurrence (``events``): an estimate converged; not converged
``CONVERGE_WARN_S`` after the first question; no answer for ``SILENT_WARN_S``; a clock
step (the offset jumped).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from formation_ilc.core.clock import Rejected
from formation_ilc.core.clocksync import (
    CONVERGED_NS,
    LONGEST_NS,
    ClockEstimate,
    EmulatedClock,
    LinkClock,
)

__all__ = ["ClockSync", "NodeClock", "converged_for", "PING_HZ", "BURST_HZ", "BURST_S",
           "CONVERGE_WARN_S", "SILENT_WARN_S", "OUTSTANDING", "DELAYS_KEPT", "answer"]

#: questions a second to a peer in steady state, and for its first BURST_S seconds
PING_HZ = 2.0
BURST_HZ = 10.0
BURST_S = 3.0
#: [s] not converged this long after the first question: WARN
CONVERGE_WARN_S = 20.0
#: [s] no answer for this long (after the first): WARN
SILENT_WARN_S = 10.0
#: questions per peer whose answer is still taken (older ones are forgotten)
OUTSTANDING = 64
#: one-way delays kept per link (the newest)
DELAYS_KEPT = 600

S = 1_000_000_000


class NodeClock:
    """A node's wall clock: the machine's, or an emulated one over it. ``now(true_ns)``
    is its reading when the machine reads ``true_ns`` (the caller reads the machine:
    time is injected). ``scale`` [s per s]: how long one of its seconds lasts in true time
    (its timers run on it)."""

    def __init__(self, emulated: EmulatedClock | None = None):
        self.emulated = emulated

    def now(self, true_ns: int) -> int:
        return int(true_ns) if self.emulated is None else self.emulated.read(true_ns)

    @property
    def scale(self) -> float:
        return 1.0 if self.emulated is None else 1.0 / (1.0 + self.emulated.drift)


def converged_for(dt_ns: int) -> int:
    """The uncertainty [ns] within which a run's clock estimates have converged: 2 ms
    (``CONVERGED_NS``), or a twentieth of its sample time when that is more (a tenth of
    the half-sample margin that eq. 11 rounds with; on a path whose legs take 2 ms at
    least, as over Wi-Fi, no two-way estimate can promise better than 2 ms)."""
    return max(CONVERGED_NS, int(dt_ns) // 20)


def answer(seq: int, t2: int, t3: int) -> tuple[int, int, int]:
    """The answer to question ``seq`` taken at t2 and answered at t3 (the answerer's
    clock): what goes back (``seq``, t2, t3)."""
    return int(seq), int(t2), int(t3)


@dataclass
class _Link:
    """One peer's clock and the delays of its answers."""

    clock: LinkClock
    sent: dict[int, int] = field(default_factory=dict)   # seq -> t1
    first_ns: int | None = None       # when the first question went out
    next_ns: int = 0                  # when the next one is due
    last_answer_ns: int | None = None
    converged_ns: int | None = None   # when it first converged
    answers: int = 0
    refused: int = 0
    steps_told: int = 0
    warned: set[str] = field(default_factory=set)
    #: (t4 local, measured, corrected or nan, injected or nan) [ns] of the newest answers
    delays: deque[tuple[int, float, float, float]] = field(
        default_factory=lambda: deque(maxlen=DELAYS_KEPT))


class ClockSync:
    """The clock exchanges of node ``me`` with ``peers`` (node names).

    truth : the emulation's clocks by node name (``config.clocks.ClockSettings.truth``):
        only for the ``injected`` delays that score a run; None on real machines.
    fallback : 'estimate' or 'own' (``config.clocks.FALLBACKS``): what ``remote_time``
        gives before an estimate has converged.
    estimating : False: the estimator is off (``--no-clock-sync``): the answers measure
        the one-way delays as the clocks read, and nothing is estimated or corrected
        (``remote_time`` is this node's clock).
    converged_ns : the uncertainty within which an estimate has converged (``converged_for``
        gives the run's: 2 ms, or a twentieth of dT when that is more).
    """

    def __init__(self, me: str, peers: Iterable[str], *,
                 truth: Mapping[str, EmulatedClock] | None = None,
                 fallback: str = "estimate", estimating: bool = True,
                 converged_ns: int = CONVERGED_NS, ping_hz: float = PING_HZ,
                 burst_hz: float = BURST_HZ, burst_s: float = BURST_S):
        self.me = me
        self.estimating = estimating
        self.links = {p: _Link(LinkClock(converged_ns=converged_ns)) for p in peers}
        self.truth = truth
        self.fallback = fallback
        self.period_ns = int(S / ping_hz)
        self.burst_ns = int(S / burst_hz)
        self.burst_for_ns = int(burst_s * S)
        self.seq = 0
        #: [ns] a question due within this much after the asking time is asked then: a
        #: caller that wakes once a question period (the wake-up may come a little before
        #: the question it made a period ago is due) skips none
        self.early_ns = 0

    @property
    def peers(self) -> list[str]:
        return list(self.links)

    # ------------------------------------------------------------------ questions
    def questions(self, now: int) -> list[tuple[str, int]]:
        """The questions due at ``now`` (this node's clock): (peer, seq) each, sent at
        ``now`` (t1); with ``early_ns``, those due within that much after ``now`` too."""
        out = []
        early_ns = self.early_ns
        for peer, link in self.links.items():
            if now + early_ns < link.next_ns:
                continue
            if link.first_ns is None:
                link.first_ns = now
            burst = now - link.first_ns < self.burst_for_ns
            link.next_ns = now + (self.burst_ns if burst else self.period_ns)
            self.seq += 1
            link.sent[self.seq] = now
            while len(link.sent) > OUTSTANDING:
                del link.sent[next(iter(link.sent))]
            out.append((peer, self.seq))
        return out

    def all_converged(self) -> bool:
        """Whether the estimate of every peer's clock has converged (at some time: a clock
        step later is warned of, not undone here)."""
        return all(link.converged_ns is not None for link in self.links.values())

    def bursting(self, now: int) -> bool:
        """Whether a peer is not asked yet or still in its first ``burst_s`` (questions
        ``burst_hz`` a second); once none is, they come ``ping_hz`` a second."""
        return any(link.first_ns is None or now - link.first_ns < self.burst_for_ns
                   for link in self.links.values())

    def next_due(self) -> int:
        """When [ns, this node's clock] the next question is due."""
        return min((x.next_ns for x in self.links.values()), default=0)

    # ------------------------------------------------------------------ answers
    def on_answer(self, peer: str, seq: int, t2: int, t3: int, t4: int) -> None:
        """``peer``'s answer to question ``seq``: it took it at t2 and answered at t3 (its
        clock); it arrived at t4 (this node's clock). Rejected: no question of this
        node's to that peer (unexpected; or stale once forgotten), an answer taken twice
        (duplicate), or times that cannot be an exchange (malformed)."""
        link = self.links.get(peer)
        if link is None:
            raise Rejected("unexpected", f"a clock answer from {peer[:100]!r}, not asked")
        t1 = link.sent.pop(int(seq), None)
        if t1 is None:
            if 0 < seq <= self.seq:
                raise Rejected("stale", f"a clock answer of {peer} to question {seq}, "
                                        f"answered already or forgotten")
            raise Rejected("unexpected", f"a clock answer of {peer} to question {seq}, "
                                         f"never asked")
        before = link.clock.estimate(t4)
        held = int(t3) - int(t2)
        rtt = (int(t4) - t1) - held
        if not (0 <= rtt <= LONGEST_NS and 0 <= held <= LONGEST_NS) or (
                self.estimating and not link.clock.exchange(t1, t2, t4, t3)):
            link.refused += 1
            raise Rejected("malformed", f"{peer}'s clock answer to question {seq} is no "
                                        f"exchange (t1 {t1}, t2 {t2}, t3 {t3}, t4 {t4})")
        link.answers += 1
        link.last_answer_ns = t4
        measured = float(t4 - t3)
        corrected = float("nan") if before is None else measured + before.offset_ns
        injected = float("nan")
        if self.truth is not None and self.me in self.truth and peer in self.truth:
            injected = float(self.truth[self.me].true(t4) - self.truth[peer].true(t3))
        link.delays.append((int(t4), measured, corrected, injected))
        est = link.clock.estimate(t4)
        if est is not None and est.converged and link.converged_ns is None:
            link.converged_ns = t4

    # ------------------------------------------------------------------ estimates
    def estimate(self, peer: str, at: int) -> ClockEstimate | None:
        return self.links[peer].clock.estimate(at)

    def remote_time(self, peer: str, local_ns: int) -> tuple[int, str]:
        """``peer``'s clock at this node's ``local_ns``, and how it was had: 'converged'
        (the estimate), 'estimate' (an estimate not yet converged: the fallback
        'estimate'), or 'own' (this node's clock as it is: no estimate yet, or the
        fallback 'own')."""
        est = self.estimate(peer, local_ns)
        if est is None:
            return int(local_ns), "own"
        if est.converged:
            return int(round(local_ns + est.offset_ns)), "converged"
        if self.fallback == "own":
            return int(local_ns), "own"
        return int(round(local_ns + est.offset_ns)), "estimate"

    # ------------------------------------------------------------------ what it says
    def events(self, now: int) -> list[tuple[str, str]]:
        """What changed that a user should hear of, once each: ('info' | 'warn', text)."""
        out: list[tuple[str, str]] = []
        for peer, link in self.links.items():
            est = link.clock.estimate(now)
            if link.clock.steps > link.steps_told:
                link.steps_told = link.clock.steps
                out.append(("warn", f"{self.me}: the clock of {peer} stepped by "
                                    f"{link.clock.last_step_ns / 1e6:+.1f} ms (step "
                                    f"{link.clock.steps}); its estimate starts again"))
            if est is not None and est.converged and "converged" not in link.warned:
                link.warned.add("converged")
                link.warned.discard("not_converged")
                out.append(("info", f"{self.me}: clock of {peer} {_words(est)}"))
            first = link.first_ns
            if (self.estimating and first is not None and now - first > CONVERGE_WARN_S * S
                    and (est is None or not est.converged)
                    and "not_converged" not in link.warned):
                link.warned.add("not_converged")
                link.warned.discard("converged")
                what = "no answer" if est is None else _words(est)
                out.append(("warn", f"{self.me}: the clock of {peer} has not converged "
                                    f"after {CONVERGE_WARN_S:g} s ({what})"))
            last = link.last_answer_ns if link.last_answer_ns is not None else first
            silent = last is not None and now - last > SILENT_WARN_S * S
            if silent and "silent" not in link.warned:
                link.warned.add("silent")
                out.append(("warn", f"{self.me}: no clock answer from {peer} for "
                                    f"{SILENT_WARN_S:g} s"))
            elif not silent:
                link.warned.discard("silent")
        return out

    def warnings(self, now: int) -> list[str]:
        """The findings that make this node's diagnostics WARN now: an estimate not
        converged after CONVERGE_WARN_S, a peer silent for SILENT_WARN_S, clock steps."""
        out = []
        for peer, link in self.links.items():
            est = link.clock.estimate(now)
            first = link.first_ns
            if (self.estimating and first is not None and now - first > CONVERGE_WARN_S * S
                    and (est is None or not est.converged)):
                out.append(f"clock of {peer} not converged")
            last = link.last_answer_ns if link.last_answer_ns is not None else first
            if last is not None and now - last > SILENT_WARN_S * S:
                out.append(f"no clock answer from {peer}")
            if link.clock.steps:
                out.append(f"clock of {peer} stepped {link.clock.steps}x")
        return out

    def delays(self, peer: str) -> np.ndarray:
        """(t4 [ns], measured, corrected, injected [ns]) of the newest answers of ``peer``,
        shape (n, 4); nan where not known."""
        d = self.links[peer].delays
        return np.array(d, dtype=float).reshape(len(d), 4)

    def report(self, now: int, since_ns: int | None = None) -> dict[str, Any]:
        """The diagnostics block: per peer the estimate at ``now`` (offset, drift, their
        bounds, exchanges, shortest round trip, steps, converged and since when) and the
        one-way delays of its answers since the estimate converged (or since
        ``since_ns``): their medians [ms] and count, and in an emulated run the largest
        error of the corrected ones; ``warn`` the findings of ``warnings``."""
        peers: dict[str, Any] = {}
        for peer, link in self.links.items():
            est = link.clock.estimate(now)
            p: dict[str, Any] = {"answers": link.answers, "refused": link.refused}
            if est is not None:
                p.update({k: _round(v) for k, v in est.to_json().items()})
            if link.converged_ns is not None and link.first_ns is not None:
                p["converged_after_s"] = _round((link.converged_ns - link.first_ns) / S)
            start = since_ns if since_ns is not None else (
                link.converged_ns if self.estimating else link.first_ns)
            p["delay"] = _delay_summary(self.delays(peer), start)
            if self.truth is not None and peer in self.truth and self.me in self.truth:
                truth = self.truth[peer].offset_at(self.truth[self.me].true(now)) - \
                    self.truth[self.me].offset_at(self.truth[self.me].true(now))
                p["true_offset_ms"] = _round(truth / 1e6)
            peers[peer] = p
        return {"peers": peers, "warn": self.warnings(now), "estimating": self.estimating}


def _words(est: ClockEstimate) -> str:
    return (f"offset {est.offset_ns / 1e6:+.3f} ms +- {est.uncertainty_ns / 1e6:.3f} ms, "
            f"drift {est.drift * 1e6:+.1f} ppm, {est.exchanges} exchanges, shortest round "
            f"trip {est.rtt_min_ns / 1e6:.3f} ms")


def _round(v: Any) -> Any:
    return round(v, 6) if isinstance(v, float) else v


def _delay_summary(d: np.ndarray, start: int | None) -> dict[str, Any]:
    """Medians [ms] of the one-way delays from ``start`` on (none before it converged);
    with the emulated truth, the largest error of a corrected delay and the largest by
    which one came out shorter than the injected delay (``early_max_ms``). A loaded
    machine makes a message later than its injected delay, never earlier: only the clock
    estimate can make a corrected delay short, so ``early_max_ms`` is the estimate's own
    error, whatever the load."""
    if start is None:
        return {"n": 0}
    d = d[d[:, 0] >= start]
    out: dict[str, Any] = {"n": int(len(d))}
    if not len(d):
        return out
    out["measured_ms"] = _round(float(np.median(d[:, 1])) / 1e6)
    c = d[np.isfinite(d[:, 2])]
    if len(c):
        out["corrected_ms"] = _round(float(np.median(c[:, 2])) / 1e6)
    if np.isfinite(d[:, 3]).all():
        out["injected_ms"] = _round(float(np.median(d[:, 3])) / 1e6)
        if len(c):
            out["error_max_ms"] = _round(float(np.max(np.abs(c[:, 2] - c[:, 3]))) / 1e6)
            out["early_max_ms"] = _round(max(0.0, float(np.max(c[:, 3] - c[:, 2]))) / 1e6)
    return out
