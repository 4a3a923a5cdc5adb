"""The safety filter: a learned command made safe before it reaches a base.

Between each robot's learned command u_n = (v, omega) and its base sits a minimally
invasive filter (a control barrier function on unicycles, as the Robotarium's barrier
certificates are). It returns the command nearest to u_n,

    minimise  (v - v_n)^2 + c^2 (omega - omega_n)^2

inside

* the base's limits: |v| <= v_max, |omega| <= omega_max, and the change from the previous
  command at most a_max dT and alpha_max dT (a box in (v, omega));
* one or two half-planes per pair of discs of this robot and another robot j heard within
  ``radius``. Each body is covered by a few discs along its heading (two cover a
  Pioneer-size rectangle far more tightly than one circle); a disc at offset l from the
  tracked point moves at p' = M(theta, l) u, M = [[cos, -l sin], [sin, l cos]]. The pair
  keeps a braking invariant: X_i + X_j <= g, X_k the disc's closing displacement if robot
  k holds its command for a sample and then brakes at its limits, g the gap beyond D.
  Robot i keeps X_i(u) <= B_i + s_i (g - B_i - B_j), B_i its own X when it brakes now,
  B_j an upper bound of robot j's from its estimated motion, s_i its share of the slack
  (split by the poses, s_i + s_j <= 1): the braking command keeps every barrier while the
  slack is not negative, and two robots that each keep theirs keep it so (``filter_command``
  has the details, docs/safety.md the assumptions). X_i is bounded by a linear function of
  u over the sample's box of commands (chords of the carried distance and turn, with the
  turn's bending of the path counted to second order). No robot needs another's command:
  every robot runs the filter.

Robot j's motion is estimated from two of its poses ``window`` samples apart (``motion``).
A pose of robot j that is old by the link's delay is moved on by that motion, and the
distance widened by how wrong that can be (or by its speed limit ``stale_speed`` x the
age, where that is less).

The problem has two unknowns: the feasible set is the box clipped by the half-planes, a
convex polygon (polygon clipping), and the answer is u_n if it lies inside, else the
nearest point of the polygon's boundary. No solver, no iteration: exact to round-off, a
few microseconds compiled. When the polygon is empty (no command in the limits keeps every
barrier), the robot brakes as hard as its limits allow (v and omega towards 0) and the
sample is flagged ``INFEASIBLE``; so is a sample at which a pair's slack was already
negative (the pair past braking apart as the filter counts it: outside the guarantee),
whether or not the filter changed the command. ``CHANGED`` masks the flags of a changed
command.

Learning through the filter (``LEARNING``, what the memory learns where the filter changed
the command) is ``core.through``'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit
from formation_ilc.core.estimate import box_centre, box_error, box_start, box_step
from formation_ilc.core.limits import Limits

__all__ = ["SafetySpec", "LEARNING", "CHANGED_LIMITS", "CHANGED_BARRIER", "INFEASIBLE",
           "CHANGED", "filter_command", "filter_team", "motion", "PARAMS", "MAX_DISCS",
           "OTHER_FIELDS", "told", "team_boxes"]

#: how the memory learns at samples the filter changed
LEARNING = ("applied", "freeze", "ignore", "split", "damped", "robust")

#: flags of one filtered command (bitwise or)
CHANGED_LIMITS = 1     # the learned command left the box of the base's limits
CHANGED_BARRIER = 2    # a barrier moved it
INFEASIBLE = 4         # outside the guarantee: a pair's slack was negative, or no command
#                        in the limits kept every barrier (the robot braked)
#: the flags of a command the filter changed (INFEASIBLE alone leaves it as it was)
CHANGED = CHANGED_LIMITS | CHANGED_BARRIER

#: the order of ``SafetySpec.params()``
PARAMS = ("distance", "discs", "gamma", "radius", "v_max", "omega_max", "a_max",
          "alpha_max", "dt", "stale_speed", "weight", "speed_uncertainty", "brake_share",
          "lag", "commands", "own_bound", "told_uncertainty", "pose_error", "noise",
          "process", "heading_error")
#: the columns of a robot heard (``filter_command``'s ``others``): pose (x, y, theta),
#: motion (vx, vy, omega), 1 where that motion is the command the robot told (``told``),
#: 0 where it is estimated from its poses (``motion``), and how far this robot's position
#: and robot j's, as the filter has them, can be off together [m] (the pair's distance
#: grows by it: ``pose_error`` for raw poses, two boxes' half-diagonals for estimates,
#: ``core.estimate``)
OTHER_FIELDS = 8
#: at most this many discs cover a body
MAX_DISCS = 3
_TOL = 1e-12
#: a limit of inf is no limit: the box is cut at this [m/s, rad/s] instead (polygon
#: clipping needs finite corners)
_BIG = 1e6
#: how far the split of a pair's slack leans towards the robot that heads towards the
#: other (0: halves; 1: all of it; below 1 each robot keeps a share, 1 - _SPLIT of its half)
_SPLIT = 0.9
#: the share of a base's acceleration limit the barrier counts on for braking: a robot
#: heading across the line to another closes in at less than its speed, and brakes that
#: closing speed at less than its full deceleration
BRAKE_SHARE = 0.5


@dataclass(frozen=True)
class SafetySpec:
    """What the filter keeps.

    discs : offsets [m] of the discs that cover a robot's body, along its heading from the
        tracked point (negative: behind it); one or two (``discs_for``). A disc ahead of
        the axle can be moved sideways by turning; at offset 0 only by driving.
    distance : D [m], the least distance between the centres of two robots' discs (two
        disc radii plus a margin).
    gamma : the share of a pair's slack (the gap left when both robots brake) that one
        robot may use up in a sample, 0 < gamma <= 0.5: each of two robots taking at most
        half keeps the pair's slack from going negative.
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
    commands : the robots tell each other the command they apply (``told``), and the
        batch simulator's ``filter_team`` takes every other robot's speed from it.
    told_uncertainty : [m/s] how wrong a told robot's velocity may be (its direction comes
        from its measured heading).
    pose_error : [m] how far the difference of two robots' measured positions can be from
        the true one: the distance grows by it where positions are the raw poses.
    noise, process, heading_error : where robots tell their commands, each robot's
        position is estimated (``core.estimate``): poses off by up to ``noise`` [m] per
        axis, motion off the told command by up to ``process`` [m] per axis a sample, the
        heading by up to ``heading_error`` [rad]; the distance then grows by the two
        estimates' bounds instead of ``pose_error``.
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
    learning: str = "damped"
    commands: bool = False
    told_uncertainty: float = 0.0
    pose_error: float = 0.0
    noise: float = 0.0
    process: float = 0.0
    heading_error: float = 0.0

    def __post_init__(self) -> None:
        checks = (("discs", 1 <= len(self.discs) <= MAX_DISCS
                   and all(math.isfinite(x) for x in self.discs)),
                  ("distance", self.distance > 0 and math.isfinite(self.distance)),
                  ("gamma", 0 < self.gamma <= 0.5),
                  ("radius", self.radius > 0),
                  ("dt", self.dt > 0 and math.isfinite(self.dt)),
                  ("stale_speed", self.stale_speed >= 0 and math.isfinite(self.stale_speed)),
                  ("weight", self.weight > 0 and math.isfinite(self.weight)),
                  ("speed_uncertainty", self.speed_uncertainty >= 0
                   and math.isfinite(self.speed_uncertainty)),
                  ("told_uncertainty", self.told_uncertainty >= 0
                   and math.isfinite(self.told_uncertainty)),
                  *((name, getattr(self, name) >= 0 and math.isfinite(getattr(self, name)))
                    for name in ("pose_error", "noise", "process", "heading_error")),
                  ("window", isinstance(self.window, int) and self.window >= 0),
                  ("brake_share", 0 < self.brake_share <= 1))
        for name, ok in checks:
            if not ok:
                raise ValueError(f"safety {name}: out of range, got {getattr(self, name)!r}")
        if self.learning not in LEARNING:
            raise ValueError(f"safety learning must be one of {', '.join(LEARNING)}, got "
                             f"{self.learning!r}")

    def params(self) -> NDArray[np.float64]:
        """The numbers the kernels take, in the order of PARAMS, then the disc offsets.
        ``commands``: 1 where the robots tell each other their commands (``told``);
        ``own_bound``: 1, a learned command that keeps its own bound passes (0: it is judged
        by the chords of the sample's box alone, the polygon the answer is projected on)."""
        lim = self.limits
        return np.array([self.distance, float(len(self.discs)), self.gamma, self.radius,
                         lim.v_max, lim.omega_max, lim.a_max, lim.alpha_max, self.dt,
                         self.stale_speed, self.weight, self.speed_uncertainty, self.brake_share,
                         0.5 * max(self.window - 1, 0) * self.dt, float(self.commands),
                         1.0, self.told_uncertainty, self.pose_error, self.noise, self.process,
                         self.heading_error, *self.discs])


