"""Initial-state shifts, input disturbances, output noises and delays of one trial (Sec. IV.A).

Every trial's draws come from its own generators, seeded by (seed, trial, stream), so any
process of the distributed stack can draw exactly what the batch simulator draws for the
same trial: the kinematic simulator draws the ``plant`` stream, the link emulator the
``delay`` stream. Changing the draw order here changes every recorded run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from .delays import DelayModel
from .links import LOST

__all__ = ["Harmonic", "Uncertainty", "TrialDraws", "trial_rng", "PLANT_STREAM", "DELAY_STREAM"]

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
        rng = trial_rng(seed, trial, PLANT_STREAM)
        shift = rng.uniform(-1.0, 1.0, (n, 3)) * np.asarray(self.initial_shift)
        dist = rng.uniform(-1.0, 1.0, (n, n_samples, 2)) * np.asarray(self.disturbance_uniform)
        noise = rng.uniform(-1.0, 1.0, (n, n_samples + 1, 3)) * np.asarray(self.noise_uniform)
        for c, h in enumerate(self.disturbance_fixed):
            dist[..., c] += _harmonic_values(h, n_samples)
        for c, h in enumerate(self.noise_fixed):
            noise[..., c] += _harmonic_values(h, n_samples + 1)
        return shift, dist, noise

    def draw_delays(self, seed: int, trial: int, n: int, n_links: int, n_samples: int
                    ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """(tau of each in-link (n, L, T+1), tau of each leader link (n, T+1)) in samples;
        a lost sample's tau is ``links.LOST``."""
        rng = trial_rng(seed, trial, DELAY_STREAM)
        tau = self.delay.draw(rng, (n, n_links, n_samples + 1))
        if self.delay_leader:
            tau0 = self.delay.draw(rng, (n, n_samples + 1))
        else:
            tau0 = np.zeros((n, n_samples + 1), dtype=np.int64)
        if self.link_loss > 0.0:
            lrng = trial_rng(seed, trial, LOSS_STREAM)
            tau[lrng.random(tau.shape) < self.link_loss] = LOST
            if self.delay_leader:
                tau0[lrng.random(tau0.shape) < self.link_loss] = LOST
        return tau, tau0


@dataclass(frozen=True)
class TrialDraws:
    shift: NDArray[np.float64]
    disturbance: NDArray[np.float64]
    noise: NDArray[np.float64]
    tau: NDArray[np.int64]
    tau_leader: NDArray[np.int64]
