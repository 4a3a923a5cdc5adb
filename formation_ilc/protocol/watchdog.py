"""Liveness: how long each phase of a run may take, and what to do past that.

A distributed run waits on other processes all the time: for readies before a trial, for
the plant's samples during it, for the answers to an abort. A node that is alive but never
answers (a lost message, a forged event, a state file that makes every ready look wrong,
a link that drops 90 % of the packets) must not make the run wait forever in silence.
This module holds, without ROS, the bounds of every phase and the decision the leader
(and, as a backstop, the launcher) takes when a bound passes:

* **start-up** (before the first trial: processes start, load the compiled kernels, and
  discover each other; and from a slot's start to the plant's first sample of it, which
  may load kernels too): ``STARTUP_S + STARTUP_PER_NODE_S`` per node; a secure team
  (SROS2) adds ``SECURE_PER_PAIR_S`` per pair of its participants, which authenticate
  each other pair by pair;
* **ready** (between trials: a trial's trajectories exchanged, every robot learned, every
  node said ready; or an abort answered; a restarted node comes back): ``READY_S +
  READY_PER_NODE_S`` per node;
* **sample** (a trial runs: the plant's next sample): lockstep, the plant's own command
  time-out plus ``SAMPLE_MARGIN_S`` (the plant names a silent robot first); realtime and
  wallclock, ``SAMPLE_DTS`` samples of dT, at least ``SAMPLE_MIN_S``.

Past a bound the leader says whom it waits for and why; past it again, it re-runs: a
running slot is aborted and its iteration runs again; a wait for readies is asked again (the
latched readies read anew, a pending abort re-sent). After ``RETRIES`` re-runs in a row
without progress the run stops (exit status ``STUCK``) naming the cause, and ``launch
--resume`` can continue it. The run's first start-up is the exception: nothing can be
lost and re-sent before a trial ever ran (its nodes start, discover each other and match
their endpoints), so past its bound the leader says whom it waits for and reads the readies
anew at once, and stops ``FIRST_STARTUP_GRACE`` of the bound later if that did not help:
within about its bound (a team whose discovery never completes waited five bounds, 801 s
for 52 processes, before). A bound grows with the run's own pace (``SLACK`` times the
longest wait of its phase so far), so a loaded machine does not look stuck.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from formation_ilc.system.exits import STUCK

__all__ = ["Bounds", "Watchdog", "STUCK", "RETRIES", "STARTUP", "READY", "SAMPLE",
           "FIRST_STARTUP_GRACE", "SECURE_PER_PAIR_S"]

#: how many times in a row a phase may pass its bound before the run stops
RETRIES = 3

STARTUP, READY, SAMPLE = "start-up", "ready", "sample"

#: [s] start-up: Python, rclpy and the numba cache per process on a loaded 2-core machine
#: take 3-10 s; discovery of every writer a few more
STARTUP_S = 60.0
STARTUP_PER_NODE_S = 2.0
#: [s] secure start-up, per pair of participants: each pair runs its handshake and key
#: exchange; 52 secure processes (1,326 pairs) took 279 s to their first trial, 0.17 s a
#: pair beyond the insecure start-up (docs/distributed-stack.md)
SECURE_PER_PAIR_S = 0.2
#: [s] between trials: a restarted node is back in 3-6 s (docs/reliability.md); learning
#: and the trajectory exchange take milliseconds
READY_S = 30.0
READY_PER_NODE_S = 0.5
#: [s] lockstep: beyond the plant's own time-out for a robot's command
SAMPLE_MARGIN_S = 10.0
#: realtime/wallclock: samples of dT without a new one, and the least bound [s]
SAMPLE_DTS = 20
SAMPLE_MIN_S = 5.0


@dataclass(frozen=True)
class Bounds:
    """The bound [s] of each phase of one run."""

    startup: float
    ready: float
    sample: float

    @classmethod
    def for_run(cls, dt: float, nodes: int, mode: str, timeout: float,
                scale: float = 1.0, secure: bool = False) -> Bounds:
        """Bounds of a run with ``nodes`` nodes waited for, sample time ``dt`` [s], in
        ``mode`` ('lockstep', 'realtime', 'wallclock'), whose plant waits ``timeout`` [s]
        for a robot's command in lockstep; every bound times ``scale`` (``launch
        --watchdog-scale``: larger on a machine known to be slow, smaller to detect a
        stuck run sooner). ``secure``: the team runs under SROS2; its start-up bound grows
        with the pairs of its participants (the nodes and the launcher's monitor)."""
        sample = (timeout + SAMPLE_MARGIN_S if mode == "lockstep"
                  else max(SAMPLE_MIN_S, SAMPLE_DTS * dt))
        participants = nodes + 1
        handshakes = SECURE_PER_PAIR_S * participants * (participants - 1) / 2 if secure else 0.0
        return cls(scale * (STARTUP_S + STARTUP_PER_NODE_S * nodes + handshakes),
                   scale * (READY_S + READY_PER_NODE_S * nodes), scale * sample)

    def of(self, phase: str) -> float:
        return {STARTUP: self.startup, READY: self.ready, SAMPLE: self.sample}[phase]


#: a phase's bound is at least this many times the longest it took in this run when
#: nothing was wrong: a loaded machine (every wait long) does not look stuck
SLACK = 4.0
#: the run's first start-up, past its bound once: the share of the bound it still waits
#: (after reading the readies anew) before it stops
FIRST_STARTUP_GRACE = 0.25


@dataclass
class Watchdog:
    """Tracks the time since the run last moved, per phase.

    ``moved(now, phase)`` when something advances the run (a ready taken, a sample, a
    trial committed); ``expired(now, phase)`` says whether the phase has now waited past
    its bound (:meth:`bound`), and counts the expiry as a strike. The first strike only
    reports (``acting`` is False: a slow machine is not a stuck run); later ones act;
    ``gave_up`` once ``retries`` acts passed without progress in between. In the run's
    first start-up (``first_startup``) the first strike acts and the second, a quarter of
    the bound later (FIRST_STARTUP_GRACE), gives up.
    """

    bounds: Bounds
    retries: int = RETRIES
    since: float = 0.0
    phase: str = STARTUP
    strikes: int = 0
    longest: dict[str, float] = field(default_factory=dict)
    #: moved() has been called: ``since`` is a time of this run
    running: bool = False
    #: when the run last made progress (a sample, a commit), or None before the first call
    progress_at: float | None = None
    #: the run has been in a phase other than start-up (a trial started)
    started: bool = False
    #: [s] the bound that expired last (what the report names)
    expired_bound: float = 0.0

    @property
    def first_startup(self) -> bool:
        """The run's first start-up: no trial has started yet."""
        return self.phase == STARTUP and not self.started

    def bound(self, phase: str) -> float:
        """[s] the bound of ``phase``: its static bound, or SLACK times the longest wait
        of that phase this run has seen go by without a strike; in the first start-up
        after a strike, FIRST_STARTUP_GRACE of it."""
        b = self.full_bound(phase)
        if phase == STARTUP and not self.started and self.strikes:
            return FIRST_STARTUP_GRACE * b
        return b

    def full_bound(self, phase: str) -> float:
        """[s] the bound of ``phase`` before any strike: its static bound, or SLACK times
        the longest wait of that phase this run has seen go by without a strike."""
        return max(self.bounds.of(phase), SLACK * self.longest.get(phase, 0.0))

    def moved(self, now: float, phase: str, progress: bool = True) -> None:
        """The run moved at ``now`` and is in ``phase``. ``progress``: a real step (a
        sample, a commit) that also clears the strikes; a retry of the watchdog's own
        making is not one."""
        if self.strikes == 0 and self.running:
            self.longest[self.phase] = max(self.longest.get(self.phase, 0.0),
                                           now - self.since)
        self.running = True
        self.since = now
        self.phase = phase
        if phase != STARTUP:
            self.started = True
        if progress or self.progress_at is None:
            self.strikes = 0
            self.progress_at = now

    def waited(self, now: float) -> float:
        """[s] since the run last made progress."""
        return now - (self.since if self.progress_at is None else self.progress_at)

    def expired(self, now: float, phase: str) -> bool:
        """Whether ``phase`` has waited past its bound (then counted as one strike and the
        clock restarted)."""
        if phase != self.phase:
            self.moved(now, phase, progress=False)
            return False
        bound = self.bound(phase)
        if now - self.since <= bound:
            return False
        self.strikes += 1
        self.since = now
        self.expired_bound = bound
        return True

    @property
    def acting(self) -> bool:
        """Past the first strike: the watchdog re-runs (the first one only reports; in the
        first start-up the first one re-runs)."""
        return self.strikes >= (1 if self.first_startup else 2)

    @property
    def gave_up(self) -> bool:
        return self.strikes > (1 if self.first_startup else self.retries + 1)