@njit(cache=True)
def _clip(a: float, lo: float, hi: float) -> float:
    return lo if a < lo else (hi if a > hi else a)


@njit(cache=True)
def _carry(v: float, dt: float, a: float) -> float:
    """How far [m, or rad] a speed v carries: held for dt, then braked at a to a stop
    (signed as v)."""
    return v * dt + v * abs(v) / (2.0 * a)


@njit(cache=True)
def _receded(v: float, dt: float, a: float, t: float) -> float:
    """How far [m] a speed v carries by time t when held for dt, then braked at a (v >= 0):
    ``_carry``'s distance, cut at t."""
    if t <= dt:
        return v * t
    stop = dt + v / a
    if t >= stop:
        return _carry(v, dt, a)
    r = t - dt
    return v * dt + v * r - 0.5 * a * r * r


@njit(cache=True)
def _toward_zero(x: float, step: float) -> float:
    """x moved towards 0 by at most ``step`` (a sample of braking at the limit)."""
    if x > step:
        return x - step
    if x < -step:
        return x + step
    return 0.0


@njit(cache=True)
def _chord_errors(lo: float, hi: float, k: float, dt: float, a: float) -> tuple[float, float]:
    """How far ``_carry(x, dt, a)`` lies above and below its chord over [lo, hi] (slope
    ``k``, through both ends), each >= 0: the function is concave below 0 and convex above
    (second derivative -+1 / a), so it lies above the chord only where the interval reaches
    below 0, and below it only where it reaches above 0; each at the one point where its
    slope is the chord's."""
    if hi <= lo:
        return 0.0, 0.0
    f_lo = _carry(lo, dt, a)
    up = 0.0
    if lo < 0.0:  # concave part [lo, min(0, hi)]: its largest rise above the chord
        x = _clip(a * (dt - k), lo, min(0.0, hi))
        up = max(0.0, _carry(x, dt, a) - f_lo - k * (x - lo))
    dn = 0.0
    if hi > 0.0:  # convex part [max(0, lo), hi]: its deepest dip below the chord
        x = _clip(a * (k - dt), max(0.0, lo), hi)
        dn = max(0.0, f_lo + k * (x - lo) - _carry(x, dt, a))
    return up, dn


