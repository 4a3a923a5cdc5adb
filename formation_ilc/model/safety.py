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

from formation_ilc.config.safety import MARGIN, SafetySettings
from formation_ilc.config.scenario import Scenario
from formation_ilc.core.estimate import BOX
from formation_ilc.core.limits import Limits, input_rates
from formation_ilc.core.safety import CHANGED, OTHER_FIELDS, SafetySpec, filter_team
from formation_ilc.core.uncertainty import Uncertainty
from formation_ilc.model.footprint import Footprint, footprint_of

__all__ = ["MARGIN", "DISCS", "spec_for", "spec_of", "body_spec", "body_limits",
           "sensing_radius",
           "DesiredClearance", "desired_clearance", "MotionPeaks", "motion_peaks",
           "DesiredThroughFilter", "desired_through_filter", "what_fits", "TOLERANCE",
           "MotionFit", "motion_fit"]

#: discs that cover a body
DISCS = 2
#: [m] how far per axis a body's own motion over a sample may be from the arc of the
#: command it applied (wheel and motor dynamics, within its limits), on top of the
#: scenario's disturbance: the growth of a position's box each sample (``core.estimate``)
BODY_PROCESS = 0.002
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
             learning: str = "damped", stale_speed: float | None = None,
             radius: float | None = None, discs: int = DISCS,
             speed_uncertainty: float = 0.0, pose_error: float = 0.0,
             pose_jitter: float = 0.0, commands: bool = False,
             heading_error: float = 0.0, noise: float = 0.0,
             process: float = 0.0) -> SafetySpec:
    """The filter for robots of footprint ``fp`` on a base with ``limits`` at sample time
    ``dt`` [s]: ``discs`` discs cover the body; two robots' discs keep 2 radii + ``margin``
    apart, + ``pose_error`` [m] (how far the difference of two robots' measured positions
    may be from the true one); a pose of another robot that is ``age`` s old widens that by
    ``stale_speed`` (default: the speed limit) x age; robots beyond ``radius`` (default
    ``sensing_radius``) are not constrained.

    Another robot's motion is estimated from two of its poses ``window`` samples apart:
    one sample (no lag) when the poses are exact, more when they jitter by up to
    ``pose_jitter`` [m] from one sample to the next (the window that makes the estimate's
    worst error, a_max lag + jitter / (window dT), least); ``speed_uncertainty`` [m/s] is
    that jitter's part plus any given. With ``commands`` the robots tell each other the
    command they apply (``core.safety.told``): another robot's speed is known, and only its
    direction comes from its measured heading, off by up to ``heading_error`` [rad], and
    every robot's position is estimated from its poses and told commands
    (``core.estimate``: poses off by up to ``noise`` [m] per axis, the motion off the told
    command by up to ``process`` [m] per axis a sample), the distance widened by two
    estimates' bounds (at most ``pose_error``) instead of ``pose_error``."""
    offsets, r = fp.discs(discs)
    distance = 2.0 * r + margin
    if stale_speed is None:
        stale_speed = 0.0 if math.isinf(limits.v_max) else limits.v_max
    if radius is None:
        radius = sensing_radius(distance + pose_error, limits, dt)
    window = 1
    # a told command is the speed itself; only its direction comes from a pose, off by up
    # to ``heading_error``: the velocity by up to the speed limit x that angle's chord
    told = (0.0 if math.isinf(limits.v_max)
            else limits.v_max * 2.0 * math.sin(0.5 * min(heading_error, math.pi)))
    if pose_jitter > 0:
        a = limits.a_max if math.isfinite(limits.a_max) else 1.0
        window = max(1, min(10, round(math.sqrt(2.0 * pose_jitter / (a * dt * dt)))))
        speed_uncertainty += pose_jitter / (window * dt)
    return SafetySpec(offsets, distance, gamma=0.5, radius=radius, limits=limits, dt=dt,
                      stale_speed=stale_speed, weight=0.1, speed_uncertainty=speed_uncertainty,
                      window=window, brake_share=1.0, learning=learning, commands=commands,
                      told_uncertainty=told, pose_error=pose_error, noise=noise,
                      process=process, heading_error=heading_error)


def body_limits(body: str) -> Limits:
    """A body's own speed and acceleration limits: a physics model's (its maker's,
    ``model.physics.MODELS``), else the base preset's (``config.bases``)."""
    from formation_ilc.config.bases import base_preset
    from formation_ilc.model.physics import MODELS

    return MODELS[body].limits if body in MODELS else base_preset(body).limits


