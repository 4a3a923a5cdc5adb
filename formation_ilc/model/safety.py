"""The safety filter of a team: its body, its limits, and what the desired motion asks.

``core.safety`` is the filter itself (numbers in, a command out). This module builds its
``SafetySpec`` for a body (``footprint``: two discs cover it) and a base's limits, and
checks a scenario against it before anything runs:

* ``desired_clearance``: the least distance between the discs of two robots on their
  desired paths, against the filter's distance: a formation tighter than its robots'
  bodies plus the margin cannot be flown, and the filter would fight it in every trial;
* ``motion_peaks``: each robot's peak desired speed, turn rate, accelerations and the
  largest jump of its desired position between two samples, for ``check`` and the
  refusals of the plants with bodies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.safety import SafetySettings
from formation_ilc.config.scenario import Scenario
from formation_ilc.core.limits import Limits, input_rates
from formation_ilc.core.safety import SafetySpec
from formation_ilc.model.footprint import Footprint, footprint_of

__all__ = ["MARGIN", "DISCS", "spec_for", "spec_of", "body_limits", "sensing_radius",
           "DesiredClearance", "desired_clearance", "MotionPeaks", "motion_peaks"]

#: [m] added to two disc radii: the least gap the filter keeps between two bodies'
#: covering discs (it covers the discs' excess over the rectangle, the arcs a robot drives
#: within a sample and the poses' noise)
MARGIN = 0.1
#: discs that cover a body
DISCS = 2
#: [m] the farthest the filter looks when a base has no speed or acceleration limit
MAX_RADIUS = 10.0


def sensing_radius(distance: float, limits: Limits, dt: float) -> float:
    """The distance [m] between two robots beyond which no barrier of the filter can bind:
    two robots at full speed, each able to stop within half of what is left
    (distance + 2 (v_max dT + v_max^2 / (2 a_max))), at most MAX_RADIUS."""
    v, a = limits.v_max, limits.a_max
    if math.isinf(v) or math.isinf(a):
        return MAX_RADIUS
    return min(MAX_RADIUS, distance + 2.0 * (v * dt + v * v / (2.0 * a)))


def spec_for(fp: Footprint, limits: Limits, dt: float, *, margin: float = MARGIN,
             learning: str = "applied", stale_speed: float | None = None,
             radius: float | None = None, discs: int = DISCS,
             speed_uncertainty: float = 0.0) -> SafetySpec:
    """The filter for robots of footprint ``fp`` on a base with ``limits`` at sample time
    ``dt`` [s]: ``discs`` discs cover the body; two robots' discs keep 2 radii + ``margin``
    apart; a pose of another robot that is ``age`` s old widens that by ``stale_speed``
    (default: the speed limit) x age; robots beyond ``radius`` (default
    ``sensing_radius``) are not constrained."""
    offsets, r = fp.discs(discs)
    distance = 2.0 * r + margin
    if stale_speed is None:
        stale_speed = 0.0 if math.isinf(limits.v_max) else limits.v_max
    if radius is None:
        radius = sensing_radius(distance, limits, dt)
    return SafetySpec(offsets, distance, gamma=1.0, radius=radius, limits=limits, dt=dt,
                      stale_speed=stale_speed, weight=0.1, speed_uncertainty=speed_uncertainty,
                      window=3, brake_share=1.0, learning=learning)


def body_limits(body: str) -> Limits:
    """A body's own speed and acceleration limits: a physics model's (its maker's,
    ``model.physics.MODELS``), else the base preset's (``config.bases``)."""
    from formation_ilc.config.bases import base_preset
    from formation_ilc.model.physics import MODELS

    return MODELS[body].limits if body in MODELS else base_preset(body).limits


def spec_of(settings: SafetySettings, dt: float) -> SafetySpec:
    """The filter of a run's safety settings (``config.safety``) at sample time ``dt``."""
    return spec_for(footprint_of(settings.body), settings.limits, dt, margin=settings.margin,
                    learning=settings.learning)


@dataclass(frozen=True)
class DesiredClearance:
    """The least distance between two robots' discs on their desired paths [m], which
    robots (1-based) and when (sample), against the filter's ``distance``."""

    value: float
    robots: tuple[int, int]
    sample: int
    distance: float

    @property
    def fits(self) -> bool:
        return self.value >= self.distance

    def line(self, dt: float) -> str:
        i, j = self.robots
        return (f"the desired formation brings robots {i} and {j} to {self.value:.3f} m "
                f"(centres of the discs that cover their bodies) at t = {self.sample * dt:.1f} "
                f"s; the safety filter keeps {self.distance:.3f} m")


def desired_clearance(sc: Scenario, spec: SafetySpec) -> DesiredClearance:
    """The least distance between any two robots' covering discs along their desired
    poses (N >= 2; otherwise infinite)."""
    eta = sc.desired.eta
    n = eta.shape[0]
    if n < 2:
        return DesiredClearance(math.inf, (1, 1), 0, spec.distance)
    off = np.asarray(spec.discs)
    c, s = np.cos(eta[..., 2]), np.sin(eta[..., 2])
    # disc centres (N, T+1, K, 2)
    cx = eta[..., 0, None] + off * c[..., None]
    cy = eta[..., 1, None] + off * s[..., None]
    best = (math.inf, (1, 1), 0)
    for i in range(n):
        for j in range(i + 1, n):
            d = np.hypot(cx[i][:, :, None] - cx[j][:, None, :],
                         cy[i][:, :, None] - cy[j][:, None, :]).min(axis=(1, 2))
            t = int(np.argmin(d))
            if d[t] < best[0]:
                best = (float(d[t]), (i + 1, j + 1), t)
    return DesiredClearance(best[0], best[1], best[2], spec.distance)


@dataclass(frozen=True)
class MotionPeaks:
    """One robot's peaks along its desired motion: speed [m/s], turn rate [rad/s],
    acceleration [m/s^2], angular acceleration [rad/s^2] (from rest into sample 0, then
    sample to sample), and the largest step of its desired position between two samples
    [m], each with its sample."""

    robot: int
    speed: tuple[float, int]
    turn_rate: tuple[float, int]
    acceleration: tuple[float, int]
    angular_acceleration: tuple[float, int]
    jump: tuple[float, int]

    def line(self, dt: float) -> str:
        def at(x: tuple[float, int], unit: str) -> str:
            return f"{x[0]:.3g} {unit} (t = {x[1] * dt:.1f} s)"
        return (f"robot {self.robot}: peak speed {at(self.speed, 'm/s')}, turn rate "
                f"{at(self.turn_rate, 'rad/s')}, acceleration {at(self.acceleration, 'm/s^2')}, "
                f"angular acceleration {at(self.angular_acceleration, 'rad/s^2')}, largest "
                f"step {at(self.jump, 'm')}")


def motion_peaks(sc: Scenario) -> list[MotionPeaks]:
    """Each robot's peaks of its desired motion (``MotionPeaks``)."""
    d = sc.desired
    u: NDArray[np.float64] = d.u
    acc = input_rates(u, sc.dt)
    steps = np.hypot(*np.diff(d.eta[..., :2], axis=1).transpose(2, 0, 1))
    out = []

    def peak(x: NDArray[np.float64]) -> tuple[float, int]:
        if x.size == 0:
            return 0.0, 0
        t = int(np.argmax(np.abs(x)))
        return float(abs(x[t])), t

    for r in range(u.shape[0]):
        out.append(MotionPeaks(r + 1, peak(u[r, :, 0]), peak(u[r, :, 1]), peak(acc[r, :, 0]),
                               peak(acc[r, :, 1]), peak(steps[r])))
    return out
