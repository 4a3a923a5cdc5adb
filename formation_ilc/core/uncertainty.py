"""Initial-state shifts, input disturbances, output noises and delays of one trial (Sec. IV.A).

Every trial's draws come from its own generators, seeded by (seed, trial, stream), so any
process of the distributed stack can draw exactly what the batch simulator draws for the
same trial: the kinematic simulator draws the ``plant`` stream, the link emulator the
``delay`` stream. Changing the draw order here changes every recorded run.

The generator is ``numpy.random.default_rng([seed, trial, stream])`` (:func:`trial_rng`).
``Uncertainty.draw_plant`` and ``draw_delays`` (the nodes' draws, once per trial) are the
contract below in numpy; the batch simulator draws a trial inside its compiled loop with
kernels (:func:`fill_plant`, :func:`fill_delays`) that reproduce numpy's numbers bit for bit
(``pcg.py``). In numpy terms, the contract is::

    rng = trial_rng(seed, trial, PLANT_STREAM)
    shift = rng.uniform(-1, 1, (n, 3)) * initial_shift
    dist = rng.uniform(-1, 1, (n, T, 2)) * disturbance_uniform + disturbance_fixed(t)
    noise = rng.uniform(-1, 1, (n, T + 1, 3)) * noise_uniform + noise_fixed(t)
    rng = trial_rng(seed, trial, DELAY_STREAM)
    tau = delay.draw(rng, (n, L, T + 1)); tau0 = delay.draw(rng, (n, T + 1)) if delay_leader

(tests/core/test_uncertainty_draws.py pins it against numpy's generator.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit
from formation_ilc.core.delays import DelayModel
from formation_ilc.core.links import LOST
from formation_ilc.core.pcg import next_double, seed_state, seed_words

__all__ = ["Harmonic", "Uncertainty", "TrialDraws", "trial_rng", "PLANT_STREAM", "DELAY_STREAM",
           "PlantArrays", "DelayArrays", "plant_arrays", "delay_arrays", "fill_plant",
           "fill_delays", "seed_words"]

PLANT_STREAM = 0
DELAY_STREAM = 1
#: lost samples come from a stream of their own: a lossless scenario draws what it always did
LOSS_STREAM = 2


def trial_rng(seed: int, trial: int, stream: int) -> np.random.Generator:
    """Generator for one trial and one stream (plant or delay)."""
    return np.random.default_rng([int(seed), int(trial), int(stream)])


@dataclass(frozen=True)
class Harmonic:
    """amplitude * sin(frequency * t + phase), t the sample index (as in Sec. IV.A)."""

    amplitude: float = 0.0
    frequency: float = 0.0
    phase: float = 0.0

    def __call__(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.amplitude * np.sin(self.frequency * np.asarray(t, dtype=float) + self.phase)


@lru_cache(maxsize=64)
def _harmonic_values(h: Harmonic, length: int) -> NDArray[np.float64]:
    """h at t = 0..length-1, computed once per (harmonic, length): the iteration-independent
    part of every trial's draws (read-only)."""
    v = h(np.arange(length, dtype=float))
    v.setflags(write=False)
    return v