def spec_of(settings: SafetySettings, dt: float,
            noise: Uncertainty | None = None) -> SafetySpec:
    """The filter of a run's safety settings (``config.safety``) at sample time ``dt``,
    for poses measured with the output noise of ``noise`` (a scenario's uncertainty; None:
    exact poses, ``Uncertainty.pose_bounds``)."""
    error, jitter = (0.0, 0.0) if noise is None else noise.pose_bounds()
    heading = 0.0 if noise is None else noise.heading_bound()
    per_axis, process = (0.0, 0.0) if noise is None else noise.estimate_bounds(dt)
    return spec_for(footprint_of(settings.body), settings.limits, dt, margin=settings.margin,
                    learning=settings.learning, pose_error=error, pose_jitter=jitter,
                    commands=settings.motion == "commands", heading_error=heading,
                    noise=per_axis, process=process + BODY_PROCESS)


def body_spec(body: str, dt: float, noise: Uncertainty | None = None,
              motion: str = "poses") -> SafetySpec:
    """The filter ``body`` robots run by default (``check --base BODY`` judges a team by
    it): the base's one limits table, its default margin and learning reading, at sample
    time ``dt``, for poses as noisy as ``noise`` (None: exact)."""
    from formation_ilc.config.safety import default_learning, default_margin

    noisy = noise is not None and noise.pose_noise
    return spec_of(SafetySettings(body, body_limits(body), default_margin(body),
                                  default_learning(body, noisy), motion=motion), dt, noise)


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
        return DesiredClearance(math.inf, (1, 1), 0, spec.distance + spec.pose_error)
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
    return DesiredClearance(best[0], best[1], best[2], spec.distance + spec.pose_error)


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


@dataclass(frozen=True)
class DesiredThroughFilter:
    """Every robot's desired motion through the filter, no learning: how many commands it
    changed, the first (robot, sample) it changed, how far (|dv| [m/s], |domega| [rad/s]
    at the largest change), and the pair of robots nearest each other at that sample
    (1-based) and their distance [m] (tracked points); ``how``: the poses and speeds the
    filter had (exact or as noisy as the scenario's; speeds told or estimated)."""

    changed: int
    first: tuple[int, int] | None
    largest: tuple[float, float]
    nearest: tuple[int, int]
    nearest_distance: float
    how: str = "exact poses"

    @property
    def passes(self) -> bool:
        return self.changed == 0

    def line(self, dt: float) -> str:
        if self.first is None:
            return (f"the safety filter lets every robot's desired motion through unchanged "
                    f"({self.how})")
        r, t = self.first
        i, j = self.nearest
        return (f"the safety filter changes the desired motion itself ({self.how}): "
                f"{self.changed} commands, the first robot {r}'s at t = {t * dt:.1f} s (by "
                f"up to {self.largest[0]:.3f} m/s, {self.largest[1]:.3f} rad/s), where "
                f"robots {i} and {j} are {self.nearest_distance:.3f} m apart")


#: changes of a desired command this small [m/s, rad/s] are below what a base's velocity
#: loop holds: ``desired_through_filter`` lets them pass
TOLERANCE = (0.01, 0.01)


