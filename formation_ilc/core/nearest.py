"""The command nearest to the wish: the last step of the safety filter (``core.safety``).

The filter's feasible set is the box of the base's limits cut by the pairs' half-planes
(``core.barrier``), a convex polygon in the scaled command plane (v, c omega), where the
cost (v - v_n)^2 + c^2 (omega - omega_n)^2 is Euclidean: the answer is the wish if it lies
inside, else the nearest point of the polygon's boundary (polygon clipping; no solver, no
iteration, exact to round-off).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import floats, njit
from formation_ilc.core.barrier import Numbers, Reach, Wish, _clip

__all__ = ["nearest_to_wish"]

_TOL = 1e-12
#: the flags ``nearest_to_wish`` adds when nothing keeps every barrier (``core.safety``'s
#: CHANGED_BARRIER | INFEASIBLE)
_BRAKED = 2 | 4


@njit(cache=True)
def nearest_to_wish(k: Numbers, r: Reach, w: Wish, ha0: NDArray[np.float64],
                    ha1: NDArray[np.float64], hb: NDArray[np.float64], m: int, flags: int,
                    out: NDArray[np.float64]) -> int:
    """The command nearest to the wish (w.zx, w.zy) inside the box of ``r`` cut by the
    first m half-planes ha0 v + ha1 (c w) >= hb, into ``out`` (v, omega); where nothing in
    the box keeps every barrier, the braking command (r.vb, r.wb), and ``flags`` gains
    CHANGED_BARRIER | INFEASIBLE. Returns the flags."""
    c = k.c
    # the planes read as Python numbers where this runs plain (``_jit.floats``)
    bx, by, ok = _nearest(w.zx, w.zy, r.v_lo, r.v_hi, c * r.w_lo, c * r.w_hi,
                          floats(ha0[:m]), floats(ha1[:m]), floats(hb[:m]), m)
    if not ok:  # nothing in the box keeps every barrier (a slack used up): brake
        out[0] = r.vb
        out[1] = r.wb
        return flags | _BRAKED
    out[0] = _clip(bx, r.v_lo, r.v_hi)
    out[1] = _clip(by / c, r.w_lo, r.w_hi)
    return flags


@njit(cache=True)
def _clip_polygon(px: NDArray[np.float64], py: NDArray[np.float64], n: int, a0: float,
                  a1: float, b: float, qx: NDArray[np.float64],
                  qy: NDArray[np.float64]) -> int:
    """The convex polygon (px, py)[:n] cut by the half-plane a0 x + a1 y >= b, into
    (qx, qy); returns its vertex count (0: empty)."""
    m = 0
    # Python floats: interpreted (the nodes), arithmetic on numpy scalars costs 3x; each
    # vertex read once (the edge from vertex k to k + 1 starts where the one before ended)
    a0, a1, b = float(a0), float(a1), float(b)
    fx, fy = float(px[0]), float(py[0])
    x1, y1 = fx, fy
    s1 = a0 * x1 + a1 * y1 - b
    for k in range(n):
        x0, y0, s0 = x1, y1, s1
        x1, y1 = (float(px[k + 1]), float(py[k + 1])) if k + 1 < n else (fx, fy)
        s1 = a0 * x1 + a1 * y1 - b
        if s0 >= 0.0:
            qx[m] = x0
            qy[m] = y0
            m += 1
        if (s0 >= 0.0) != (s1 >= 0.0):
            f = s0 / (s0 - s1)
            qx[m] = x0 + f * (x1 - x0)
            qy[m] = y0 + f * (y1 - y0)
            m += 1
    return m


@njit(cache=True)
def _nearest(zx: float, zy: float, bx0: float, bx1: float, by0: float, by1: float,
             ha0: NDArray[np.float64], ha1: NDArray[np.float64], hb: NDArray[np.float64],
             m: int) -> tuple[float, float, bool]:
    """The nearest point to (zx, zy) of the box [bx0, bx1] x [by0, by1] cut by the first
    m half-planes ha0 x + ha1 y >= hb (arrays, or their ``_jit.floats``), and whether there
    is one. Most often one barrier binds: the nearest point of the box cut by that one
    half-plane is the answer when it keeps every other (the feasible set lies inside that
    cut box); else the box is clipped by every half-plane (exact)."""
    bx, by = _clip(zx, bx0, bx1), _clip(zy, by0, by1)
    if _keeps(bx, by, ha0, ha1, hb, m):
        return bx, by, True
    qx4 = np.empty(5)
    qy4 = np.empty(5)
    box_x = np.array([bx0, bx1, bx1, bx0])
    box_y = np.array([by0, by0, by1, by1])
    for k in range(m):
        a0, a1, b = ha0[k], ha1[k], hb[k]
        if a0 * zx + a1 * zy >= b - _TOL:
            continue  # z keeps this one: it cannot be the one that binds alone
        n = _clip_polygon(box_x, box_y, 4, a0, a1, b, qx4, qy4)
        if n == 0:
            continue
        cx, cy = _nearest_on_polygon(qx4, qy4, n, zx, zy)
        if _keeps(cx, cy, ha0, ha1, hb, m):
            return cx, cy, True
    px = np.empty(4 + m + 4)
    py = np.empty(4 + m + 4)
    qx = np.empty(4 + m + 4)
    qy = np.empty(4 + m + 4)
    px[:4] = box_x
    py[:4] = box_y
    n = 4
    for k in range(m):
        n = _clip_polygon(px, py, n, ha0[k], ha1[k], hb[k], qx, qy)
        px, qx = qx, px
        py, qy = qy, py
        if n == 0:
            return bx, by, False
    bx, by = _nearest_on_polygon(px, py, n, zx, zy)
    return bx, by, True


@njit(cache=True)
def _keeps(x: float, y: float, ha0: NDArray[np.float64], ha1: NDArray[np.float64],
           hb: NDArray[np.float64], m: int) -> bool:
    """Whether (x, y) keeps every half-plane ha0 x + ha1 y >= hb of the first m (arrays, or
    their ``_jit.floats``)."""
    for k in range(m):
        if ha0[k] * x + ha1[k] * y < hb[k] - 1e-9:
            return False
    return True


@njit(cache=True)
def _nearest_on_polygon(px: NDArray[np.float64], py: NDArray[np.float64], n: int,
                        zx: float, zy: float) -> tuple[float, float]:
    """The nearest point to (zx, zy) of the boundary of the convex polygon (px, py)[:n]."""
    best = np.inf
    zx, zy = float(zx), float(zy)
    bx, by = zx, zy
    fx, fy = float(px[0]), float(py[0])
    x1, y1 = fx, fy
    for k in range(n):  # each vertex read once, as in ``_clip_polygon``
        x0, y0 = x1, y1
        x1, y1 = (float(px[k + 1]), float(py[k + 1])) if k + 1 < n else (fx, fy)
        ex, ey = x1 - x0, y1 - y0
        ee = ex * ex + ey * ey
        f = 0.0 if ee <= 0.0 else _clip(((zx - x0) * ex + (zy - y0) * ey) / ee, 0.0, 1.0)
        cx, cy = x0 + f * ex, y0 + f * ey
        d = (cx - zx) * (cx - zx) + (cy - zy) * (cy - zy)
        if d < best:
            best = d
            bx, by = cx, cy
    return bx, by
