"""References r(t), formation offsets d_i(t), and desired trajectories that satisfy Assumption 1.

Time is the sample index t = 0..T (t * dt seconds). Every reference is sampled on t = 0..T+1:
the extra sample gives the path tangent at t = T.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Sinusoid",
    "paper_lemniscate",
    "paper_ivb_speed",
    "unicycle_reference",
    "sampled_reference",
    "waypoint_reference",
    "path_headings",
    "path_headings_signed",
    "formation_positions",
    "Desired",
    "desired_trajectories",
    "HEADINGS",
    "arc_headings",
]

#: how desired headings are read from a path (``desired_trajectories``): 'chord', the
#: direction of each sample's step (exact for the Euler model that ``simulate`` steps), or
#: 'arc', the heading at the start of each sample's arc (exact for a robot that turns while
#: it drives: any real base, a physics engine)
HEADINGS = ("chord", "arc")


@dataclass(frozen=True)
class Sinusoid:
    """value(t) = mean + amplitude * sin(2 pi t / period + phase); t in seconds.

    period <= 0 (or amplitude 0) gives the constant ``mean``.
    """

    mean: float = 1.0
    amplitude: float = 0.0
    period: float = 0.0
    phase: float = 0.0

    def __call__(self, seconds: NDArray[np.float64]) -> NDArray[np.float64]:
        s = np.asarray(seconds, dtype=float)
        if self.period <= 0 or self.amplitude == 0:
            return np.full(s.shape, self.mean)
        return self.mean + self.amplitude * np.sin(2 * np.pi * s / self.period + self.phase)


@dataclass(frozen=True)
class AxisScales:
    """An offset scaled along each of its axes by a scale of its own: value(t) has shape
    (..., 2), (x(t), y(t)). A robot that keeps its place along the leader's heading and
    moves across from one side to the other (x constant, y swinging) is one."""

    x: Sinusoid
    y: Sinusoid

    def __call__(self, seconds: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.stack([self.x(seconds), self.y(seconds)], axis=-1)


def path_headings(p: NDArray[np.float64], fallback: float = 0.0,
                  reverse: bool = False) -> NDArray[np.float64]:
    """Unwrapped tangent headings of a sampled path (paper-notes 3-4).

    p : ndarray, shape (M, 2), M >= 2. Returns shape (M-1,): heading of the step t -> t+1.
    A step of zero length keeps the heading of the nearest moving step (the path stands
    still, the robot does not turn). With ``reverse``, see ``path_headings_signed``.
    """
    return path_headings_signed(p, fallback)[0] if reverse else _tangent(p, fallback)


def _tangent(p: NDArray[np.float64], fallback: float) -> NDArray[np.float64]:
    d = np.diff(np.asarray(p, dtype=float), axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    scale = max(float(length.max(initial=0.0)), 1e-300)
    moving = length > 1e-12 * scale
    th = np.arctan2(d[:, 1], d[:, 0])
    if not moving.any():
        return np.full(len(d), fallback)
    idx = np.flatnonzero(moving)
    # nearest moving step: forward fill, then back fill the leading stand-still
    fill = np.maximum.accumulate(np.where(moving, np.arange(len(d)), -1))
    fill[fill < 0] = idx[0]
    return np.unwrap(th[fill])


def path_headings_signed(p: NDArray[np.float64], fallback: float = 0.0
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Headings of a path a unicycle may also drive backwards, and the sign of each step.

    A unicycle tracks a step either facing it (v > 0) or backing along it (v < 0). Facing
    every step turns a robot on the spot by pi wherever its path doubles back, e.g. when a
    formation shrinks faster than a standing-start leader moves (paper-triangle3, t = 0):
    here the heading is anchored on the longest step and every other step takes the branch
    (theta or theta + pi) nearest its neighbour's heading, so the robot backs up instead.

    Returns theta, shape (M-1,), unwrapped, and sign, shape (M-1,), in {-1, +1}.
    """
    raw = _tangent(p, fallback)
    m = len(raw)
    theta = raw.copy()
    sign = np.ones(m)
    anchor = int(np.argmax(np.hypot(*np.diff(np.asarray(p, dtype=float), axis=0).T)))
    order = list(range(anchor + 1, m)) + list(range(anchor - 1, -1, -1))
    for k in order:
        prev = theta[k - 1] if k > anchor else theta[k + 1]
        base = prev + (raw[k] - prev + np.pi) % (2 * np.pi) - np.pi  # raw, unwrapped near prev
        alt = prev + (raw[k] + np.pi - prev + np.pi) % (2 * np.pi) - np.pi
        if abs(alt - prev) < abs(base - prev):
            theta[k], sign[k] = alt, -1.0
        else:
            theta[k] = base
    return theta, sign


