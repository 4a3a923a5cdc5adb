"""Batch simulator: all robots over all trials, with the uncertainty of Sec. IV.A.

Each trial runs in one compiled loop over samples that calls the law's per-step function
(``law.command``) for all robots at once, then ``law.learn`` for the next trial's memory.
The robot node calls the same two functions for one robot, interpreted (``core/_jit.py``);
the functions here call the compiled forms (``kernel.jit``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario
from formation_ilc.core._jit import njit
from formation_ilc.core.estimate import BOX
from formation_ilc.core.guards import DivergedError, check_finite
from formation_ilc.core.kinematics import PLANT_MODELS, arc_step, unicycle_step, wrap_angle
from formation_ilc.core.law import (
    command_trig,
    heading_code,
    heading_trig,
    law_code,
    learn_trig,
    memory_code,
)
from formation_ilc.core.links import delivered_label
from formation_ilc.core.metrics import METRIC_COLUMNS
from formation_ilc.core.pcg import STATE_SIZE
from formation_ilc.core.safety import CHANGED, OTHER_FIELDS, SafetySpec, filter_team
from formation_ilc.core.through import after_learning, learn_base, learning_code
from formation_ilc.core.uncertainty import (
    DelayArrays,
    PlantArrays,
    delay_arrays,
    fill_delays,
    fill_plant,
    plant_arrays,
    seed_words,
)

__all__ = ["Problem", "TrialRecord", "SimResult", "simulate", "simulate_seeds", "trial_errors",
           "simulate_bytes", "METRIC_COLUMNS", "DivergedError", "safety_arrays", "SafetyArrays"]

#: the safety filter's arrays for the kernels (``safety_arrays``): its parameters
#: (``SafetySpec.params()``, empty: no filter), (learning code, pose age [s], velocity
#: window [samples]), and the scratch: nominal commands (N, T, 2), flags (N, T), previous
#: commands (N, 2), the poses and motions and ages a robot hears (N, OTHER_FIELDS), (N,),
#: the memory the learning step starts from (N, T, 2), and each robot's box of positions
#: (N, 4; ``core.estimate``)
SafetyArrays = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                     NDArray[np.int64], NDArray[np.float64], NDArray[np.float64],
                     NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]


@dataclass(frozen=True)
class Problem:
    """A scenario compiled to the arrays the kernels take.

    eta_d : shape (N, T+1, 3); src, weight : shape (N, L); leader, gain, gain_prime :
    shape (N,).
    """

    dt: float
    eta_d: NDArray[np.float64]
    src: NDArray[np.int64]
    weight: NDArray[np.float64]
    leader: NDArray[np.float64]
    gain: NDArray[np.float64]
    gain_prime: NDArray[np.float64]
    law: int
    memory: int
    heading: int
    #: index into ``kinematics.PLANT_MODELS``: 0 Euler (eq. 1, the paper's), 1 exact arc
    plant: int = 0
    #: the safety filter every robot's command goes through (None: none), and how old [s]
    #: the other robots' poses are when a robot filters with them
    safety: SafetySpec | None = None
    safety_age: float = 0.0

    @property
    def n(self) -> int:
        return int(self.eta_d.shape[0])

    @property
    def samples(self) -> int:
        return int(self.eta_d.shape[1] - 1)

    @classmethod
    def from_scenario(cls, sc: Scenario, plant: str = "euler",
                      safety: SafetySpec | None = None, safety_age: float = 0.0) -> Problem:
        """The scenario's arrays; ``plant`` is the model the batch simulator steps
        ('euler' or 'arc', ``kinematics.PLANT_MODELS``); ``safety`` the filter between
        the law and the plant (None: none), with other robots' poses ``safety_age`` [s]
        old."""
        if plant not in PLANT_MODELS:
            raise ValueError(f"plant model must be one of {', '.join(PLANT_MODELS)}, "
                             f"got {plant!r}")
        sc.graph.check_spanning_tree()
        src, w = sc.graph.in_links()
        return cls(dt=sc.dt, eta_d=np.ascontiguousarray(sc.desired.eta), src=src, weight=w,
                   leader=sc.graph.leader.copy(), gain=np.asarray(sc.law.gain, dtype=float),
                   gain_prime=np.asarray(sc.law.gain_prime, dtype=float),
                   law=law_code(sc.law.kind), memory=memory_code(sc.law.memory),
                   heading=heading_code(sc.law.gain_heading),
                   plant=PLANT_MODELS.index(plant), safety=safety, safety_age=safety_age)

    def trial(self, memory: NDArray[np.float64], xi0: NDArray[np.float64],
              dist: NDArray[np.float64], noise: NDArray[np.float64], tau: NDArray[np.int64],
              tau0: NDArray[np.int64]) -> tuple[NDArray[np.float64], ...]:
        """One trial into fresh arrays: (xi, eta, u, next memory). See ``run_trial``."""
        n, n_t = self.n, self.samples
        xi = np.empty((n, n_t + 1, 3))
        eta = np.empty_like(xi)
        u = np.empty((n, n_t, 2))
        nxt = np.empty_like(memory)
        run_trial.jit(self.law, self.memory, self.heading, self.plant, self.dt, memory, xi0,
                      dist, noise, tau,
                  tau0, self.src, self.weight, self.leader, self.eta_d, self.gain,
                  self.gain_prime, xi, eta, u, nxt, safety_arrays(self))
        return xi, eta, u, nxt

    def tiled(self, copies: int) -> Problem:
        """``copies`` independent teams stacked on the robot axis (for many seeds at once)."""
        n = self.n
        offs = (np.arange(copies) * n)[:, None, None]
        src = np.where(self.src[None] >= 0, self.src[None] + offs, -1).reshape(-1,
                                                                               self.src.shape[1])
        rep = lambda a: np.tile(a, (copies,) + (1,) * (a.ndim - 1))  # noqa: E731
        if self.safety is not None:
            raise ValueError("tiled teams would see each other: no safety filter here")
        return Problem(self.dt, rep(self.eta_d), src, rep(self.weight), rep(self.leader),
                       rep(self.gain), rep(self.gain_prime), self.law, self.memory, self.heading,
                       self.plant)


def safety_arrays(pb: Problem) -> SafetyArrays:
    """The safety filter of ``pb`` as the kernels take it (an empty parameter array when
    it has none)."""
    n, n_t = pb.n, pb.samples
    if pb.safety is None:
        params = np.empty(0)
        meta = np.zeros(3)
        n_t = 0
    else:
        params = pb.safety.params()
        meta = np.array([learning_code(pb.safety.learning), pb.safety_age,
                         pb.safety.window])
    return (params, meta, np.zeros((n, n_t, 2)), np.zeros((n, n_t), dtype=np.int64),
            np.zeros((n, 2)), np.zeros((n, OTHER_FIELDS)), np.zeros(n), np.zeros((n, n_t, 2)),
            np.zeros((n, BOX)))


@njit(cache=True)
def run_trial(law: int, memory_mode: int, heading: int, plant: int, dt: float,
              memory: NDArray[np.float64], xi0: NDArray[np.float64],
              dist: NDArray[np.float64], noise: NDArray[np.float64],
              tau: NDArray[np.int64], tau0: NDArray[np.int64],
              src: NDArray[np.int64], weight: NDArray[np.float64], leader: NDArray[np.float64],
              eta_d: NDArray[np.float64], gain: NDArray[np.float64],
              gain_prime: NDArray[np.float64],
              xi: NDArray[np.float64], eta: NDArray[np.float64], u: NDArray[np.float64],
              next_memory: NDArray[np.float64], sf: SafetyArrays) -> None:
    """One trial of N robots; fills xi, eta (N, T+1, 3), u (N, T, 2) and next_memory.

    tau : shape (N, L, T+1), delay of each in-link at each sample; tau0 : shape (N, T+1).
    A link delivers at sample t the sender's output labelled t - tau (the network); the
    law itself is ``command``. plant : 0 Euler, 1 exact arc (``Problem.plant``).
    sf : the safety filter (``safety_arrays``); u is what it let through.
    """
    n, n_links = src.shape
    ws = _workspace(n, n_links, memory.shape[1])
    _trial(law, memory_mode, heading, plant, dt, memory, xi0, dist, noise, tau, tau0, src, weight,
           leader, eta_d, gain, gain_prime, xi, eta, u, next_memory, ws[0], ws[1], ws[2], ws[3],
           ws[4], sf)


@njit(cache=True)
def _workspace(n: int, n_links: int, n_t: int) -> tuple[
        NDArray[np.float64], NDArray[np.int64], NDArray[np.int64], NDArray[np.float64],
        NDArray[np.float64]]:
    """Scratch of one trial: neighbour outputs as received (N, L, 3), their labels (N, L),
    the leader's labels (N,), neighbours' whole trajectories (N, L, T+1, 3), cos and sin of
    the gain heading (N, T, 2)."""
    return (np.zeros((n, n_links, 3)), np.zeros((n, n_links), dtype=np.int64),
            np.zeros(n, dtype=np.int64), np.zeros((n, n_links, n_t + 1, 3)),
            np.zeros((n, n_t, 2)))


@njit(cache=True)
def _trial(law: int, memory_mode: int, heading: int, plant: int, dt: float,
           memory: NDArray[np.float64], xi0: NDArray[np.float64],
           dist: NDArray[np.float64], noise: NDArray[np.float64],
           tau: NDArray[np.int64], tau0: NDArray[np.int64],
           src: NDArray[np.int64], weight: NDArray[np.float64], leader: NDArray[np.float64],
           eta_d: NDArray[np.float64], gain: NDArray[np.float64],
           gain_prime: NDArray[np.float64],
           xi: NDArray[np.float64], eta: NDArray[np.float64], u: NDArray[np.float64],
           next_memory: NDArray[np.float64], nb_eta: NDArray[np.float64],
           nb_s: NDArray[np.int64], lead_s: NDArray[np.int64],
           nb_full: NDArray[np.float64], trig: NDArray[np.float64], sf: SafetyArrays) -> int:
    """``run_trial`` on the scratch of :func:`_workspace` (reused from trial to trial).
    Returns how many commands (robots x samples) the safety filter changed."""
    n, n_links = src.shape
    n_t = memory.shape[1]
    safe = sf[0].shape[0] > 0
    nb_eta[:] = 0.0
    nb_s[:] = 0
    lead_s[:] = 0
    xi[:, 0] = xi0
    if safe:
        sf[4][:] = 0.0  # a trial starts from rest
    for t in range(n_t):
        for r in range(n):
            for c in range(3):
                eta[r, t, c] = xi[r, t, c] + noise[r, t, c]
        for r in range(n):
            for ell in range(n_links):
                j = src[r, ell]
                s = delivered_label(t, tau[r, ell, t])
                nb_s[r, ell] = s
                if j >= 0 and s >= 0:
                    for c in range(3):
                        nb_eta[r, ell, c] = eta[j, s, c]
            lead_s[r] = delivered_label(t, tau0[r, t])
        heading_trig(heading, eta, eta_d, t, t + 1, trig, 0)
        command_trig(t, t, law, memory, eta, eta_d, nb_eta, nb_s, src, weight, eta_d,
                     lead_s, leader, gain_prime, trig, u)
        if safe:
            filter_team(t, u, eta, sf[4], sf[1][1], sf[0], int(sf[1][2]), sf[2], sf[3], sf[5],
                        sf[6], sf[8])
        # step_into's arithmetic, by index (views of xi, u, dist per sample cost ~5 %)
        for r in range(n):
            if plant == 0:
                xi[r, t + 1, 0], xi[r, t + 1, 1], xi[r, t + 1, 2] = unicycle_step(
                    xi[r, t, 0], xi[r, t, 1], xi[r, t, 2], u[r, t, 0] + dist[r, t, 0],
                    u[r, t, 1] + dist[r, t, 1], dt)
            else:
                xi[r, t + 1, 0], xi[r, t + 1, 1], xi[r, t + 1, 2] = arc_step(
                    xi[r, t, 0], xi[r, t, 1], xi[r, t, 2], u[r, t, 0] + dist[r, t, 0],
                    u[r, t, 1] + dist[r, t, 1], dt)
    for r in range(n):
        for c in range(3):
            eta[r, n_t, c] = xi[r, n_t, c] + noise[r, n_t, c]
    for r in range(n):
        for ell in range(n_links):
            j = src[r, ell]
            if j >= 0:
                nb_full[r, ell] = eta[j]
    if not safe:
        learn_trig(law, memory_mode, memory, u, eta, eta_d, nb_full, src, weight, eta_d, leader,
                   gain, trig, next_memory)
        return 0
    mode = int(sf[1][0])
    learn_base(mode, memory, sf[2], u, sf[3], sf[7])
    learn_trig(law, memory_mode, sf[7], u, eta, eta_d, nb_full, src, weight, eta_d, leader,
               gain, trig, next_memory)
    after_learning(mode, dt, memory, sf[3], next_memory)
    changed = 0
    for r in range(n):
        for t in range(n_t):
            if sf[3][r, t] & CHANGED:
                changed += 1
    return changed


@njit(cache=True)
def run_trials(seed: NDArray[np.uint32], first_trial: int, plant: PlantArrays,
               delays: DelayArrays, law: int, memory_mode: int, heading: int,
               model: int, dt: float,
               src: NDArray[np.int64], weight: NDArray[np.float64], leader: NDArray[np.float64],
               eta_d: NDArray[np.float64], gain: NDArray[np.float64],
               gain_prime: NDArray[np.float64], memory: NDArray[np.float64],
               spare: NDArray[np.float64], metrics: NDArray[np.float64],
               xi: NDArray[np.float64], eta: NDArray[np.float64], u: NDArray[np.float64],
               tau: NDArray[np.int64], tau0: NDArray[np.int64], sf: SafetyArrays) -> bool:
    """Trials first_trial, first_trial + 1, ... (one per row of ``metrics``), compiled end to
    end: each trial's draws (``uncertainty.fill_plant`` / ``fill_delays``), ``_trial`` and
    ``trial_errors`` into its metrics row (METRIC_COLUMNS; the commands the safety filter
    ``sf`` changed, and no contacts: nan).

    model : the plant model (``Problem.plant``). memory : the first trial's memory
    (N, T, 2); spare : an array like it. They alternate
    as this and the next trial's memory. Returns True when the memory after the last trial
    is in ``spare``, False when in ``memory``. xi, eta, u, tau, tau0 : the last trial's.
    """
    n, n_links = src.shape
    n_t = memory.shape[1]
    state = np.empty(STATE_SIZE, dtype=np.uint64)
    shift = np.empty((n, 3))
    dist = np.empty((n, n_t, 2))
    noise = np.empty((n, n_t + 1, 3))
    xi0 = np.empty((n, 3))
    row = np.empty(6)
    nb_eta, nb_s, lead_s, nb_full, trig = _workspace(n, n_links, n_t)
    cur = memory
    nxt = spare
    swapped = False
    for i in range(metrics.shape[0]):
        k = first_trial + i
        fill_plant(seed, k, plant[0], plant[1], plant[2], plant[3], plant[4], state, shift,
                   dist, noise)
        fill_delays(seed, k, delays[0], delays[1], delays[2], delays[3], delays[4], delays[5],
                    delays[6], delays[7], state, tau, tau0)
        for r in range(n):
            for c in range(3):
                xi0[r, c] = eta_d[r, 0, c] + shift[r, c]
        changed = _trial(law, memory_mode, heading, model, dt, cur, xi0, dist, noise, tau, tau0,
                         src, weight, leader, eta_d, gain, gain_prime, xi, eta, u, nxt, nb_eta,
                         nb_s, lead_s, nb_full, trig, sf)
        trial_errors(eta, xi, eta_d, src, weight, row)
        metrics[i, 0] = k
        for c in range(6):
            metrics[i, c + 1] = row[c]
        metrics[i, 7] = changed
        metrics[i, 8] = np.nan  # no bodies, no contacts
        cur, nxt = nxt, cur
        swapped = not swapped
    return swapped


@njit(cache=True)
def trial_errors(eta: NDArray[np.float64], xi: NDArray[np.float64],
                 eta_d: NDArray[np.float64], src: NDArray[np.int64],
                 weight: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """Metrics of one trial over robots and t in [1, T] (the METRIC_COLUMNS after 'trial').

    eta, xi, eta_d : shape (N, T+1, 3). out : shape (6,).
    """
    n, m, _ = eta.shape
    mp = 0.0
    mh = 0.0
    tp = 0.0
    th = 0.0
    ss = 0.0
    mf = 0.0
    for r in range(n):
        for t in range(1, m):
            ex = eta_d[r, t, 0] - eta[r, t, 0]
            ey = eta_d[r, t, 1] - eta[r, t, 1]
            p = np.sqrt(ex * ex + ey * ey)
            ss += p * p
            mp = max(mp, p)
            mh = max(mh, abs(wrap_angle(eta_d[r, t, 2] - eta[r, t, 2])))
            ex = eta_d[r, t, 0] - xi[r, t, 0]
            ey = eta_d[r, t, 1] - xi[r, t, 1]
            tp = max(tp, np.sqrt(ex * ex + ey * ey))
            th = max(th, abs(wrap_angle(eta_d[r, t, 2] - xi[r, t, 2])))
            for ell in range(src.shape[1]):
                j = src[r, ell]
                if j < 0 or weight[r, ell] == 0.0:
                    continue
                fx = (eta_d[r, t, 0] - eta_d[j, t, 0]) - (eta[r, t, 0] - eta[j, t, 0])
                fy = (eta_d[r, t, 1] - eta_d[j, t, 1]) - (eta[r, t, 1] - eta[j, t, 1])
                mf = max(mf, np.sqrt(fx * fx + fy * fy))
    out[0] = mp
    out[1] = mh
    out[2] = tp
    out[3] = th
    out[4] = np.sqrt(ss / (n * (m - 1)))
    out[5] = mf


@dataclass(frozen=True)
class TrialRecord:
    """One trial's trajectories: xi, eta (N, T+1, 3) true and measured, u (N, T, 2)."""

    trial: int
    xi: NDArray[np.float64]
    eta: NDArray[np.float64]
    u: NDArray[np.float64]


