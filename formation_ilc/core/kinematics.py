"""Discrete unicycle (eq. 1/3) with input disturbance and output noise, batched over robots.

State xi = (x, y, theta) [m, m, rad], input u = (v, omega) [m/s, rad/s].
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit

__all__ = ["step", "step_into", "unicycle_step", "arc_step", "PLANT_MODELS", "rollout",
           "wrap_angle", "heading_from_quaternion", "quaternion_from_heading",
           "yaw_and_tilt"]


@njit(cache=True)
def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    two_pi = 2.0 * np.pi
    return a - two_pi * np.ceil((a - np.pi) / two_pi)


@njit(cache=True)
def unicycle_step(x: float, y: float, th: float, v: float, w: float, dt: float
                  ) -> tuple[float, float, float]:
    """One sample of eq. (1) for one robot: v, w the input plus its disturbance."""
    return x + dt * np.cos(th) * v, y + dt * np.sin(th) * v, th + dt * w


#: the batch simulator's plant models: 'euler' (eq. 1 as the paper writes it: the robot
#: drives straight along its heading for a whole sample, then turns) and 'arc' (a unicycle
#: that holds v and omega for the sample: it drives an arc, as a real base does)
PLANT_MODELS = ("euler", "arc")


@njit(cache=True)
def arc_step(x: float, y: float, th: float, v: float, w: float, dt: float
             ) -> tuple[float, float, float]:
    """One sample of the continuous unicycle under constant (v, w): the exact arc.

    Moves by the arc's chord, v dt sin(w dt / 2) / (w dt / 2), along th + w dt / 2 (the
    chord's direction); a turn below 1e-9 rad is a straight step.
    """
    half = 0.5 * w * dt
    scale = np.sin(half) / half if abs(half) > 1e-9 else 1.0
    d = v * dt * scale
    mid = th + half
    return x + d * np.cos(mid), y + d * np.sin(mid), th + w * dt


@njit(cache=True)
def step_into(
    xi: NDArray[np.float64],
    u: NDArray[np.float64],
    dist: NDArray[np.float64],
    dt: float,
    out: NDArray[np.float64],
) -> None:
    """One sample of eq. (1) for a batch, written into ``out``.

    xi : shape (R, 3); u, dist : shape (R, 2) [m/s, rad/s]; out : shape (R, 3).
    """
    for r in range(xi.shape[0]):
        out[r, 0], out[r, 1], out[r, 2] = unicycle_step(
            xi[r, 0], xi[r, 1], xi[r, 2], u[r, 0] + dist[r, 0], u[r, 1] + dist[r, 1], dt)


def step(
    xi: NDArray[np.float64],
    u: NDArray[np.float64],
    dt: float,
    dist: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """xi(t+1) = xi(t) + B[xi(t)] (u(t) + disturbance(t)).

    xi : ndarray, shape (..., 3); u, dist : ndarray, shape (..., 2). Returns shape (..., 3).
    """
    xi = np.asarray(xi, dtype=float)
    u = np.asarray(u, dtype=float)
    d = np.zeros_like(u) if dist is None else np.asarray(dist, dtype=float)
    v = u[..., 0] + d[..., 0]
    out = np.empty(np.broadcast_shapes(xi.shape, u.shape[:-1] + (3,)))
    out[..., 0] = xi[..., 0] + dt * np.cos(xi[..., 2]) * v
    out[..., 1] = xi[..., 1] + dt * np.sin(xi[..., 2]) * v
    out[..., 2] = xi[..., 2] + dt * (u[..., 1] + d[..., 1])
    return out


def rollout(
    xi0: NDArray[np.float64],
    u: NDArray[np.float64],
    dt: float,
    dist: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Open-loop trajectory.

    xi0 : shape (R, 3); u : shape (R, T, 2). Returns xi, shape (R, T+1, 3).
    """
    xi0 = np.atleast_2d(np.asarray(xi0, dtype=float))
    u = np.asarray(u, dtype=float)
    n_t = u.shape[1]
    xi = np.empty((xi0.shape[0], n_t + 1, 3))
    xi[:, 0] = xi0
    for t in range(n_t):
        xi[:, t + 1] = step(xi[:, t], u[:, t], dt, None if dist is None else dist[:, t])
    return xi


def quaternion_from_heading(theta: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by theta about z."""
    return 0.0, 0.0, float(np.sin(0.5 * theta)), float(np.cos(0.5 * theta))


def heading_from_quaternion(z: float, w: float, previous: float | None = None) -> float:
    """Heading of a yaw-only quaternion; unwrapped next to ``previous`` when given."""
    th = 2.0 * float(np.arctan2(z, w))
    if previous is None:
        return float(wrap_angle(th))
    return previous + float(wrap_angle(th - previous))


def yaw_and_tilt(x: float, y: float, z: float, w: float) -> tuple[float, float]:
    """(yaw, tilt) [rad] of any rotation quaternion (x, y, z, w), normalised first.

    yaw : where the body's x axis points, seen from above (ZYX Euler yaw: the heading of a
    base on a slope or with a little roll). tilt : the angle between the body's z axis and
    the vertical, whatever the mix of roll and pitch. ValueError for a quaternion that is
    not finite or of zero length.
    """
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not math.isfinite(n) or n < 1e-9:
        raise ValueError("orientation is not a rotation (zero or non-finite quaternion)")
    x, y, z, w = x / n, y / n, z / n, w / n
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    zz = 1.0 - 2.0 * (x * x + y * y)  # the body's z axis, its vertical component
    return yaw, math.acos(max(-1.0, min(1.0, zz)))
