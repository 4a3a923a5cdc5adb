"""Speed and acceleration limits of a robot base: checking a plan, limiting commands.

A base publishes its limits (its driver's or controller's configuration); a scenario's
desired inputs u_d (Assumption 1) must stay inside them, or the law asks for what the robot
cannot do, the commands are clipped, and the error the clipping leaves is learned as if the
robot had obeyed. ``check_inputs`` finds the first place a plan leaves the limits;
``RateLimiter`` keeps commands inside them at run time and counts what it clipped.

Units: v [m/s], omega [rad/s], accelerations [m/s^2] and [rad/s^2]. A limit of ``inf`` is
no limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Limits", "Violation", "check_inputs", "input_rates", "scale_needed", "RateLimiter"]


@dataclass(frozen=True)
class Limits:
    """Largest |v|, |omega|, |dv/dt| and |domega/dt| a base accepts."""

    v_max: float = math.inf
    omega_max: float = math.inf
    a_max: float = math.inf
    alpha_max: float = math.inf

    def __post_init__(self) -> None:
        for name in ("v_max", "omega_max", "a_max", "alpha_max"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and v > 0 and not math.isnan(v)):
                raise ValueError(f"{name} must be > 0 (inf for none), got {v!r}")

    def as_tuple(self) -> tuple[float, float, float, float]:
        return self.v_max, self.omega_max, self.a_max, self.alpha_max

    def tighter(self, other: Limits) -> Limits:
        """The tighter of two limits, field by field."""
        return Limits(*(min(a, b) for a, b in zip(self.as_tuple(), other.as_tuple(),
                                                   strict=True)))


_WHAT = (("speed", "m/s", "v_max"), ("turn rate", "rad/s", "omega_max"),
         ("acceleration", "m/s^2", "a_max"), ("angular acceleration", "rad/s^2", "alpha_max"))


@dataclass(frozen=True)
class Violation:
    """Where a plan leaves a robot's limits first (by the largest ratio): robot (1-based),
    sample, which quantity, its value and limit, and ``ratio`` = value / limit."""

    robot: int
    sample: int
    quantity: str
    unit: str
    value: float
    limit: float
    ratio: float

    def line(self, dt: float) -> str:
        return (f"robot {self.robot}: desired {self.quantity} {self.value:.3g} {self.unit} at "
                f"t = {self.sample * dt:.1f} s exceeds its limit {self.limit:.3g} {self.unit}")


def input_rates(u: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """Accelerations of desired inputs u (N, T, 2) [m/s^2, rad/s^2], shape (N, T, 2): from
    rest into sample 0 (a robot stands at a trial's start), then sample to sample."""
    prev = np.concatenate([np.zeros_like(u[:, :1]), u[:, :-1]], axis=1)
    return (u - prev) / dt


def check_inputs(u: NDArray[np.float64], dt: float, limits: list[Limits]
                 ) -> Violation | None:
    """The worst excess of desired inputs u (N, T, 2) over each robot's limits (one Limits
    per robot), or None if every value is inside (equal counts as inside)."""
    u = np.asarray(u, dtype=float)
    if len(limits) != u.shape[0]:
        raise ValueError(f"one Limits per robot: {u.shape[0]} robots, {len(limits)} given")
    acc = input_rates(u, dt)
    worst: Violation | None = None
    for r, lim in enumerate(limits):
        series = (u[r, :, 0], u[r, :, 1], acc[r, :, 0], acc[r, :, 1])
        for (quantity, unit, _field), values, limit in zip(_WHAT, series, lim.as_tuple(),
                                                           strict=True):
            if math.isinf(limit) or values.size == 0:
                continue
            t = int(np.argmax(np.abs(values)))
            ratio = abs(float(values[t])) / limit
            if ratio > 1.0 and (worst is None or ratio > worst.ratio):
                worst = Violation(r + 1, t, quantity, unit, abs(float(values[t])), limit,
                                  ratio)
    return worst


def scale_needed(u: NDArray[np.float64], dt: float, limits: list[Limits]) -> float:
    """The least time scale s >= 1 that brings u inside the limits if the plan is stretched
    in time by s (speeds scale by 1 / s, accelerations by 1 / s^2; the start from rest
    by 1 / s): an estimate for ``--time-scale``, to be checked on the stretched plan."""
    u = np.asarray(u, dtype=float)
    acc = input_rates(u, dt)
    need = 1.0
    for r, lim in enumerate(limits):
        v, w, a, al = lim.as_tuple()
        need = max(need, float(np.abs(u[r, :, 0]).max(initial=0.0)) / v,
                   float(np.abs(u[r, :, 1]).max(initial=0.0)) / w,
                   math.sqrt(float(np.abs(acc[r, 1:, 0]).max(initial=0.0)) / a),
                   math.sqrt(float(np.abs(acc[r, 1:, 1]).max(initial=0.0)) / al),
                   float(np.abs(acc[r, :1, 0]).max(initial=0.0)) / a,
                   float(np.abs(acc[r, :1, 1]).max(initial=0.0)) / al)
    return need


class RateLimiter:
    """Keeps one robot's commands inside its Limits, counting every clipped command.

    ``limit(v, omega, now)``: |v| and |omega| are clamped to the speed limits, then the
    change since the last command to what the accelerations allow in the time since it
    (``now`` [s], any monotonic clock). ``reset()`` forgets the last command (the robot
    is known to stand still).
    """

    def __init__(self, limits: Limits):
        self.limits = limits
        self.last: tuple[float, float] = (0.0, 0.0)
        self.last_time: float | None = None
        self.clipped_speed = 0
        self.clipped_accel = 0
        self.commands = 0

    def reset(self, now: float | None = None) -> None:
        self.last = (0.0, 0.0)
        self.last_time = now

    def limit(self, v: float, omega: float, now: float) -> tuple[float, float, bool]:
        """(v, omega, clipped)."""
        lim = self.limits
        self.commands += 1
        cv = min(max(v, -lim.v_max), lim.v_max)
        cw = min(max(omega, -lim.omega_max), lim.omega_max)
        speed_clip = cv != v or cw != omega
        accel_clip = False
        if self.last_time is not None:
            dt = max(now - self.last_time, 0.0)
            lv, lw = self.last
            av = min(max(cv, lv - lim.a_max * dt), lv + lim.a_max * dt)
            aw = min(max(cw, lw - lim.alpha_max * dt), lw + lim.alpha_max * dt)
            accel_clip = av != cv or aw != cw
            cv, cw = av, aw
        self.clipped_speed += speed_clip
        self.clipped_accel += accel_clip
        self.last = (cv, cw)
        self.last_time = now
        return cv, cw, speed_clip or accel_clip

    def counts(self) -> dict[str, int]:
        return {"commands": self.commands, "clipped_speed": self.clipped_speed,
                "clipped_accel": self.clipped_accel}
