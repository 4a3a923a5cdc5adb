"""Communication delays: measurement from time labels (eq. 11) and delay models.

A delay tau is a whole number of samples. Robot i at sample t uses, on each in-link, the
sender's output labelled t - tau (paper eq. 9/13).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["measure_delay", "measure_delays", "DelayModel", "PAPER_DELAY_PROBABILITIES"]

#: Sec. IV.A kappa table (paper-notes 6): P(tau = 1, 2, 3, 4 samples).
PAPER_DELAY_PROBABILITIES = {1: 0.15, 2: 0.30, 3: 0.35, 4: 0.20}


def measure_delay(receive_time: float, send_time: float, dt: float) -> int:
    """Eq. (11): tau = floor((Rt - St + 0.5 dT) / dT), times in seconds.

    A label from the future (clock skew) is measured as 0: a delay is never negative.
    """
    if dt <= 0:
        raise ValueError(f"dt must be positive, got {dt}")
    return max(0, math.floor((receive_time - send_time + 0.5 * dt) / dt))


def measure_delays(receive_time: NDArray[np.float64], send_time: NDArray[np.float64],
                   dt: float) -> NDArray[np.int64]:
    """Eq. (11) element-wise; shapes broadcast."""
    d = np.floor((np.asarray(receive_time) - np.asarray(send_time) + 0.5 * dt) / dt)
    return np.maximum(d, 0).astype(np.int64)


def measure_delay_ns(receive_ns: int, send_ns: int, dt_ns: int) -> int:
    """Eq. (11) in integer nanoseconds (ROS stamps): exact at the rounding boundaries."""
    return max(0, (receive_ns - send_ns + dt_ns // 2) // dt_ns)


@dataclass(frozen=True)
class DelayModel:
    """How many samples a link's data is late.

    kind : 'none' (tau = 0), 'fixed' (tau = ``samples``), 'uniform' (integers in
    [low, high]) or 'table' (``values`` with ``probabilities``; the paper's model).
    """

    kind: str = "none"
    samples: int = 0
    low: int = 0
    high: int = 0
    values: tuple[int, ...] = ()
    probabilities: tuple[float, ...] = ()

    @classmethod
    def paper(cls) -> DelayModel:
        vals = tuple(PAPER_DELAY_PROBABILITIES)
        return cls(kind="table", values=vals,
                   probabilities=tuple(PAPER_DELAY_PROBABILITIES[v] for v in vals))

    def __post_init__(self) -> None:
        if self.kind not in ("none", "fixed", "uniform", "table"):
            raise ValueError(f"unknown delay model {self.kind!r}")
        if self.kind == "fixed" and self.samples < 0:
            raise ValueError("a fixed delay must be >= 0 samples")
        if self.kind == "uniform" and not 0 <= self.low <= self.high:
            raise ValueError("uniform delay needs 0 <= low <= high")
        if self.kind == "table":
            if len(self.values) == 0 or len(self.values) != len(self.probabilities):
                raise ValueError("a delay table needs as many probabilities as values")
            if min(self.values) < 0:
                raise ValueError("delays must be >= 0 samples")
            if abs(sum(self.probabilities) - 1.0) > 1e-9 or min(self.probabilities) < 0:
                raise ValueError("delay probabilities must be >= 0 and sum to 1")

    @property
    def max_delay(self) -> int:
        return {"none": 0, "fixed": self.samples, "uniform": self.high,
                "table": max(self.values, default=0)}[self.kind]

    def pmf(self) -> dict[int, float]:
        """Probability of each delay in samples."""
        if self.kind == "none":
            return {0: 1.0}
        if self.kind == "fixed":
            return {self.samples: 1.0}
        if self.kind == "uniform":
            k = self.high - self.low + 1
            return {d: 1.0 / k for d in range(self.low, self.high + 1)}
        return dict(zip(self.values, self.probabilities, strict=True))

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...]) -> NDArray[np.int64]:
        """Delays in samples, one per (link, sample); the draw order is part of the contract
        shared with the distributed stack, so it must not change."""
        if self.kind == "none":
            return np.zeros(shape, dtype=np.int64)
        if self.kind == "fixed":
            return np.full(shape, self.samples, dtype=np.int64)
        kappa = rng.random(shape)
        if self.kind == "uniform":
            k = self.high - self.low + 1
            return (self.low + np.minimum((kappa * k).astype(np.int64), k - 1)).astype(np.int64)
        edges = np.cumsum(self.probabilities)[:-1]
        idx = np.searchsorted(edges, kappa, side="right")
        return np.asarray(self.values, dtype=np.int64)[idx]
