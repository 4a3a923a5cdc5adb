"""Where a robot is, from noisy poses and the commands it told: a box of positions.

A robot's measured position is its true one plus noise bounded per axis by ``b`` (the
scenario's uniform half-widths; the harmonics every robot's noise shares shift all robots
alike, move two robots' distance not at all, and are tracked as part of the position).
Between two samples a robot moves as the command it applied over the sample says (an arc
of v and omega held for dT, from its measured heading), to within ``q`` per axis: its
plant's disturbance, its heading's noise, the shared harmonic's step and what its body
adds (``process_bound``). The positions consistent with every pose so far then form a box
(set-membership estimation, the bounded-noise counterpart of a Kalman filter): moved by
the told command and grown by ``q``, then cut by the new pose's box [z - b, z + b]. Its
centre is the estimate; its half-diagonal bounds how far the estimate is from the truth,
never more than a single pose's hypot(b, b), and with uniform noise about half of that
once a few samples are in. A pose the box misses (the robot did not move as it told:
slip, a push, a wrong bound) starts the box afresh from that pose, and is counted.

The safety filter (``core.safety``) keeps two robots' discs apart by its distance plus
their two half-diagonals, on the two centres, where a fixed widening of 2 hypot(b, b) on
the raw poses held every pair off by the noise's worst case at every sample, and moved
the distance it judged from sample to sample by as much.

A box is four numbers (x_lo, x_hi, y_lo, y_hi) [m] in a row of an array; no state else.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit
from formation_ilc.core.kinematics import arc_step

__all__ = ["box_start", "box_step", "box_centre", "box_error", "process_bound", "BOX"]

#: the columns of a box: x_lo, x_hi, y_lo, y_hi [m]
BOX = 4


@njit(cache=True)
def box_start(box: NDArray[np.float64], r: int, zx: float, zy: float, b: float) -> None:
    """Row ``r`` of ``box``: the positions one pose (zx, zy) allows, noise ``b`` per axis."""
    box[r, 0] = zx - b
    box[r, 1] = zx + b
    box[r, 2] = zy - b
    box[r, 3] = zy + b


@njit(cache=True)
def box_step(box: NDArray[np.float64], r: int, th: float, v: float, w: float, dt: float,
             zx: float, zy: float, b: float, q: float, heading_error: float) -> bool:
    """Row ``r`` of ``box`` one sample on: moved by the arc of (v, w) held for ``dt`` from
    heading ``th``, grown by ``process_bound`` (``q`` and the heading's ``heading_error``),
    then cut by the pose (zx, zy) with noise ``b``. False: the pose lay outside the moved box (the
    robot did not move as told), and the box starts afresh from the pose."""
    x1, y1, _ = arc_step(0.0, 0.0, th, v, w, dt)
    q = process_bound(q, heading_error, v, w, dt)
    lo_x = box[r, 0] + x1 - q
    hi_x = box[r, 1] + x1 + q
    lo_y = box[r, 2] + y1 - q
    hi_y = box[r, 3] + y1 + q
    lo_x = max(lo_x, zx - b)
    hi_x = min(hi_x, zx + b)
    lo_y = max(lo_y, zy - b)
    hi_y = min(hi_y, zy + b)
    if lo_x > hi_x or lo_y > hi_y:
        box_start(box, r, zx, zy, b)
        return False
    box[r, 0] = lo_x
    box[r, 1] = hi_x
    box[r, 2] = lo_y
    box[r, 3] = hi_y
    return True


@njit(cache=True)
def box_centre(box: NDArray[np.float64], r: int) -> tuple[float, float]:
    """The estimate: the centre of row ``r``."""
    return 0.5 * (box[r, 0] + box[r, 1]), 0.5 * (box[r, 2] + box[r, 3])


@njit(cache=True)
def box_error(box: NDArray[np.float64], r: int) -> float:
    """How far the centre of row ``r`` can be from the true position [m]: its half-diagonal."""
    return 0.5 * math.hypot(box[r, 1] - box[r, 0], box[r, 3] - box[r, 2])


@njit(cache=True)
def process_bound(q: float, heading_error: float, v: float, w: float, dt: float) -> float:
    """How far per axis [m] a robot's position after a sample of (v, w) can be from the arc
    its told command draws: ``q`` (its disturbance, the shared noise's step, its body's
    own), its heading known to ``heading_error`` [rad] (the arc turned by that much), and
    a plant that steps along the heading (eq. 1 as the paper writes it) instead of the
    arc's chord (half a sample's turn)."""
    return q + abs(v) * dt * (heading_error + 0.5 * abs(w) * dt)