def paper_lemniscate(n_samples: int, dt: float, ax: float = 7.5, ay: float = 10.0,
                     period: float = 45.0) -> NDArray[np.float64]:
    """Sec. IV.A reference: x = ax sin(2 pi t dt / P), y = ay sin(4 pi t dt / P).

    Returns r, shape (n_samples, 3): x, y and the unwrapped tangent heading (atan2, not the
    paper's arctan of a ratio, paper-notes 4).
    """
    t = np.arange(n_samples + 1) * dt
    xy = np.stack([ax * np.sin(2 * np.pi * t / period), ay * np.sin(4 * np.pi * t / period)], 1)
    return np.column_stack([xy[:-1], path_headings(xy)])


def paper_ivb_speed(t: NDArray[np.float64]) -> NDArray[np.float64]:
    """Sec. IV.B leader speed v0(t) [m/s], t the sample index (dt = 0.2 s), erratum 5 fixed."""
    t = np.asarray(t, dtype=float)
    ramp_up = 0.35 * (16 - (t * 0.2 - 4) ** 2) / 16
    ramp_down = 0.35 * (16 - (t * 0.2 - 24) ** 2) / 16
    # past t = 140 the leader stays stopped (the ramp would turn negative)
    return np.maximum(np.where(t <= 20, ramp_up, np.where(t < 120, 0.35, ramp_down)), 0.0)