@njit(cache=True)
def _clip_polygon(px: NDArray[np.float64], py: NDArray[np.float64], n: int, a0: float,
                  a1: float, b: float, qx: NDArray[np.float64],
                  qy: NDArray[np.float64]) -> int:
    """The convex polygon (px, py)[:n] cut by the half-plane a0 x + a1 y >= b, into
    (qx, qy); returns its vertex count (0: empty)."""
    m = 0
    # Python floats: interpreted (the nodes), arithmetic on numpy scalars costs 3x
    a0, a1, b = float(a0), float(a1), float(b)
    for k in range(n):
        x0, y0 = float(px[k]), float(py[k])
        x1, y1 = float(px[(k + 1) % n]), float(py[(k + 1) % n])
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
    others : shape (>= count, OTHER_FIELDS), the robots it hears: pose (x, y, theta) and
        motion (vx, vy [m/s] of the tracked point in the world frame, omega [rad/s]; zeros
        when not known), estimated from its poses (``motion``, column 6 is 0: as wrong as
        ``speed_uncertainty`` and ``lag`` allow) or the command it told (``told``, column 6
        is 1: as wrong as ``told_uncertainty``); ages : shape (>= count,), how old each
        pose is [s] (0 when it is of this sample).
    params : SafetySpec.params().
    Returns the flags (CHANGED_LIMITS | CHANGED_BARRIER | INFEASIBLE); ``out`` is the
    nominal command where ``flags & CHANGED`` is 0. INFEASIBLE: a pair's slack was
    negative before this sample (a pose or a body off by more than the filter accounts
    for; the command then closes in no more than braking), or nothing in the box keeps
    every barrier (the robot brakes).

    The barrier of a pair of discs (module docstring, "The guarantee"): with n the unit
    vector from robot j's disc to robot i's and g the gap beyond D, robot i's closing
    displacement X_i(u) (hold u for a sample, then brake at the limits) is at most
    s_i(u) tau + rot_i, s_i(u) = -n^T M(th, l) u its closing speed, linear in u. Robot i
    keeps X_i(u) <= B_i + share (g - B_i - B_j), B_i its own X when it brakes now, B_j an
    upper bound of robot j's from its estimated motion: the braking command always keeps
    it while the pair's slack g - B_i - B_j is not negative, and two robots that each take
    their share (at most half) of the slack keep it not negative.
    """
    # Python floats (a node runs this uncompiled: numpy scalars cost 3x in arithmetic)
    dist, n_discs, share, radius = (float(params[0]), int(params[1]), float(params[2]),
                                    float(params[3]))
    v_max, w_max, a_max, al_max, dt = (float(params[4]), float(params[5]), float(params[6]),
                                       float(params[7]), float(params[8]))
    stale, c, sigma, brake, lag = (float(params[9]), float(params[10]), float(params[11]),
                                   float(params[12]), float(params[13]))
    v_n, w_n, x, y, th = float(v_n), float(w_n), float(x), float(y), float(th)
    v_prev, w_prev = float(v_prev), float(w_prev)
    own_bound = float(params[15]) > 0.0
    told_sigma = float(params[16])
    off0 = float(params[len(PARAMS)])
    off1 = float(params[len(PARAMS) + 1]) if n_discs > 1 else 0.0
    off2 = float(params[len(PARAMS) + 2]) if n_discs > 2 else 0.0
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
    inside = not (v_n < v_lo - _TOL or v_n > v_hi + _TOL or w_n < w_lo - _TOL
                  or w_n > w_hi + _TOL)
    if not inside:
        flags |= CHANGED_LIMITS
    # braking: the deceleration counted on (a share of the limit), and this robot's own
    # braking command (a sample of braking from the previous command, inside the box)
    a_b = brake * a_max if a_max < _BIG else _BIG
    al_b = brake * al_max if al_max < _BIG else _BIG
    vb = _clip(_toward_zero(v_prev, a_max * dt), v_lo, v_hi)
    wb = _clip(_toward_zero(w_prev, al_max * dt), w_lo, w_hi)
    # how far a command carries the robot: held for a sample, then braked to a stop,
    # f(v) = v dT + v |v| / (2 a) along its heading, g(w) = w dT + w |w| / (2 alpha) of
    # turn. Over the box each is replaced by its chord (slope k, offset e): the chord
    # plus e bounds the function from above and minus e from below (|f''| <= 1 / a)
    fv0, fv1 = _carry(v_lo, dt, a_b), _carry(v_hi, dt, a_b)
    kv = (fv1 - fv0) / (v_hi - v_lo) if v_hi > v_lo else dt + abs(v_lo) / a_b
    ev = (v_hi - v_lo) * (v_hi - v_lo) / (8.0 * a_b)
    ev_up, ev_dn = _chord_errors(v_lo, v_hi, kv, dt, a_b)
    gw0, gw1 = _carry(w_lo, dt, al_b), _carry(w_hi, dt, al_b)
    sv_hi = max(abs(v_lo), abs(v_hi))
    sw_hi = max(abs(w_lo), abs(w_hi))
    # the heading turns while the robot holds and brakes, by G(w). Its path (at most
    # path_i = f(sv_hi) long) then strays sideways, towards the side it turns to, by up to
    # its length x the turn (all of it if the turn ends first); a disc swings sideways by
    # its offset x the turn; both to second order in the turn (at most ``turn``): q |G|.
    # So X_i(u) <= a0 F(v) + max(sp G(w), sm G(w)), per pair sp = a1c + path_i max(b, 0)
    # + q, sm = a1c + path_i min(b, 0) - q (b: the side the pair's direction lies on)
    turn = _carry(sw_hi, dt, al_b)
    path_i = _carry(sv_hi, dt, a_b)
    l_max = max(abs(off0), abs(off1), abs(off2))
    q_i = 0.5 * (path_i + l_max) * turn
    f_b, g_b = _carry(vb, dt, a_b), _carry(wb, dt, al_b)
    # G's chord on the box (slope kw, through (w_lo, G(w_lo))) and its error ew; on a box
    # on one side of w = 0 only that side's line of the max counts
    kw = (gw1 - gw0) / (w_hi - w_lo) if w_hi > w_lo else dt + abs(w_lo) / al_b
    ew = (w_hi - w_lo) * (w_hi - w_lo) / (8.0 * al_b)
    ew_up, ew_dn = _chord_errors(w_lo, w_hi, kw, dt, al_b)
    g_off = gw0 - kw * w_lo
    lines_p = w_hi > 0.0
    lines_m = w_lo < 0.0
    # the most robot i's braking closes in (e_i) and the most a command of the box can
    # change that (w_i), for the test that skips robots too far to matter
    e_i = path_i + (l_max + path_i + q_i) * (turn + ew) + ev
    w_i = kv * (v_hi - v_lo) + (l_max + path_i + q_i) * kw * (w_hi - w_lo)
    # the earliest robot i can have closed in all a command of the box closes in: its
    # carried distance f(v) over its speed, dT + |v| / (2 a), at the box's least |v|
    v_least = 0.0 if v_lo <= 0.0 <= v_hi else min(abs(v_lo), abs(v_hi))
    t_close = dt + v_least / (2.0 * a_b) if a_b < _BIG else dt
    # the learned command's own carried distance, turn and path (``keeps`` below), once
    judge_own = inside and own_bound
    f_n = _carry(v_n, dt, a_b)
    g_n = _carry(w_n, dt, al_b)
    path_n = _carry(abs(v_n), dt, a_b)
    q_n = 0.5 * (path_n + l_max) * abs(g_n)
    # in scaled coordinates (v, c omega) the cost is Euclidean
    zx, zy = v_n, c * w_n
    bx0, bx1, by0, by1 = v_lo, v_hi, c * w_lo, c * w_hi
    cth, sth = math.cos(th), math.sin(th)
    cap = 0
    ha0 = np.empty(0)
    ha1 = np.empty(0)
    hb = np.empty(0)
    m = 0
    barrier = False
    infeasible = False
    for j in range(count):
        ox, oy = float(others[j, 0]), float(others[j, 1])
        gx, gy = x - ox, y - oy
        gg = gx * gx + gy * gy
        if gg > radius * radius:
            continue
        age = float(ages[j])
        # robot j: its estimated speed, how wrong it may be, how far it closes in braking
        vxj, vyj, wj = float(others[j, 3]), float(others[j, 4]), float(others[j, 5])
        swj = abs(wj)
        spj = math.sqrt(vxj * vxj + vyj * vyj)
        # the estimate is a mean over the window, ``lag`` old: since then robot j's speed
        # changed by at most a_max lag, its direction by |omega| lag; a told command is
        # the speed itself (no lag), its direction as good as the pose's heading
        told_j = float(others[j, 6]) > 0.0
        lag_j = 0.0 if told_j else lag
        sig = ((told_sigma if told_j else sigma) + a_max * (lag_j + age)
               + spj * swj * (lag_j + age + 0.5 * dt))
        # a pose ``age`` s old: robot j has moved on since, as its motion says, to within
        # sig x age of there; or, if its speed limit (``stale``) says less, within that of
        # where it was
        ahead = age > 0.0 and not (0.0 < stale <= sig)
        dj = dist + float(others[j, 7]) + (sig if ahead or stale <= 0.0 else stale) * age
        if ahead:
            ox += vxj * age
            oy += vyj * age
            gx, gy = x - ox, y - oy
            gg = gx * gx + gy * gy
        # robot j braking now covers f(v - a_max dT) along its heading: its closing speed
        # lasts that over its speed, rho (at its fastest for a closing bound, its slowest,
        # braking its hardest, for a receding one)
        v_up, v_dn = spj + sig, spj - sig
        tau_j = _carry(v_up - a_max * dt, dt, a_b) / v_up if v_up > a_max * dt else 0.0
        # a receding robot, credited for all it recedes by the end of its braking (tau_jlo)
        # or only for what it recedes by the time robot i can have closed in all it may
        # (tau_jsoon, at t_close): see the pair's test below
        tau_jlo = (_carry(v_dn - a_max * dt, dt, a_max) / v_dn if v_dn > a_max * dt
                   else 0.0)
        tau_jsoon = (_receded(v_dn - a_max * dt, dt, a_max, t_close) / v_dn
                     if v_dn > a_max * dt else 0.0)
        turn_j = _carry(swj + al_max * (lag_j + age), dt, al_b)
        rot_j = (_carry(spj + sig, dt, a_b) + 0.5 * l_max * turn_j) * turn_j
        e_j = v_up * tau_j + l_max * turn_j + rot_j
        # so far apart that no command of the box can meet a barrier
        gap0 = math.sqrt(gg) - 2.0 * l_max - dj
        if share * (1.0 - _SPLIT) * (gap0 - e_i - e_j) >= w_i:
            continue
        oth = float(others[j, 2]) + (wj * age if ahead else 0.0)
        cj, sj = math.cos(oth), math.sin(oth)
        for a in range(n_discs):
            ell = off0 if a == 0 else (off1 if a == 1 else off2)
            sx, sy = x + ell * cth - ox, y + ell * sth - oy
            for b in range(n_discs):
                ellj = off0 if b == 0 else (off1 if b == 1 else off2)
                dx, dy = sx - ellj * cj, sy - ellj * sj
                dd = math.sqrt(dx * dx + dy * dy)
                if dd < 1e-9:  # coincident centres: no direction to keep
                    continue
                if share * (1.0 - _SPLIT) * (dd - dj - e_i - e_j) >= w_i:
                    continue  # this pair of discs is too far apart to matter
                dx /= dd
                dy /= dd
                # robot i's closing displacement X_i(u) <= a0 F(v) + |a0| ev + max(sp G,
                # sm G) + max(|sp|, |sm|) ew: its disc moves along M(th, ell) = [[cos,
                # -ell sin], [sin, ell cos]], a0 = -n^T M e_v, a1c = -n^T M e_w = ell b
                a0 = -(dx * cth + dy * sth)
                bside = dx * sth - dy * cth
                a1c = ell * bside
                sp = a1c + (path_i * bside if bside > 0.0 else 0.0) + q_i
                sm = a1c + (path_i * bside if bside < 0.0 else 0.0) - q_i
                # braking now (vb, wb) closes in by b_i, as f and g give it (the chords of
                # a command may lie above: at a slack of 0 braking may be all that is
                # left, and the robot brakes)
                b_i = a0 * f_b + (sp * g_b if g_b >= 0.0 else sm * g_b)
                # robot j's closing speed towards i: its tracked point's, taken ``sig``
                # faster than it looks, over its braking time. The disc's swing is not a
                # speed that lasts that long: the turn stops within its own braking, and
                # the swing it makes is at most |ellj| turn_j (below). Counted as a speed,
                # a swing away from robot i was credited for the whole of a straight
                # braking: two Pioneers returning side by side closed 2.3 cm past D
                s_j = dx * vxj + dy * vyj + sig
                # Robot j recedes (s_j < 0) while robot i may close in: the sum of their
                # closings peaks at the end of both brakings only if robot i's closing
                # slows no faster than robot j's receding does (i's closing factor x its
                # deceleration at most j's); else it can peak while robot j still recedes,
                # and j is credited only up to t_close (a fuzz of pairs side by side found
                # 6 mm past D at dT 0.2 s with the whole credit)
                if s_j >= 0.0:
                    r_j = s_j * tau_j
                elif v_dn > 0.0 and a0 * a_b * v_dn <= -s_j * a_max:
                    r_j = s_j * tau_jlo
                else:
                    r_j = s_j * tau_jsoon
                b_j = r_j + abs(ellj) * turn_j + rot_j
                slack = dd - dj - b_i - b_j
                if slack < 0.0:
                    infeasible = True
                    slack = 0.0
                # the pair's slack is split by the poses, which both robots see alike: the
                # more a robot heads towards the other than the other towards it, the more
                # is its own (19 parts in 20 for a robot behind another that drives away, 1
                # for the one ahead, which brakes or drives on without closing in);
                # the two shares add up to 2 gamma <= 1
                mine = share * (1.0 + 0.5 * _SPLIT * (a0 - dx * cj - dy * sj))
                # the learned command's own closing, bounded as above but with its own
                # path and turn in place of the box's largest: the chords below, which make
                # the feasible set a polygon, hold for every command of the box and lie
                # above it. A learned command that keeps its own bound keeps the invariant,
                # and passes (the paper's triangle on Pioneers: its desired motion kept it
                # where the chords were off by 2-3 mm)
                keeps = False
                if judge_own:
                    bend = path_n * bside
                    x_n = a0 * f_n + (
                        (a1c + (bend if bside > 0.0 else 0.0) + q_n) * g_n if g_n >= 0.0
                        else (a1c + (bend if bside < 0.0 else 0.0) - q_n) * g_n)
                    keeps = x_n <= b_i + mine * slack + _TOL
                # X_i(u) <= b_i + mine slack: h0 v + h1 (c w) <= lim, a half-plane per
                # line of the max that the box reaches
                h0 = a0 * kv
                base = (b_i + mine * slack - a0 * (fv0 - kv * v_lo)
                        - (a0 * ev_up if a0 >= 0.0 else -a0 * ev_dn))
                for li in range(2):
                    if (li == 0 and not lines_p) or (li == 1 and not lines_m):
                        continue
                    slope = sp if li == 0 else sm
                    h1 = slope * kw / c
                    lim = (base - slope * g_off
                           - (slope * ew_up if slope >= 0.0 else -slope * ew_dn))
                    # the largest h0 v + h1 (c w) over the box, at one of its corners
                    if ((h0 * bx1 if h0 >= 0.0 else h0 * bx0)
                            + (h1 * by1 if h1 >= 0.0 else h1 * by0)) <= lim:
                        continue  # holds over the whole box
                    if not keeps and h0 * zx + h1 * zy > lim + _TOL:
                        barrier = True
                    if m == cap:
                        cap = 2 * cap + 8
                        n0, n1, n2 = np.empty(cap), np.empty(cap), np.empty(cap)
                        n0[:m] = ha0[:m]
                        n1[:m] = ha1[:m]
                        n2[:m] = hb[:m]
                        ha0, ha1, hb = n0, n1, n2
                    ha0[m] = -h0
                    ha1[m] = -h1
                    hb[m] = -lim
                    m += 1
    if infeasible:
        # a pair's slack was negative before this sample (a pose or a body off by more
        # than the filter accounts for): outside the guarantee, flagged even where the
        # command closes in no more than braking and passes unchanged
        flags |= INFEASIBLE
    if not barrier and flags & CHANGED == 0:
        out[0] = v_n
        out[1] = w_n
        return flags
    if barrier:
        flags |= CHANGED_BARRIER
    # the nearest feasible point (``_nearest``)
    bx, by, ok = _nearest(zx, zy, bx0, bx1, by0, by1, ha0, ha1, hb, m)
    if not ok:  # nothing in the box keeps every barrier (a slack used up): brake
        out[0] = vb
        out[1] = wb
        return flags | CHANGED_BARRIER | INFEASIBLE
    out[0] = _clip(bx, v_lo, v_hi)
    out[1] = _clip(by / c, w_lo, w_hi)
    return flags


@njit(cache=True)
def _nearest(zx: float, zy: float, bx0: float, bx1: float, by0: float, by1: float,
             ha0: NDArray[np.float64], ha1: NDArray[np.float64], hb: NDArray[np.float64],
             m: int) -> tuple[float, float, bool]:
    """The nearest point to (zx, zy) of the box [bx0, bx1] x [by0, by1] cut by the first
    m half-planes ha0 x + ha1 y >= hb, and whether there is one. Most often one barrier
    binds: the nearest point of the box cut by that one half-plane is the answer when it
    keeps every other (the feasible set lies inside that cut box); else the box is clipped
    by every half-plane (exact)."""
    bx, by = _clip(zx, bx0, bx1), _clip(zy, by0, by1)
    if _keeps(bx, by, ha0, ha1, hb, m):
        return bx, by, True
    qx4 = np.empty(5)
    qy4 = np.empty(5)
    box_x = np.array([bx0, bx1, bx1, bx0])
    box_y = np.array([by0, by0, by1, by1])
    for k in range(m):
        if ha0[k] * zx + ha1[k] * zy >= hb[k] - _TOL:
            continue  # z keeps this one: it cannot be the one that binds alone
        n = _clip_polygon(box_x, box_y, 4, ha0[k], ha1[k], hb[k], qx4, qy4)
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
    """Whether (x, y) keeps every half-plane ha0 x + ha1 y >= hb of the first m."""
    x, y = float(x), float(y)
    for k in range(m):
        if float(ha0[k]) * x + float(ha1[k]) * y < float(hb[k]) - 1e-9:
            return False
    return True


@njit(cache=True)
def _nearest_on_polygon(px: NDArray[np.float64], py: NDArray[np.float64], n: int,
                        zx: float, zy: float) -> tuple[float, float]:
    """The nearest point to (zx, zy) of the boundary of the convex polygon (px, py)[:n]."""
    best = np.inf
    zx, zy = float(zx), float(zy)
    bx, by = zx, zy
    for k in range(n):
        x0, y0 = float(px[k]), float(py[k])
        ex, ey = float(px[(k + 1) % n]) - x0, float(py[(k + 1) % n]) - y0
        ee = ex * ex + ey * ey
        f = 0.0 if ee <= 0.0 else _clip(((zx - x0) * ex + (zy - y0) * ey) / ee, 0.0, 1.0)
        cx, cy = x0 + f * ex, y0 + f * ey
        d = (cx - zx) * (cx - zx) + (cy - zy) * (cy - zy)
        if d < best:
            best = d
            bx, by = cx, cy
    return bx, by


@njit(cache=True)
def motion(x1: float, y1: float, th1: float, x0: float, y0: float, th0: float,
           span: float, out: NDArray[np.float64], at: int) -> None:
    """A robot's motion from two of its poses ``span`` [s] apart (pose 1 the newer), into
    out[at, 3:7]: (vx, vy [m/s], omega [rad/s], 0: estimated); zeros when span <= 0."""
    out[at, 6] = 0.0
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
def told(th: float, v: float, w: float, out: NDArray[np.float64], at: int) -> None:
    """A robot's motion from the command it tells it applies over the sample (v [m/s],
    omega [rad/s]) and its measured heading ``th``, into out[at, 3:7] (1: told)."""
    out[at, 3] = v * math.cos(th)
    out[at, 4] = v * math.sin(th)
    out[at, 5] = w
    out[at, 6] = 1.0


@njit(cache=True)
def filter_team(t: int, u: NDArray[np.float64], eta: NDArray[np.float64],
                prev: NDArray[np.float64], age: float, params: NDArray[np.float64],
                window: int, nominal: NDArray[np.float64], flags: NDArray[np.int64],
                others: NDArray[np.float64], ages: NDArray[np.float64],
                boxes: NDArray[np.float64]) -> int:
    """Every robot's filter at sample t, as the batch simulator runs it: robot r hears
    every other robot's measured pose eta[j, t], ``age`` seconds old, and estimates its
    motion from eta[j, t - window] (``motion``; from sample 0 before that), or, where the
    robots tell each other their commands (params ``commands``), takes it from the
    command robot j applied over the sample before (``told``), and every position from
    its box (``team_boxes``).

    u : shape (N, >= t+1, 2), the learned commands at column t on entry, the safe ones on
        return (the nominal ones are copied into ``nominal`` (N, >= t+1, 2) first).
    eta : shape (N, >= t+1, 3), measured poses. prev : shape (N, 2), the previous
        commands (updated to the safe ones). flags : shape (N, >= t+1), written at t.
    others, ages : scratch of shape (N, OTHER_FIELDS) and (N,). boxes : shape (N, 4),
        each robot's box (``core.estimate``), moved on to sample t here (called once a
        sample, t = 0, 1, ... of a trial). Returns how many poses missed their box.
    """
    n = u.shape[0]
    res = np.empty(2)
    dt = params[8]
    commands = params[14] > 0.0  # PARAMS: "commands"
    pose_error = params[17]
    missed = team_boxes(t, eta, prev, params, boxes) if commands else 0
    back = max(0, t - window) if window > 0 else t
    for r in range(n):
        nominal[r, t, 0] = u[r, t, 0]
        nominal[r, t, 1] = u[r, t, 1]
    for r in range(n):
        m = 0
        for j in range(n):
            if j == r:
                continue
            others[m, 2] = eta[j, t, 2]
            if commands:
                others[m, 0], others[m, 1] = box_centre(boxes, j)
                others[m, 7] = box_error(boxes, j) + box_error(boxes, r)
                told(eta[j, t, 2], prev[j, 0], prev[j, 1], others, m)
            else:
                others[m, 0] = eta[j, t, 0]
                others[m, 1] = eta[j, t, 1]
                others[m, 7] = pose_error
                motion(eta[j, t, 0], eta[j, t, 1], eta[j, t, 2], eta[j, back, 0],
                       eta[j, back, 1], eta[j, back, 2], (t - back) * dt, others, m)
            ages[m] = age
            m += 1
        if commands:
            x, y = box_centre(boxes, r)
        else:
            x, y = eta[r, t, 0], eta[r, t, 1]
        flags[r, t] = filter_command(nominal[r, t, 0], nominal[r, t, 1], x, y, eta[r, t, 2],
                                     prev[r, 0], prev[r, 1], others, ages, m, params, res)
        u[r, t, 0] = res[0]
        u[r, t, 1] = res[1]
    for r in range(n):
        prev[r, 0] = u[r, t, 0]
        prev[r, 1] = u[r, t, 1]
    return missed


@njit(cache=True)
def team_boxes(t: int, eta: NDArray[np.float64], prev: NDArray[np.float64],
               params: NDArray[np.float64], boxes: NDArray[np.float64]) -> int:
    """Every robot's box (``core.estimate``) moved on to sample t: from its pose alone at
    t = 0, else by the command it applied over the sample before (``prev``, what it
    told) from its heading then, cut by its pose of t. Returns how many poses missed
    their box (each starts afresh)."""
    noise, process, heading = params[18], params[19], params[20]
    missed = 0
    for r in range(eta.shape[0]):
        if t == 0:
            box_start(boxes, r, eta[r, 0, 0], eta[r, 0, 1], noise)
        elif not box_step(boxes, r, eta[r, t - 1, 2], prev[r, 0], prev[r, 1], params[8],
                          eta[r, t, 0], eta[r, t, 1], noise, process, heading):
            missed += 1
    return missed