@dataclass
class SimResult:
    """metrics : shape (K, len(METRIC_COLUMNS)); records : chosen trials; memory : the
    memory for the trial after the last, shape (N, T, 2)."""

    metrics: NDArray[np.float64]
    records: dict[int, TrialRecord] = field(default_factory=dict)
    memory: NDArray[np.float64] | None = None

    def column(self, name: str) -> NDArray[np.float64]:
        return self.metrics[:, METRIC_COLUMNS.index(name)]


def simulate_bytes(scenario: Scenario, trials: int | None = None, keep: int = 0,
                   store_metrics: bool = True) -> int:
    """Peak memory [bytes] of ``simulate`` beyond the loaded scenario, estimated before
    anything is allocated: 32 + 4 L floats per robot and sample (L in-links per robot; the
    desired trajectories while they are built, then the working arrays, two trials' random
    draws and the kernel's neighbour trajectories), 8 more per kept trial, and 56 bytes per
    trial of metrics if ``store_metrics``. Measured peak RSS at 10^5 and 10^6 samples (6 and
    3 robots, L = 1): 33 to 36 floats per robot and sample without kept trials.
    """
    n, n_t = scenario.n, scenario.samples
    links = max(1, max((len(scenario.graph.neighbours(i)) for i in range(n)), default=1))
    k = scenario.trials if trials is None else int(trials)
    per_robot_sample = 8 * (32 + 4 * links + 8 * keep)
    rows = k * 8 * len(METRIC_COLUMNS) if store_metrics else 0
    return per_robot_sample * n * (n_t + 2) + rows