@dataclass(frozen=True)
class Uncertainty:
    """What perturbs each trial.

    initial_shift : half-widths of the uniform initial-state shift (x, y, theta) [m, m, rad].
    disturbance_fixed / disturbance_uniform : iteration-independent harmonics and uniform
        half-widths of (Dv, Domega) [m/s, rad/s].
    noise_fixed / noise_uniform : the same for (Nx, Ny, Ntheta) [m, m, rad].
    delay : model of every link's delay; ``delay_leader`` whether the leader link is delayed.
    link_loss : probability that a link loses a sample (it then delivers nothing at that
        tick, ``links.LOST``); the leader link too when ``delay_leader``.
    """

    initial_shift: tuple[float, float, float] = (0.0, 0.0, 0.0)
    disturbance_fixed: tuple[Harmonic, Harmonic] = (Harmonic(), Harmonic())
    disturbance_uniform: tuple[float, float] = (0.0, 0.0)
    noise_fixed: tuple[Harmonic, Harmonic, Harmonic] = (Harmonic(), Harmonic(), Harmonic())
    noise_uniform: tuple[float, float, float] = (0.0, 0.0, 0.0)
    delay: DelayModel = field(default_factory=DelayModel)
    delay_leader: bool = True
    link_loss: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.link_loss < 1.0:
            raise ValueError(f"link loss must be in [0, 1), got {self.link_loss}")

    def without_noise(self) -> Uncertainty:
        """No initial shift, disturbance or noise; delays kept."""
        return Uncertainty(delay=self.delay, delay_leader=self.delay_leader,
                           link_loss=self.link_loss)

    def without_delay(self) -> Uncertainty:
        return Uncertainty(self.initial_shift, self.disturbance_fixed, self.disturbance_uniform,
                           self.noise_fixed, self.noise_uniform, DelayModel(), self.delay_leader)

    def pose_bounds(self) -> tuple[float, float]:
        """How far the difference of two robots' measured positions can be from the true
        one [m], and how far one robot's measured position can move between two samples
        beyond its true motion [m]: what the safety filter widens its distance and its
        estimates of the other robots' speeds by. The fixed harmonics are the same for
        every robot (``noise_fixed(t)``), so only the uniform half-widths part two robots'
        positions (2 u per axis); from one sample to the next both the uniform part (2 u)
        and the harmonics' largest step move a robot's."""
        ux, uy = abs(self.noise_uniform[0]), abs(self.noise_uniform[1])
        step = max(abs(h.amplitude * h.frequency) for h in self.noise_fixed[:2])
        apart = math.hypot(2 * ux, 2 * uy)
        return apart, apart + step

    def estimate_bounds(self, dt: float) -> tuple[float, float]:
        """What a position's box (``core.estimate``) is built on: how far one robot's
        measured position is from its true one per axis, the harmonics every robot shares
        left out (they move all alike) [m]; and how far per axis a sample of its motion
        can be from the arc of the command it applied: its speed's disturbance over dT and
        the shared harmonics' step (the box tracks them with the position) [m]."""
        per_axis = max(abs(self.noise_uniform[0]), abs(self.noise_uniform[1]))
        step = max(abs(h.amplitude * h.frequency) for h in self.noise_fixed[:2])
        dv = abs(self.disturbance_fixed[0].amplitude) + abs(self.disturbance_uniform[0])
        return per_axis, dv * dt + step

    def heading_bound(self) -> float:
        """How far one robot's measured heading can be from its true one [rad]: its
        uniform half-width and its fixed harmonic's amplitude."""
        return abs(self.noise_uniform[2]) + abs(self.noise_fixed[2].amplitude)

    @property
    def pose_noise(self) -> bool:
        """The measured poses carry noise drawn anew every trial (``noise_uniform``): what
        a learning law cannot learn, and takes into its memory unless it filters it."""
        return any(self.noise_uniform)

    @property
    def noisy(self) -> bool:
        return bool(
            any(self.initial_shift) or any(self.disturbance_uniform) or any(self.noise_uniform)
            or any(h.amplitude for h in self.disturbance_fixed)
            or any(h.amplitude for h in self.noise_fixed)
        )

    def draw_plant(self, seed: int, trial: int, n: int, n_samples: int
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """(shift (n, 3), disturbance (n, T, 2), noise (n, T+1, 3)) of one trial."""
        shift_w, dist_w, noise_w, dist_fixed, noise_fixed = plant_arrays(self, n_samples)
        rng = trial_rng(seed, _trial_index(trial), PLANT_STREAM)
        # numpy's uniform(-1, 1) is -1 + 2 random(): the kernel's numbers, in its order
        shift = rng.uniform(-1.0, 1.0, (n, 3)) * shift_w
        dist = rng.uniform(-1.0, 1.0, (n, n_samples, 2)) * dist_w + dist_fixed.T
        noise = rng.uniform(-1.0, 1.0, (n, n_samples + 1, 3)) * noise_w + noise_fixed.T
        return shift, dist, noise

    def draw_delays(self, seed: int, trial: int, n: int, n_links: int, n_samples: int
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(tau of each in-link (n, L, T+1), tau of each leader link (n, T+1)) in samples;
        a lost sample's tau is ``links.LOST``."""
        trial = _trial_index(trial)
        rng = trial_rng(seed, trial, DELAY_STREAM)
        tau = self.delay.draw(rng, (n, n_links, n_samples + 1))
        tau0 = (self.delay.draw(rng, (n, n_samples + 1)) if self.delay_leader
                else np.zeros((n, n_samples + 1), dtype=np.int64))
        if self.link_loss > 0.0:
            lost = trial_rng(seed, trial, LOSS_STREAM)
            tau[lost.random(tau.shape) < self.link_loss] = LOST
            if self.delay_leader:
                tau0[lost.random(tau0.shape) < self.link_loss] = LOST
        return tau, tau0


def _trial_index(trial: int) -> int:
    trial = int(trial)
    if trial < 0:
        raise ValueError(f"a trial index is >= 0, got {trial}")
    return trial


#: (initial_shift (3,), disturbance_uniform (2,), noise_uniform (3,),
#: disturbance_fixed at t = 0..T-1 (2, T), noise_fixed at t = 0..T (3, T+1))
PlantArrays = tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64],
                    NDArray[np.float64], NDArray[np.float64]]
#: (kind: 0 none, 1 fixed, 2 uniform, 3 table; the fixed delay; uniform low; uniform
#: count high - low + 1; table values; table edges cumsum(probabilities)[:-1]; delay_leader;
#: link_loss)
DelayArrays = tuple[int, int, int, int, NDArray[np.int64], NDArray[np.float64], bool, float]


