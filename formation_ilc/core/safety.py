"""The safety filter: a learned command made safe before it reaches a base.

Between each robot's learned command u_n = (v, omega) and its base sits a minimally
invasive filter (a control barrier function on unicycles, as the Robotarium's barrier
certificates are). It returns the command nearest to u_n,

    minimise  (v - v_n)^2 + c^2 (omega - omega_n)^2

inside

* the base's limits: |v| <= v_max, |omega| <= omega_max, and the change from the previous
  command at most a_max dT and alpha_max dT (a box in (v, omega));
* one half-plane per pair of discs of this robot and another robot j heard within
  ``radius``. Each body is covered by a few discs along its heading (two cover a
  Pioneer-size rectangle far more tightly than one circle); a disc at offset l from the
  tracked point moves at p' = M(theta, l) u, M = [[cos, -l sin], [sin, l cos]], linear in
  u. For two discs d = |p_i - p_j| apart, with D the least distance between their
  centres, the robot keeps its own closing speed -d^T p'_i at most ``closing_speed`` of
  its share of the gap: half of d - D, plus r^2 / (2 a_max) when robot j recedes at r (it
  moves on that far at least before it can have stopped). Within its share a robot that
  holds its command for one sample can still stop, braking at its acceleration limit: the
  barrier is safe under the base's own limits, not only for an ideal unicycle. Each robot
  of a pair keeps its half, none needs the other's command: every robot runs the filter.

D_ij = ``distance`` + ``stale_speed`` x (age of robot j's pose): a pose that is old by the
link's delay is widened by how far robot j can have moved since. Robot j's motion is
estimated from two of its poses ``window`` samples apart (``motion``).

The problem has two unknowns: the feasible set is the box clipped by the half-planes, a
convex polygon (polygon clipping), and the answer is u_n if it lies inside, else the
nearest point of the polygon's boundary. No solver, no iteration: exact to round-off, a
few microseconds compiled. When the polygon is empty (no command in the limits keeps every
barrier), the robot brakes as hard as its limits allow (v towards 0, omega as asked, both
clipped to the box) and the sample is flagged ``INFEASIBLE``.

Learning through the filter (``LEARNING``): the memory must not wind up where the filter
overrode the learned command. ``learn_base`` gives the memory the learning step starts
from, ``freeze_flagged`` restores it where nothing may be learned:

* ``applied``: m + (u_applied - u_nominal) at every changed sample, so the memory learns
  from the command the robot really drove (the anti-windup of ILC with input saturation);
* ``freeze``: the old memory at every changed sample;
* ``split``: ``applied`` where only a limit clipped the command (a saturation, the same
  from trial to trial: anti-windup is right), ``freeze`` where a barrier moved it (another
  robot was in the way: a state of this trial, not of the task);
* ``ignore``: learns as if nothing had been changed (winds up; for comparison).

docs/safety.md has the measurements behind the default (``config.safety.default_learning``):
``applied`` for two-wheel bodies, where it learns fastest and the filter's work falls to
zero as the team converges; ``split`` for skid-steer bases (Husky, Jackal), whose
acceleration limits let a barrier change a command by metres a second within a sample,
and where ``applied`` then stalls.

Units: metres, seconds, radians. Robots' poses (x, y, theta) are their tracked points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit
from formation_ilc.core.limits import Limits

__all__ = ["SafetySpec", "LEARNING", "CHANGED_LIMITS", "CHANGED_BARRIER", "INFEASIBLE",
           "filter_command", "filter_team", "motion", "closing_speed", "learn_base",
           "freeze_flagged", "learning_code", "PARAMS", "MAX_DISCS"]

#: how the memory learns at samples the filter changed
LEARNING = ("applied", "freeze", "ignore", "split")
APPLIED, FREEZE, IGNORE, SPLIT = 0, 1, 2, 3

#: flags of one filtered command (bitwise or)
CHANGED_LIMITS = 1     # the learned command left the box of the base's limits
CHANGED_BARRIER = 2    # a barrier moved it
INFEASIBLE = 4         # no command in the limits keeps every barrier: the robot braked

#: the order of ``SafetySpec.params()``
PARAMS = ("distance", "discs", "gamma", "radius", "v_max", "omega_max", "a_max",
          "alpha_max", "dt", "stale_speed", "weight", "speed_uncertainty", "brake_share")
#: at most this many discs cover a body
MAX_DISCS = 3
_TOL = 1e-12
#: a limit of inf is no limit: the box is cut at this [m/s, rad/s] instead (polygon
#: clipping needs finite corners)
_BIG = 1e6
#: the share of a base's acceleration limit the barrier counts on for braking: a robot
#: heading across the line to another closes in at less than its speed, and brakes that
#: closing speed at less than its full deceleration
BRAKE_SHARE = 0.5


def learning_code(mode: str) -> int:
    if mode not in LEARNING:
        raise ValueError(f"safety learning must be one of {', '.join(LEARNING)}, got {mode!r}")
    return LEARNING.index(mode)


@dataclass(frozen=True)
class SafetySpec:
    """What the filter keeps.

    discs : offsets [m] of the discs that cover a robot's body, along its heading from the
        tracked point (negative: behind it); one or two (``discs_for``). A disc ahead of
        the axle can be moved sideways by turning; at offset 0 only by driving.
    distance : D [m], the least distance between the centres of two robots' discs (two
        disc radii plus a margin).
    gamma : the share of the barrier that may be used up per sample, 0 < gamma <= 1.
    radius : robots whose tracked points are farther apart than this [m] are not
        constrained (the sensing radius).
    limits : the base's speed and acceleration limits.
    dt : the sample time [s].
    stale_speed : [m/s] how fast another robot may have moved since its pose was taken
        (its speed limit): D grows by stale_speed x age.
    weight : c [m], the length that prices a change of omega against one of v.
    speed_uncertainty : [m/s] how wrong an estimate of another robot's velocity may be
        (from its poses' noise over the estimate's window): closing speeds count it.
    window : how many samples apart the two poses are that estimate another robot's
        velocity (``motion``).
    learning : how the memory learns where the filter changed the command (LEARNING).
    """

    discs: tuple[float, ...]
    distance: float
    gamma: float
    radius: float
    limits: Limits
    dt: float
    stale_speed: float = 0.0
    weight: float = 0.1
    speed_uncertainty: float = 0.0
    window: int = 3
    brake_share: float = 0.5
    learning: str = "applied"

    def __post_init__(self) -> None:
        checks = (("discs", 1 <= len(self.discs) <= MAX_DISCS
                   and all(math.isfinite(x) for x in self.discs)),
                  ("distance", self.distance > 0 and math.isfinite(self.distance)),
                  ("gamma", 0 < self.gamma <= 1),
                  ("radius", self.radius > 0),
                  ("dt", self.dt > 0 and math.isfinite(self.dt)),
                  ("stale_speed", self.stale_speed >= 0 and math.isfinite(self.stale_speed)),
                  ("weight", self.weight > 0 and math.isfinite(self.weight)),
                  ("speed_uncertainty", self.speed_uncertainty >= 0
                   and math.isfinite(self.speed_uncertainty)),
                  ("window", isinstance(self.window, int) and self.window >= 0),
                  ("brake_share", 0 <= self.brake_share <= 1))
        for name, ok in checks:
            if not ok:
                raise ValueError(f"safety {name}: out of range, got {getattr(self, name)!r}")
        learning_code(self.learning)

    def params(self) -> NDArray[np.float64]:
        """The numbers the kernels take, in the order of PARAMS, then the disc offsets."""
        lim = self.limits
        return np.array([self.distance, float(len(self.discs)), self.gamma, self.radius,
                         lim.v_max, lim.omega_max, lim.a_max, lim.alpha_max, self.dt,
                         self.stale_speed, self.weight, self.speed_uncertainty, self.brake_share,
                         *self.discs])


@njit(cache=True)
def closing_speed(share: float, gamma: float, dt: float, a_brake: float) -> float:
    """The fastest a robot may close in on another [m/s] when its share of the gap between
    them is ``share`` [m]: it may use up ``gamma`` of its share in the next sample, and
    must still be able to stop within it, braking at ``a_brake`` [m/s^2] in steps of
    a_brake dT held for a sample each after holding this command for ``dt``. Such braking
    covers w dT + w^2 / (2 a) + w dT / 2 (the steps cover half a sample more than braking
    smoothly would): w (1.5 dT) + w^2 / (2 a) <= share. A gap already used up (share <= 0)
    allows no closing at all."""
    if share <= 0.0:
        return 0.0
    w = gamma * share / dt
    if a_brake < 1e12:
        lag = 1.5 * dt
        w = min(w, a_brake * (np.sqrt(lag * lag + 2.0 * share / a_brake) - lag))
    return w


@njit(cache=True)
def _clip(a: float, lo: float, hi: float) -> float:
    return lo if a < lo else (hi if a > hi else a)


@njit(cache=True)
def _clip_polygon(px: NDArray[np.float64], py: NDArray[np.float64], n: int, a0: float,
                  a1: float, b: float, qx: NDArray[np.float64],
                  qy: NDArray[np.float64]) -> int:
    """The convex polygon (px, py)[:n] cut by the half-plane a0 x + a1 y >= b, into
    (qx, qy); returns its vertex count (0: empty)."""
    m = 0
    for k in range(n):
        x0, y0 = px[k], py[k]
        x1, y1 = px[(k + 1) % n], py[(k + 1) % n]
        s0 = a0 * x0 + a1 * y0 - b
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
def filter_command(v_n: float, w_n: float, x: float, y: float, th: float, v_prev: float,
                   w_prev: float, others: NDArray[np.float64], ages: NDArray[np.float64],
                   count: int, params: NDArray[np.float64],
                   out: NDArray[np.float64]) -> int:
    """The safe command of one robot, written into ``out`` (2,): (v [m/s], omega [rad/s]).

    v_n, w_n : the learned (nominal) command. x, y, th : the robot's own pose.
    v_prev, w_prev : its previous command (0, 0 at a trial's start: it stands).
    others : shape (>= count, 6), the robots it hears: pose (x, y, theta) and motion
        (vx, vy [m/s] of the tracked point in the world frame, omega [rad/s]; ``motion``;
        zeros when not known); ages : shape (>= count,), how old each pose is [s] (0 when
        it is of this sample).
    params : SafetySpec.params().
    Returns the flags (CHANGED_LIMITS | CHANGED_BARRIER | INFEASIBLE), 0 if ``out`` is the
    nominal command.
    """
    dist, n_discs, gamma, radius = params[0], int(params[1]), params[2], params[3]
    v_max, w_max, a_max, al_max, dt = params[4], params[5], params[6], params[7], params[8]
    stale, c, sigma = params[9], params[10], params[11]
    # the box of the limits
    v_lo = max(-v_max, v_prev - a_max * dt, -_BIG)
    v_hi = min(v_max, v_prev + a_max * dt, _BIG)
    w_lo = max(-w_max, w_prev - al_max * dt, -_BIG)
    w_hi = min(w_max, w_prev + al_max * dt, _BIG)
    if v_lo > v_hi:  # the previous command lies outside the speed limit: nearest edge
        v_lo = v_hi = v_max if v_prev > 0 else -v_max
    if w_lo > w_hi:
        w_lo = w_hi = w_max if w_prev > 0 else -w_max
    flags = 0
    if v_n < v_lo - _TOL or v_n > v_hi + _TOL or w_n < w_lo - _TOL or w_n > w_hi + _TOL:
        flags |= CHANGED_LIMITS
    # in scaled coordinates (v, c omega) the cost is Euclidean
    zx, zy = v_n, c * w_n
    bx0, bx1, by0, by1 = v_lo, v_hi, c * w_lo, c * w_hi
    # the barriers' half-planes a0 v + a1 (c omega) >= rhs that cut the box (one that holds
    # at every corner of the box cannot change the answer: most of them, as the box is a
    # sample's acceleration wide)
    cap = count * n_discs * n_discs
    ha0 = np.empty(cap)
    ha1 = np.empty(cap)
    hb = np.empty(cap)
    m = 0
    cth, sth = np.cos(th), np.sin(th)
    a_brake = params[12] * a_max if params[12] > 0.0 else np.inf
    barrier = False
    for j in range(count):
        gx, gy = x - others[j, 0], y - others[j, 1]
        if gx * gx + gy * gy > radius * radius:
            continue
        dj = dist + stale * ages[j]
        cj, sj = np.cos(others[j, 2]), np.sin(others[j, 2])
        for a in range(n_discs):
            ell = params[len(PARAMS) + a]
            sx, sy = x + ell * cth, y + ell * sth
            for b in range(n_discs):
                ellj = params[len(PARAMS) + b]
                dx, dy = sx - others[j, 0] - ellj * cj, sy - others[j, 1] - ellj * sj
                dd = np.sqrt(dx * dx + dy * dy)
                if dd < 1e-9:  # coincident centres: no direction to keep
                    continue
                dx /= dd
                dy /= dd
                # robot j receding from i at r moves on at least r^2 / (2 a_max) before it
                # can have stopped (it brakes no harder than its limit): room for robot i
                # besides its half of the gap (the other half is robot j's). Its motion is
                # an estimate (``motion``), taken as ``sigma`` slower than it looks.
                recede = -(dx * others[j, 3] + dy * others[j, 4]) - sigma
                share = 0.5 * (dd - dj)
                if recede > 0.0 and a_max < _BIG:
                    share += 0.5 * recede * recede / a_max
                # own closing speed -d^T p'_i <= w: d^T M(th, ell) u >= -w,
                # M = [[cos, -ell sin], [sin, ell cos]]
                rhs = -closing_speed(share, gamma, dt, a_brake)
                a0 = dx * cth + dy * sth
                a1 = ell * (-dx * sth + dy * cth) / c
                if (a0 * bx0 + a1 * by0 >= rhs and a0 * bx1 + a1 * by0 >= rhs
                        and a0 * bx0 + a1 * by1 >= rhs and a0 * bx1 + a1 * by1 >= rhs):
                    continue  # holds over the whole box
                if a0 * zx + a1 * zy < rhs - _TOL:
                    barrier = True
                ha0[m] = a0
                ha1[m] = a1
                hb[m] = rhs
                m += 1
    if not barrier and flags == 0:
        out[0] = v_n
        out[1] = w_n
        return 0
    # the feasible set: the box clipped by the half-planes that cut it
    px = np.empty(4 + m + 4)
    py = np.empty(4 + m + 4)
    qx = np.empty(4 + m + 4)
    qy = np.empty(4 + m + 4)
    px[0], py[0] = bx0, by0
    px[1], py[1] = bx1, by0
    px[2], py[2] = bx1, by1
    px[3], py[3] = bx0, by1
    n = 4
    for k in range(m):
        n = _clip_polygon(px, py, n, ha0[k], ha1[k], hb[k], qx, qy)
        px, qx = qx, px
        py, qy = qy, py
        if n == 0:
            break
    if n == 0:
        out[0] = _clip(0.0, v_lo, v_hi)
        out[1] = _clip(w_n, w_lo, w_hi)
        return flags | CHANGED_BARRIER | INFEASIBLE
    if barrier:
        flags |= CHANGED_BARRIER
    # the nearest point of the polygon: the nominal point is outside it
    best = np.inf
    bx, by = zx, zy
    for k in range(n):
        x0, y0 = px[k], py[k]
        ex, ey = px[(k + 1) % n] - x0, py[(k + 1) % n] - y0
        ee = ex * ex + ey * ey
        f = 0.0 if ee <= 0.0 else _clip(((zx - x0) * ex + (zy - y0) * ey) / ee, 0.0, 1.0)
        cx, cy = x0 + f * ex, y0 + f * ey
        d = (cx - zx) * (cx - zx) + (cy - zy) * (cy - zy)
        if d < best:
            best = d
            bx, by = cx, cy
    out[0] = _clip(bx, v_lo, v_hi)
    out[1] = _clip(by / c, w_lo, w_hi)
    return flags


@njit(cache=True)
def motion(x1: float, y1: float, th1: float, x0: float, y0: float, th0: float,
           span: float, out: NDArray[np.float64], at: int) -> None:
    """A robot's motion from two of its poses ``span`` [s] apart (pose 1 the newer), into
    out[at, 3:6]: (vx, vy [m/s], omega [rad/s]); zeros when span <= 0."""
    if span <= 0.0:
        out[at, 3] = 0.0
        out[at, 4] = 0.0
        out[at, 5] = 0.0
        return
    out[at, 3] = (x1 - x0) / span
    out[at, 4] = (y1 - y0) / span
    dth = th1 - th0
    dth -= 2.0 * np.pi * np.floor((dth + np.pi) / (2.0 * np.pi))
    out[at, 5] = dth / span


@njit(cache=True)
def filter_team(t: int, u: NDArray[np.float64], eta: NDArray[np.float64],
                prev: NDArray[np.float64], age: float, params: NDArray[np.float64],
                window: int, nominal: NDArray[np.float64], flags: NDArray[np.int64],
                others: NDArray[np.float64], ages: NDArray[np.float64]) -> None:
    """Every robot's filter at sample t, as the batch simulator runs it: robot r hears
    every other robot's measured pose eta[j, t], ``age`` seconds old, and estimates its
    motion from eta[j, t - window] (``motion``; from sample 0 before that).

    u : shape (N, >= t+1, 2), the learned commands at column t on entry, the safe ones on
        return (the nominal ones are copied into ``nominal`` (N, >= t+1, 2) first).
    eta : shape (N, >= t+1, 3), measured poses. prev : shape (N, 2), the previous
        commands (updated to the safe ones). flags : shape (N, >= t+1), written at t.
    others, ages : scratch of shape (N, 6) and (N,).
    """
    n = u.shape[0]
    res = np.empty(2)
    dt = params[8]
    back = max(0, t - window) if window > 0 else t
    for r in range(n):
        nominal[r, t, 0] = u[r, t, 0]
        nominal[r, t, 1] = u[r, t, 1]
    for r in range(n):
        m = 0
        for j in range(n):
            if j == r:
                continue
            others[m, 0] = eta[j, t, 0]
            others[m, 1] = eta[j, t, 1]
            others[m, 2] = eta[j, t, 2]
            motion(eta[j, t, 0], eta[j, t, 1], eta[j, t, 2], eta[j, back, 0],
                   eta[j, back, 1], eta[j, back, 2], (t - back) * dt, others, m)
            ages[m] = age
            m += 1
        flags[r, t] = filter_command(nominal[r, t, 0], nominal[r, t, 1], eta[r, t, 0],
                                     eta[r, t, 1], eta[r, t, 2], prev[r, 0], prev[r, 1],
                                     others, ages, m, params, res)
        u[r, t, 0] = res[0]
        u[r, t, 1] = res[1]
    for r in range(n):
        prev[r, 0] = u[r, t, 0]
        prev[r, 1] = u[r, t, 1]


@njit(cache=True)
def learn_base(mode: int, memory: NDArray[np.float64], nominal: NDArray[np.float64],
               applied: NDArray[np.float64], flags: NDArray[np.int64],
               out: NDArray[np.float64]) -> None:
    """The memory the learning step starts from, written into ``out`` (R, T, 2).

    memory, nominal, applied : shape (R, T, 2): the trial's memory, the learned commands
    and the commands the filter let through; flags : shape (R, T). ``applied`` (APPLIED):
    memory + (applied - nominal); ``freeze`` and ``ignore``: the memory itself (freeze then
    restores the old memory at flagged samples after the step, ``freeze_flagged``).
    """
    for r in range(memory.shape[0]):
        for t in range(memory.shape[1]):
            for c in range(2):
                x = memory[r, t, c]
                f = flags[r, t]
                if f != 0 and (mode == APPLIED or (mode == SPLIT and f == CHANGED_LIMITS)):
                    x += applied[r, t, c] - nominal[r, t, c]
                out[r, t, c] = x


@njit(cache=True)
def freeze_flagged(mode: int, memory: NDArray[np.float64], flags: NDArray[np.int64],
                   learned: NDArray[np.float64]) -> None:
    """``freeze``: the learned memory keeps the old one at every flagged sample; ``split``:
    at every sample where a barrier acted."""
    if mode != FREEZE and mode != SPLIT:
        return
    for r in range(memory.shape[0]):
        for t in range(memory.shape[1]):
            f = flags[r, t]
            if (mode == FREEZE and f != 0) or (mode == SPLIT and f & CHANGED_BARRIER):
                learned[r, t, 0] = memory[r, t, 0]
                learned[r, t, 1] = memory[r, t, 1]