def unicycle_reference(v: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                       w: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                       n_samples: int, dt: float,
                       start: tuple[float, float, float] = (0.0, 0.0, 0.0),
                       substeps: int = 32) -> NDArray[np.float64]:
    """The path of a continuous-time unicycle driven by v(t), w(t), sampled at t = 0..M-1.

    v, w : callables of the (fractional) sample index t, [m/s] and [rad/s], elementwise on
    arrays. The leader is virtual, so it moves in continuous time: integrating it with one
    Euler step per sample would keep it still for a whole sample after a standing start
    (v(0) = 0) and the formation's first step would then be pure shape change, sideways or
    backwards. Classical RK4 with ``substeps`` steps per sample. Returns r, shape (M, 3).

    Since v and w depend on time only, every RK4 stage of the heading is known in advance
    and the position's stages follow from the headings: the steps are computed as arrays
    and summed in order (``np.add.accumulate``), the same floating-point operations as a
    step-by-step loop (``_unicycle_reference_loop``, which the tests compare bit for bit),
    in chunks of bounded memory, about 1000 times faster.
    """
    r = np.empty((n_samples, 3))
    r[0] = start
    h = 1.0 / substeps
    s_ = np.array(r[0], dtype=float)
    j = np.arange(substeps)
    per_chunk = max(1, 65536 // substeps)

    def at(f: Callable[[NDArray[np.float64]], NDArray[np.float64]],
           t: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.broadcast_to(np.asarray(f(t), dtype=float), t.shape)

    for k0 in range(0, n_samples - 1, per_chunk):
        k = np.arange(k0, min(n_samples - 1, k0 + per_chunk))
        t = (k[:, None] + j[None, :] * h).ravel()  # as the loop: k + j * h
        v1, v2, v4 = at(v, t), at(v, t + h / 2), at(v, t + h)
        w1, w2, w4 = dt * at(w, t), dt * at(w, t + h / 2), dt * at(w, t + h)
        # heading: its stages depend on t only
        inc = h / 6 * (w1 + 2 * w2 + 2 * w2 + w4)
        th = np.add.accumulate(np.concatenate([[s_[2]], inc]))
        th0 = th[:-1]
        th2 = th0 + h / 2 * w1
        th3 = th0 + h / 2 * w2
        th4 = th0 + h * w2
        out = [th[substeps::substeps]]
        for c, fn in ((0, np.cos), (1, np.sin)):
            k1 = dt * (fn(th0) * v1)
            k2 = dt * (fn(th2) * v2)
            k3 = dt * (fn(th3) * v2)
            k4 = dt * (fn(th4) * v4)
            pos = np.add.accumulate(np.concatenate([[s_[c]], h / 6 * (k1 + 2 * k2 + 2 * k3
                                                                       + k4)]))
            out.insert(c, pos[substeps::substeps])
            s_[c] = pos[-1]
        s_[2] = th[-1]
        r[k + 1, 0], r[k + 1, 1], r[k + 1, 2] = out
    return r


def _unicycle_reference_loop(v: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                             w: Callable[[NDArray[np.float64]], NDArray[np.float64]],
                             n_samples: int, dt: float,
                             start: tuple[float, float, float] = (0.0, 0.0, 0.0),
                             substeps: int = 32) -> NDArray[np.float64]:
    """``unicycle_reference`` step by step (the reference implementation it is tested
    against; 1.5 ms per sample)."""
    r = np.empty((n_samples, 3))
    r[0] = start
    h = 1.0 / substeps

    def f(t: float, s: NDArray[np.float64]) -> NDArray[np.float64]:
        vt = float(v(np.asarray(t)))
        return dt * np.array([np.cos(s[2]) * vt, np.sin(s[2]) * vt, float(w(np.asarray(t)))])

    s_ = r[0].copy()
    for k in range(n_samples - 1):
        for j in range(substeps):
            t = k + j * h
            k1 = f(t, s_)
            k2 = f(t + h / 2, s_ + h / 2 * k1)
            k3 = f(t + h / 2, s_ + h / 2 * k2)
            k4 = f(t + h, s_ + h * k3)
            s_ = s_ + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        r[k + 1] = s_
    return r


def sampled_reference(xy: NDArray[np.float64], n_samples: int,
                      heading: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """A user-given sampled path, shape (M, 2), M >= n_samples - 1.

    A path one sample short is extended linearly. Without ``heading`` the tangent is used.
    """
    xy = np.asarray(xy, dtype=float)
    if len(xy) < 2:
        raise ValueError("a sampled reference needs at least 2 points")
    if len(xy) < n_samples - 1:
        raise ValueError(f"a sampled reference needs {n_samples - 1} points, got {len(xy)}")
    if len(xy) == n_samples - 1:
        xy = np.vstack([xy, 2 * xy[-1] - xy[-2]])
    xy = xy[:n_samples]
    ext = np.vstack([xy, 2 * xy[-1] - xy[-2]])
    th = path_headings(ext) if heading is None else np.asarray(heading, dtype=float)[:n_samples]
    return np.column_stack([xy, th])


def waypoint_reference(times: NDArray[np.float64], xy: NDArray[np.float64], n_samples: int,
                       dt: float) -> NDArray[np.float64]:
    """Piecewise-linear path through waypoints at given times [s], sampled at dt.

    Corners are exactly trackable in discrete time (a large omega for one sample).
    """
    times = np.asarray(times, dtype=float)
    xy = np.asarray(xy, dtype=float)
    t = np.arange(n_samples) * dt
    pts = np.column_stack([np.interp(t, times, xy[:, 0]), np.interp(t, times, xy[:, 1])])
    return sampled_reference(pts, n_samples)


def formation_positions(
    reference: NDArray[np.float64],
    base: NDArray[np.float64],
    scales: list[Callable[[NDArray[np.float64]], NDArray[np.float64]]],
    dt: float,
    frame: str,
    times: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Desired positions r(t) + d_i(t), shape (n, M, 2).

    reference : shape (M, 3) (x, y, heading). base : shape (n, 2), the offset of each robot
    at scale 1 in the world frame or in the leader's body frame (x ahead, y left).
    scales : one callable per robot, seconds -> scale factor (s(t), D1(t), ...), shape
        (M,), or one factor per axis, shape (M, 2) (``AxisScales``).
    times : shape (M,), the seconds the scales are read at (default t * dt; a ramped
        start's warped seconds).
    """
    m = reference.shape[0]
    sec = np.arange(m, dtype=float) * dt if times is None else np.asarray(times, dtype=float)
    s = np.stack([np.broadcast_to(np.reshape(f(sec), (m, -1)), (m, 2)) for f in scales])
    d = s * np.asarray(base, dtype=float)[:, None, :]  # (n, M, 2)
    if frame == "leader":
        c, sn = np.cos(reference[:, 2]), np.sin(reference[:, 2])
        d = np.stack([c * d[..., 0] - sn * d[..., 1], sn * d[..., 0] + c * d[..., 1]], -1)
    elif frame != "world":
        raise ValueError(f"frame must be 'world' or 'leader', got {frame!r}")
    return reference[None, :, :2] + d


@dataclass(frozen=True)
class Desired:
    """Desired outputs and inputs (Assumption 1) for n robots over t = 0..T.

    eta : shape (n, T+1, 3) [m, m, rad], headings unwrapped.
    u : shape (n, T, 2) [m/s, rad/s]; replaying u from eta[:, 0] reproduces eta.
    reference : shape (T+1, 3), the leader's r(t).
    """

    eta: NDArray[np.float64]
    u: NDArray[np.float64]
    reference: NDArray[np.float64]

    @property
    def xi0(self) -> NDArray[np.float64]:
        return self.eta[:, 0]


def arc_headings(chord: NDArray[np.float64]) -> NDArray[np.float64]:
    """Headings at the start of each sample's arc from the chord headings.

    chord : shape (n, T+1), unwrapped direction of each step t -> t+1. A unicycle that turns
    by d at a constant rate while it drives from p(t) to p(t+1) starts the arc at the chord
    direction minus d / 2; d is taken as the change of chord direction from the step before
    (the step after at t = 0). Returns shape (n, T+1).
    """
    c = np.asarray(chord, dtype=float)
    turn = np.empty_like(c)
    turn[:, 1:] = np.diff(c, axis=1)
    turn[:, 0] = turn[:, 1] if c.shape[1] > 1 else 0.0
    return c - 0.5 * turn


def desired_trajectories(positions: NDArray[np.float64], dt: float,
                         reference: NDArray[np.float64], headings: str = "chord") -> Desired:
    """Headings from each robot's own path and the unique u_d of Assumption 1.

    positions : shape (n, T+2, 2), desired positions on t = 0..T+1.
    reference : shape (T+2, 3).
    headings : 'chord' (default: u_d replayed through the Euler model of eq. 1 reproduces
        eta) or 'arc' (``arc_headings``; v is the arc's length over dt: u_d replayed through
        the exact-arc unicycle, ``kinematics.arc_step``, reproduces eta to within a quarter
        of the change of turn per sample, the second difference of the chord headings).
    """
    if headings not in HEADINGS:
        raise ValueError(f"headings must be one of {', '.join(HEADINGS)}, got {headings!r}")
    p = np.asarray(positions, dtype=float)
    n, m, _ = p.shape
    steps = np.diff(p, axis=1)  # (n, T+1, 2)
    # headings of the steps inside the trial (t = 0..T-1); the heading at t = T is not
    # tied to any step of the trial, so it continues the last turn rate: taking the tangent
    # of a step past the trial would turn a robot sideways where the leader stops and only
    # the formation's shape still changes (paper-triangle3, t = 140)
    signed = [path_headings_signed(p[i, :-1], fallback=float(reference[0, 2]))
              for i in range(n)]
    theta = np.stack([h for h, _ in signed])  # (n, T)
    theta = np.concatenate([theta, 2 * theta[:, -1:] - theta[:, -2:-1]], axis=1)  # (n, T+1)
    sign = np.stack([sg for _, sg in signed])
    chord_len = np.hypot(steps[:, :-1, 0], steps[:, :-1, 1])
    if headings == "arc":
        theta = arc_headings(theta)
        half = 0.5 * np.diff(theta, axis=1)  # half the turn of each sample's arc
        # an arc of turn 2h is longer than its chord by h / sin(h)
        with np.errstate(invalid="ignore", divide="ignore"):
            stretch = np.where(np.abs(half) > 1e-9, half / np.sin(half), 1.0)
        chord_len = chord_len * stretch
    eta = np.concatenate([p[:, :-1], theta[..., None]], axis=-1)  # (n, T+1, 3)
    v = sign * chord_len / dt
    w = np.diff(theta, axis=1) / dt
    u = np.stack([v, w], axis=-1)
    return Desired(eta=eta, u=u, reference=np.asarray(reference, dtype=float)[: m - 1])