def simulate(
    scenario: Scenario,
    trials: int | None = None,
    keep: Iterable[int] = (),
    progress: Callable[[int, NDArray[np.float64]], None] | None = None,
    initial_memory: NDArray[np.float64] | None = None,
    first_trial: int = 0,
    on_trial_data: Callable[..., None] | None = None,
    *,
    stop_on_divergence: bool = False,
    on_memory: Callable[[int, NDArray[np.float64]], None] | None = None,
    store_metrics: bool = True,
    problem: Problem | None = None,
    plant: str = "euler",
    safety: SafetySpec | None = None,
    safety_age: float = 0.0,
) -> SimResult:
    """Run ``trials`` trials (default: the scenario's) and return per-trial metrics.

    keep : trial indices whose trajectories are returned. initial_memory : shape (N, T, 2),
    default u_0 = 0 (the paper's). first_trial : index of the first trial (its random draws
    are those of that index, so a run can continue another).
    progress : called after each trial with (trial, metrics row).
    on_trial_data : called after each trial with (trial, xi, eta, u, tau, tau0), e.g. to
        record it; the arrays are reused, copy what you keep.
    stop_on_divergence : check each trial's outputs, inputs and learned memory
        (``guards.check_finite``) and raise ``DivergedError`` at the first inf or nan, its
        ``result`` holding the finished trials' metrics and the last finite memory (the
        one the failing trial started from). Otherwise a diverged run goes on in nan.
    on_memory : called after each trial with (index of the next trial, the memory for it,
        shape (N, T, 2)); the array is reused two trials later, copy what you keep.
    store_metrics : keep every trial's metrics row in ``SimResult.metrics``; False keeps
        none (shape (0, 7)), for a run of any length in bounded memory whose rows go to
        ``progress``.
    problem : ``Problem.from_scenario(scenario)`` when the caller has it already (a study
        runs many seeds of one configuration); it does not depend on the seed or trials.
    plant : the plant model when ``problem`` is None: 'euler' (eq. 1, default) or 'arc' (a
        unicycle that drives arcs; the scenario's 'auto' headings then read as 'arc').
    safety : when ``problem`` is None, the safety filter between the law and the plant
        (``core.safety``; None: none): each robot filters with every other robot's measured
        pose of the sample, taken as ``safety_age`` [s] old. The metrics' ``filter_active``
        column counts the commands it changed.
    """
    pb = (Problem.from_scenario(scenario.for_plant(plant), plant, safety, safety_age)
          if problem is None else problem)
    k_total = scenario.trials if trials is None else int(trials)
    n, n_t, n_links = pb.n, pb.samples, pb.src.shape[1]
    unc = scenario.uncertainty
    memory = (np.zeros((n, n_t, 2)) if initial_memory is None
              else np.array(initial_memory, dtype=float))
    if memory.shape != (n, n_t, 2):
        raise ValueError(f"initial memory must have shape {(n, n_t, 2)}, got {memory.shape}")
    if first_trial < 0:
        raise ValueError(f"first_trial must be >= 0, got {first_trial}")
    nxt = np.empty_like(memory)
    xi = np.empty((n, n_t + 1, 3))
    eta = np.empty_like(xi)
    u = np.empty((n, n_t, 2))
    tau = np.empty((n, n_links, n_t + 1), dtype=np.int64)
    tau0 = np.empty((n, n_t + 1), dtype=np.int64)
    metrics = np.empty((k_total if store_metrics else 0, len(METRIC_COLUMNS)))
    keep = set(keep)
    records: dict[int, TrialRecord] = {}
    args = (seed_words(scenario.seed), first_trial, plant_arrays(unc, n_t), delay_arrays(unc),
            pb.law, pb.memory, pb.heading, pb.plant, pb.dt, pb.src, pb.weight, pb.leader,
            pb.eta_d, pb.gain, pb.gain_prime)
    sf = safety_arrays(pb)
    if (not keep and progress is None and on_trial_data is None and not stop_on_divergence
            and on_memory is None and store_metrics):
        # every trial in one compiled call: nothing to do in Python between trials
        if run_trials.jit(*args, memory, nxt, metrics, xi, eta, u, tau, tau0, sf):
            memory = nxt
        return SimResult(metrics=metrics, records=records, memory=memory)
    memory = _one_by_one(pb, args, sf, memory, nxt, metrics, (xi, eta, u, tau, tau0),
                         range(first_trial, first_trial + k_total), keep=keep, records=records,
                         progress=progress, on_trial_data=on_trial_data, on_memory=on_memory,
                         stop_on_divergence=stop_on_divergence, store_metrics=store_metrics)
    return SimResult(metrics=metrics, records=records, memory=memory)