@lru_cache(maxsize=64)
def plant_arrays(unc: Uncertainty, n_samples: int) -> PlantArrays:
    """The arguments of :func:`fill_plant` after the seed and trial (read-only)."""
    out = (np.asarray(unc.initial_shift, dtype=float),
           np.asarray(unc.disturbance_uniform, dtype=float),
           np.asarray(unc.noise_uniform, dtype=float),
           np.stack([_harmonic_values(h, n_samples) for h in unc.disturbance_fixed]),
           np.stack([_harmonic_values(h, n_samples + 1) for h in unc.noise_fixed]))
    for a in out:
        a.setflags(write=False)
    return out


@lru_cache(maxsize=64)
def delay_arrays(unc: Uncertainty) -> DelayArrays:
    """The arguments of :func:`fill_delays` after the seed and trial (read-only)."""
    d = unc.delay
    kind = ("none", "fixed", "uniform", "table").index(d.kind)
    values = np.asarray(d.values if d.kind == "table" else (0,), dtype=np.int64)
    # DelayModel.draw's edges, computed as it computes them
    edges = (np.cumsum(d.probabilities)[:-1] if d.kind == "table" else np.zeros(0)
             ).astype(float)
    values.setflags(write=False)
    edges.setflags(write=False)
    return (kind, d.samples, d.low, d.high - d.low + 1, values, edges, unc.delay_leader,
            float(unc.link_loss))


@njit(cache=True)
def fill_plant(seed: NDArray[np.uint32], trial: int, shift_w: NDArray[np.float64],
               dist_w: NDArray[np.float64], noise_w: NDArray[np.float64],
               dist_fixed: NDArray[np.float64], noise_fixed: NDArray[np.float64],
               state: NDArray[np.uint64], shift: NDArray[np.float64],
               dist: NDArray[np.float64], noise: NDArray[np.float64]) -> None:
    """The plant stream of one trial into shift (n, 3), dist (n, T, 2), noise (n, T+1, 3),
    exactly as ``Uncertainty.draw_plant``'s numpy contract. seed : ``seed_words(seed)``;
    state : scratch, uint64 (STATE_SIZE,)."""
    seed_state(seed, trial, PLANT_STREAM, state)
    n = shift.shape[0]
    for i in range(n):
        for c in range(3):
            shift[i, c] = (-1.0 + 2.0 * next_double(state)) * shift_w[c]
    for i in range(n):
        for t in range(dist.shape[1]):
            for c in range(2):
                dist[i, t, c] = (-1.0 + 2.0 * next_double(state)) * dist_w[c] + dist_fixed[c, t]
    for i in range(n):
        for t in range(noise.shape[1]):
            for c in range(3):
                noise[i, t, c] = ((-1.0 + 2.0 * next_double(state)) * noise_w[c]
                                  + noise_fixed[c, t])


@njit(cache=True)
def fill_delays(seed: NDArray[np.uint32], trial: int, kind: int, fixed: int, low: int,
                count: int, values: NDArray[np.int64], edges: NDArray[np.float64],
                leader: bool, loss: float, state: NDArray[np.uint64], tau: NDArray[np.int64],
                tau0: NDArray[np.int64]) -> None:
    """The delay stream of one trial into tau (n, L, T+1) and tau0 (n, T+1), then the loss
    stream, exactly as ``Uncertainty.draw_delays``. Arguments after the trial:
    :func:`delay_arrays`."""
    if kind <= 1:  # none, fixed: nothing drawn
        tau[:] = 0 if kind == 0 else fixed
        tau0[:] = fixed if kind == 1 and leader else 0
    else:
        seed_state(seed, trial, DELAY_STREAM, state)
        # one number per delay, tau first, then tau0 (C order), as DelayModel.draw; the
        # loops are written out per kind (a call per delay with the arrays costs 20 ns each)
        for target in range(2 if leader else 1):
            flat = tau.reshape(-1) if target == 0 else tau0.reshape(-1)
            if kind == 2:
                for i in range(flat.shape[0]):
                    flat[i] = low + min(int(next_double(state) * count), count - 1)
            else:
                n_edges = edges.shape[0]
                for i in range(flat.shape[0]):
                    kappa = next_double(state)
                    # np.searchsorted(edges, kappa, side="right") on sorted edges: how many
                    # are <= kappa; counted without branches (a random branch mispredicts)
                    idx = 0
                    for e in range(n_edges):
                        idx += edges[e] <= kappa
                    flat[i] = values[idx]
        if not leader:
            tau0[:] = 0
    if loss > 0.0:  # tau[random < loss] = LOST, then tau0 likewise if the leader link is
        seed_state(seed, trial, LOSS_STREAM, state)
        for target in range(2 if leader else 1):
            flat = tau.reshape(-1) if target == 0 else tau0.reshape(-1)
            for i in range(flat.shape[0]):
                if next_double(state) < loss:
                    flat[i] = LOST


@dataclass(frozen=True)
class TrialDraws:
    shift: NDArray[np.float64]
    disturbance: NDArray[np.float64]
    noise: NDArray[np.float64]
    tau: NDArray[np.int64]
    tau_leader: NDArray[np.int64]