def desired_through_filter(sc: Scenario, spec: SafetySpec,
                           noisy: bool = False) -> DesiredThroughFilter:
    """Run every robot's desired command through the filter at its desired pose, each
    robot hearing the others' desired poses of the sample (age 0) as the batch simulator
    does, without learning: a formation whose own motion the filter changes is one the
    filter would fight in every trial (``check`` fails it). ``noisy``: every pose as the
    robots measure it, with the scenario's output noise (its first trial's draw, from its
    seed): the room the filter keeps for noise is then tried on the noise itself. Changes
    within ``TOLERANCE`` do not count."""
    d = sc.for_plant("arc").desired
    eta = np.ascontiguousarray(d.eta)
    noisy = noisy and sc.uncertainty.noisy
    if noisy:
        noise = sc.uncertainty.draw_plant(sc.seed, 0, eta.shape[0], d.u.shape[1])[2]
        eta = np.ascontiguousarray(eta + noise)
    n, n_t = d.u.shape[0], d.u.shape[1]
    u = np.array(d.u, dtype=float)
    nominal = np.empty_like(u)
    flags = np.zeros((n, n_t), dtype=np.int64)
    prev = np.zeros((n, 2))
    params = spec.params()
    others, ages, boxes = np.zeros((n, OTHER_FIELDS)), np.zeros(n), np.zeros((n, BOX))
    for t in range(n_t):
        filter_team.jit(t, u, eta, prev, 0.0, params, spec.window, nominal, flags, others, ages,
                        boxes)
        # each sample is judged on the desired motion alone: the next starts from the
        # desired command, not the filtered one
        prev[:] = d.u[:, t]
    diff = np.abs(u - d.u)
    changed = ((flags & CHANGED != 0)
               & ((diff[..., 0] > TOLERANCE[0]) | (diff[..., 1] > TOLERANCE[1])))
    count = int(changed.sum())
    how = ((f"poses as noisy as the scenario's (seed {sc.seed})" if noisy else "exact poses")
           + (", speeds told" if spec.commands else ", speeds from poses"))
    if count == 0:
        return DesiredThroughFilter(0, None, (0.0, 0.0), (1, 1), math.inf, how)
    rs, ts = np.nonzero(changed)
    k = int(np.argmin(ts))
    r, t = int(rs[k]), int(ts[k])
    worst = np.unravel_index(int(np.argmax(diff[..., 0] + spec.weight * diff[..., 1])),
                             diff.shape[:2])
    p = eta[:, t, :2]
    gap = np.hypot(p[:, None, 0] - p[None, :, 0], p[:, None, 1] - p[None, :, 1])
    gap[np.diag_indices(n)] = np.inf
    j = int(np.argmin(gap[r])) if n > 1 else r
    return DesiredThroughFilter(count, (r + 1, t), (float(diff[worst][0]),
                                                    float(diff[worst][1])),
                                (min(r, j) + 1, max(r, j) + 1), float(gap[r, j]), how)


def what_fits(sc: Scenario, spec: SafetySpec,
              noisy: bool = False) -> tuple[float | None, float | None]:
    """What would let a formation's desired motion through the filter (``noisy``: as
    ``desired_through_filter``): the least time scale (slower) of 1.25, 1.5, 2, 3, 4 that
    does, and the least spread of its offsets (wider) of 1.1, 1.25, 1.5, 2 that does; None
    for either where none does."""
    from dataclasses import replace

    scale = next((k for k in (1.25, 1.5, 2.0, 3.0, 4.0)
                  if desired_through_filter(sc.with_options(time_scale=sc.time_scale * k),
                                            spec, noisy).passes), None)
    spread = next((k for k in (1.1, 1.25, 1.5, 2.0)
                   if desired_through_filter(replace(sc, offsets=sc.offsets * k),
                                             spec, noisy).passes), None)
    return scale, spread


@dataclass(frozen=True)
class MotionFit:
    """What ``check --base BODY`` asks of a scenario's desired motion (``motion_fit``): the
    base's limits (one table, ``config.bases``), the line saying where the motion leaves
    them (None: it fits), the least distance of two robots' discs against the filter's,
    and the motion through the filter (None when the discs already come too close)."""

    body: str
    limits: Limits
    spec: SafetySpec
    limits_line: str | None
    clearance: DesiredClearance
    through: DesiredThroughFilter | None
    noisy: bool = False

    @property
    def fits(self) -> bool:
        return (self.limits_line is None and self.clearance.fits
                and self.through is not None and self.through.passes)


def motion_fit(sc: Scenario, body: str, noise: Uncertainty | None = None,
               motion: str | None = None) -> MotionFit:
    """``sc``'s desired motion (arc headings where 'auto') against ``body`` robots: inside
    the base's limits, its bodies kept the filter's distance apart, and let through the
    filter unchanged, for poses as noisy as ``noise`` (None: exact poses; else the filter
    keeps room for it, and is tried on the scenario's own noise), the other robots' speeds
    taken as ``motion`` says (default: as a launch of ``sc`` takes them,
    ``config.safety.default_motion``). The one test ``check --base`` and the generated
    families (``studies.families``) both apply."""
    from formation_ilc.config.bases import fit_limits
    from formation_ilc.config.safety import default_motion

    sc = sc.for_plant("arc")
    limits = body_limits(body)
    spec = body_spec(body, sc.dt, noise, motion or default_motion(sc.n))
    line = fit_limits(sc, [limits] * sc.n)
    clearance = desired_clearance(sc, spec)
    through = (desired_through_filter(sc, spec, noisy=noise is not None)
               if clearance.fits else None)
    return MotionFit(body, limits, spec, line, clearance, through, noise is not None)