def _one_by_one(pb: Problem, args: tuple[Any, ...], sf: Any, memory: NDArray[np.float64],
                nxt: NDArray[np.float64], metrics: NDArray[np.float64],
                bufs: tuple[NDArray[Any], ...], trials: range, *, keep: set[int],
                records: dict[int, TrialRecord],
                progress: Callable[[int, NDArray[np.float64]], None] | None,
                on_trial_data: Callable[..., None] | None,
                on_memory: Callable[[int, NDArray[np.float64]], None] | None,
                stop_on_divergence: bool, store_metrics: bool) -> NDArray[np.float64]:
    """``simulate``'s trials one compiled call each, with its hooks between them (``args``
    and ``sf`` the compiled loop's, ``bufs`` its arrays xi, eta, u, tau, tau0); the memory
    after the last. DivergedError (``stop_on_divergence``) with the result so far."""
    xi, eta, u, tau, tau0 = bufs
    n = pb.n
    rows = np.empty((1, len(METRIC_COLUMNS)))
    row = rows[0]

    def diverged(exc: DivergedError, done: int) -> DivergedError:
        exc.result = SimResult(metrics=metrics[:done].copy(), records=records,
                               memory=memory.copy())
        return exc

    for i, k in enumerate(trials):
        # the same compiled code, one trial per call
        run_trials.jit(*args[:1], k, *args[2:], memory, nxt, rows, xi, eta, u, tau, tau0, sf)
        done = i if store_metrics else 0
        if stop_on_divergence:
            try:
                check_finite(k, row, output=eta, input=u)
            except DivergedError as exc:
                if exc.robot is None:  # finite states whose squared errors overflow
                    far = np.abs(eta[..., :2] - pb.eta_d[..., :2]).reshape(n, -1).max(axis=1)
                    exc = DivergedError(k, exc.what, int(np.argmax(far)) + 1)
                raise diverged(exc, done) from None
        if store_metrics:
            metrics[i] = row
        if k in keep:
            records[k] = TrialRecord(k, xi.copy(), eta.copy(), u.copy())
        if on_trial_data is not None:
            on_trial_data(k, xi, eta, u, tau, tau0)
        if progress is not None:
            progress(k, row.copy())
        if stop_on_divergence:
            try:
                check_finite(k, learned_memory=nxt)
            except DivergedError as exc:
                raise diverged(exc, done + store_metrics) from None
        memory, nxt = nxt, memory
        if on_memory is not None:
            on_memory(k + 1, memory)
    return memory


def simulate_seeds(scenario: Scenario, seeds: Iterable[int], trials: int) -> NDArray[np.float64]:
    """Many independent runs at once: the teams are stacked on the robot axis.

    Returns the max measured position error, shape (S, trials).
    """
    seeds = list(seeds)
    base = Problem.from_scenario(scenario)
    pb = base.tiled(len(seeds))
    n1, n_t, n_links = base.n, base.samples, base.src.shape[1]
    n = pb.n
    unc = scenario.uncertainty
    memory = np.zeros((n, n_t, 2))
    nxt = np.empty_like(memory)
    xi = np.empty((n, n_t + 1, 3))
    eta = np.empty_like(xi)
    u = np.empty((n, n_t, 2))
    out = np.empty((len(seeds), trials))
    row = np.empty(len(METRIC_COLUMNS) - 1)
    # each seed's draws into its rows of the stacked arrays, by the compiled kernels
    shift, dist, noise = np.empty((n, 3)), np.empty((n, n_t, 2)), np.empty((n, n_t + 1, 3))
    tau = np.empty((n, n_links, n_t + 1), dtype=np.int64)
    tau0 = np.empty((n, n_t + 1), dtype=np.int64)
    state = np.empty(STATE_SIZE, dtype=np.uint64)
    words = [seed_words(s) for s in seeds]
    plant_args, delay_args = plant_arrays(unc, n_t), delay_arrays(unc)
    for k in range(trials):
        for i, w in enumerate(words):
            sl = slice(i * n1, (i + 1) * n1)
            fill_plant.jit(w, k, *plant_args, state, shift[sl], dist[sl], noise[sl])
            fill_delays.jit(w, k, *delay_args, state, tau[sl], tau0[sl])
        run_trial.jit(pb.law, pb.memory, pb.heading, pb.plant, pb.dt, memory,
                      pb.eta_d[:, 0] + shift, dist,
                      noise, tau, tau0, pb.src, pb.weight, pb.leader, pb.eta_d, pb.gain,
                      pb.gain_prime, xi, eta, u, nxt, safety_arrays(pb))
        for i in range(len(seeds)):
            sl = slice(i * n1, (i + 1) * n1)
            trial_errors.jit(eta[sl], xi[sl], base.eta_d, base.src, base.weight, row)
            out[i, k] = row[0]
        memory, nxt = nxt, memory
    return out
