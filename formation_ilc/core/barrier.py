"""The safety filter's steps up to its half-planes (``core.safety.filter_command`` composes them).

1. :func:`numbers` (the spec's numbers), :func:`own_reach`: this robot's box of commands (its
   limits) and how far a command of the box carries it (held for a sample, then braked),
   bounded by chords over the box; :func:`wish_reach`: the learned command's own.
2. :func:`heard_motion`: another robot heard: how far it may close in, from its estimated or
   told motion, and whether it is near enough to matter.
3. :func:`pair_constraints`: per pair of discs of the two bodies, the braking invariant as
   one or two half-planes in the scaled command plane (v, c omega), this robot's part of the
   pair's slack given by :func:`share`.

``core.nearest`` then finds the command nearest to the wish inside the box cut by them.
Every step is a kernel (``core._jit.njit``): plain Python where a node calls it, compiled
where the batch simulator does. Values pass between the steps as named tuples of Python
floats (a node runs the steps uncompiled: numpy scalars cost 3x in arithmetic there).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import floats, njit

__all__ = ["PARAMS", "Numbers", "Reach", "Wish", "Chords", "Heard", "numbers", "limits_box",
           "own_reach", "wish_reach", "chords", "heard_motion", "pair_constraints", "share",
           "planes_room", "turn_closing"]

#: the order of ``SafetySpec.params()`` (the disc offsets follow)
PARAMS = ("distance", "discs", "gamma", "radius", "v_max", "omega_max", "a_max",
          "alpha_max", "dt", "stale_speed", "weight", "speed_uncertainty", "brake_share",
          "lag", "commands", "own_bound", "told_uncertainty", "pose_error", "noise",
          "process", "heading_error")
_TOL = 1e-12
#: a limit of inf is no limit: the box is cut at this [m/s, rad/s] instead (polygon
#: clipping needs finite corners)
_BIG = 1e6
#: how far the split of a pair's slack leans towards the robot that heads towards the
#: other (0: halves; 1: all of it; below 1 each robot keeps a share, 1 - _SPLIT of its half)
_SPLIT = 0.9


class Numbers(NamedTuple):
    """The spec's numbers the pairs read (``SafetySpec.params()``, as Python floats), the
    largest disc offset, and how far a measured heading can be off (``heading``, rad)."""

    dist: float
    n_discs: int
    share: float
    radius: float
    a_max: float
    al_max: float
    dt: float
    stale: float
    c: float
    sigma: float
    lag: float
    told_sigma: float
    off0: float
    off1: float
    off2: float
    l_max: float
    heading: float


class Reach(NamedTuple):
    """This robot's sample: the box of commands, its braking, and how far a command of the
    box carries it (the chords of f and g, their errors, the most braking closes in)."""

    v_lo: float
    v_hi: float
    w_lo: float
    w_hi: float
    a_b: float
    al_b: float
    vb: float
    wb: float
    fv0: float
    kv: float
    ev_up: float
    ev_dn: float
    kw: float
    ew_up: float
    ew_dn: float
    g_off: float
    lines_p: bool
    lines_m: bool
    path_i: float
    q_i: float
    f_b: float
    g_b: float
    e_i: float
    w_i: float
    t_close: float


class Wish(NamedTuple):
    """The learned command: in scaled coordinates (zx, zy) = (v_n, c omega_n), where the
    cost is Euclidean; whether it lies inside the box, whether it is judged by its own
    bound (``judge``), and its own carried distance, turn and path."""

    zx: float
    zy: float
    inside: bool
    judge: bool
    f_n: float
    g_n: float
    path_n: float
    q_n: float


class Chords(NamedTuple):
    """What every half-plane of a sample reads, in one tuple (``pair_constraints`` reads it
    into locals once a robot): the chords of f and g over the box (slope, offset, errors
    above and below), which lines of the max the box reaches, the box in scaled coordinates,
    the wish."""

    kv: float
    v_off: float
    ev_up: float
    ev_dn: float
    kw: float
    c: float
    g_off: float
    ew_up: float
    ew_dn: float
    lines_p: bool
    lines_m: bool
    bx0: float
    bx1: float
    by0: float
    by1: float
    zx: float
    zy: float


class Heard(NamedTuple):
    """Another robot, as one sample's pairs need it: where it is taken to be (moved on by its
    age), the distance its discs keep (D widened), its closing bounds, its heading, the path
    it brakes along (``path_j``) and how far its heading can be off (``dev_j``, rad).

    Robot j's closing towards robot i (``pair_constraints``, per pair of discs): its
    tracked point's closing speed s_j, taken ``sig`` faster than it looks, over its braking
    time (``tau_j``). The disc's swing is not a speed that lasts that long: the turn stops
    within its own braking, and the swing it makes is at most |ellj| turn_j. Counted as a
    speed, a swing away from robot i was credited for the whole of a straight braking: two
    Pioneers returning side by side closed 2.3 cm past D. Robot j recedes (s_j < 0) while
    robot i may close in: the sum of their closings peaks at the end of both brakings only
    if robot i's closing slows no faster than robot j's receding does (i's closing factor x
    its deceleration at most j's: ``tau_jlo``); else it can peak while robot j still
    recedes, and j is credited only up to t_close (``tau_jsoon``; a fuzz of pairs side by
    side found 6 mm past D at dT 0.2 s with the whole credit)."""

    near: bool
    ox: float
    oy: float
    dj: float
    vxj: float
    vyj: float
    sig: float
    v_dn: float
    tau_j: float
    tau_jlo: float
    tau_jsoon: float
    turn_j: float
    rot_j: float
    e_j: float
    cj: float
    sj: float
    path_j: float
    dev_j: float


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
def limits_box(v_prev: float, w_prev: float, v_max: float, w_max: float, a_max: float,
               al_max: float, dt: float) -> tuple[float, float, float, float]:
    """The box of commands the base's limits allow after (v_prev, w_prev): (v_lo, v_hi,
    w_lo, w_hi); where the previous command lies outside a speed limit, its nearest edge."""
    v_lo = max(-v_max, v_prev - a_max * dt, -_BIG)
    v_hi = min(v_max, v_prev + a_max * dt, _BIG)
    w_lo = max(-w_max, w_prev - al_max * dt, -_BIG)
    w_hi = min(w_max, w_prev + al_max * dt, _BIG)
    if v_lo > v_hi:  # the previous command lies outside the speed limit: nearest edge
        v_lo = v_hi = v_max if v_prev > 0 else -v_max
    if w_lo > w_hi:
        w_lo = w_hi = w_max if w_prev > 0 else -w_max
    return v_lo, v_hi, w_lo, w_hi


@njit(cache=True)
def numbers(params: NDArray[np.float64]) -> Numbers:
    """The numbers of ``SafetySpec.params()`` the pairs read, as Python floats (a node runs
    this uncompiled: numpy scalars cost 3x in arithmetic)."""
    q = floats(params)
    n_discs = int(q[1])
    off0 = q[len(PARAMS)]
    off1 = q[len(PARAMS) + 1] if n_discs > 1 else 0.0
    off2 = q[len(PARAMS) + 2] if n_discs > 2 else 0.0
    return Numbers(q[0], n_discs, q[2], q[3], q[6], q[7], q[8], q[9], q[10], q[11], q[13],
                   q[16], off0, off1, off2, max(abs(off0), abs(off1), abs(off2)), q[20])


@njit(cache=True)
def own_reach(v_prev: float, w_prev: float, k: Numbers,
              params: NDArray[np.float64]) -> Reach:
    """This robot's sample: the box of its limits, its braking command (vb, wb), and how
    far a command carries it: held for a sample, then braked to a stop, f(v) = v dT +
    v |v| / (2 a) along its heading, g(w) = w dT + w |w| / (2 alpha) of turn. Over the box
    each is replaced by its chord (slope k, offset e): the chord plus e bounds the function
    from above and minus e from below (|f''| <= 1 / a)."""
    a_max, al_max, dt = k.a_max, k.al_max, k.dt
    brake = float(params[12])
    v_lo, v_hi, w_lo, w_hi = limits_box(v_prev, w_prev, float(params[4]), float(params[5]),
                                        a_max, al_max, dt)
    # braking: the deceleration counted on (a share of the limit), and this robot's own
    # braking command (a sample of braking from the previous command, inside the box)
    a_b = brake * a_max if a_max < _BIG else _BIG
    al_b = brake * al_max if al_max < _BIG else _BIG
    vb = _clip(_toward_zero(v_prev, a_max * dt), v_lo, v_hi)
    wb = _clip(_toward_zero(w_prev, al_max * dt), w_lo, w_hi)
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
    l_max = k.l_max
    q_i = 0.5 * (path_i + l_max) * turn
    f_b, g_b = _carry(vb, dt, a_b), _carry(wb, dt, al_b)
    # G's chord on the box (slope kw, through (w_lo, G(w_lo))) and its error ew; on a box
    # on one side of w = 0 only that side's line of the max counts
    kw = (gw1 - gw0) / (w_hi - w_lo) if w_hi > w_lo else dt + abs(w_lo) / al_b
    ew = (w_hi - w_lo) * (w_hi - w_lo) / (8.0 * al_b)
    ew_up, ew_dn = _chord_errors(w_lo, w_hi, kw, dt, al_b)
    # the most robot i's braking closes in (e_i) and the most a command of the box can
    # change that (w_i), for the test that skips robots too far to matter
    e_i = path_i + (l_max + path_i + q_i) * (turn + ew) + ev
    w_i = kv * (v_hi - v_lo) + (l_max + path_i + q_i) * kw * (w_hi - w_lo)
    # the earliest robot i can have closed in all a command of the box closes in: its
    # carried distance f(v) over its speed, dT + |v| / (2 a), at the box's least |v|
    v_least = 0.0 if v_lo <= 0.0 <= v_hi else min(abs(v_lo), abs(v_hi))
    t_close = dt + v_least / (2.0 * a_b) if a_b < _BIG else dt
    return Reach(v_lo, v_hi, w_lo, w_hi, a_b, al_b, vb, wb, fv0, kv, ev_up, ev_dn, kw, ew_up,
                 ew_dn, gw0 - kw * w_lo, w_hi > 0.0, w_lo < 0.0, path_i, q_i, f_b, g_b, e_i,
                 w_i, t_close)


@njit(cache=True)
def wish_reach(v_n: float, w_n: float, k: Numbers, r: Reach, own_bound: bool) -> Wish:
    """The learned command (v_n, w_n) as the pairs judge it: inside the box or not, and
    (judged by its own bound where it is inside and ``own_bound``) its own carried
    distance, turn and path (``pair_constraints``)."""
    inside = not (v_n < r.v_lo - _TOL or v_n > r.v_hi + _TOL or w_n < r.w_lo - _TOL
                  or w_n > r.w_hi + _TOL)
    path_n = _carry(abs(v_n), k.dt, r.a_b)
    g_n = _carry(w_n, k.dt, r.al_b)
    return Wish(v_n, k.c * w_n, inside, inside and own_bound, _carry(v_n, k.dt, r.a_b), g_n,
                path_n, 0.5 * (path_n + k.l_max) * abs(g_n))


@njit(cache=True)
def chords(k: Numbers, r: Reach, w: Wish) -> Chords:
    """The sample's :class:`Chords`, from its numbers, reach and wish."""
    c = k.c
    return Chords(r.kv, r.fv0 - r.kv * r.v_lo, r.ev_up, r.ev_dn, r.kw, c, r.g_off, r.ew_up,
                  r.ew_dn, r.lines_p, r.lines_m, r.v_lo, r.v_hi, c * r.w_lo, c * r.w_hi, w.zx,
                  w.zy)


@njit(cache=True)
def heard_motion(ox: float, oy: float, oth: float, vxj: float, vyj: float, wj: float,
                 told_j: bool, err: float, age: float, x: float, y: float, k: Numbers,
                 r: Reach) -> Heard:
    """Another robot as this sample's pairs need it, from its row of ``filter_command``'s
    ``others`` (pose ox, oy, oth; motion vxj, vyj, wj, ``told_j`` or estimated; ``err``, how
    far the two positions can be off together) and its pose's ``age``; ``near`` False: beyond
    the sensing radius, or so far apart that no command of the box can meet a barrier.
    Scalars, not the array: a compiled call that passes an array pays for its reference
    count."""
    gx, gy = x - ox, y - oy
    gg = gx * gx + gy * gy
    if gg > k.radius * k.radius:
        return Heard(False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                     0.0, 0.0, 0.0, 0.0)
    a_max, dt, a_b = k.a_max, k.dt, r.a_b
    # robot j: its estimated speed, how wrong it may be, how far it closes in braking
    swj = abs(wj)
    spj = math.sqrt(vxj * vxj + vyj * vyj)
    # the estimate is a mean over the window, ``lag`` old: since then robot j's speed
    # changed by at most a_max lag, its direction by |omega| lag; a told command is
    # the speed itself (no lag), its direction as good as the pose's heading
    lag_j = 0.0 if told_j else k.lag
    sig = ((k.told_sigma if told_j else k.sigma) + a_max * (lag_j + age)
           + spj * swj * (lag_j + age + 0.5 * dt))
    # a pose ``age`` s old: robot j has moved on since, as its motion says, to within
    # sig x age of there; or, if its speed limit (``stale``) says less, within that of
    # where it was
    stale = k.stale
    ahead = age > 0.0 and not (0.0 < stale <= sig)
    dj = k.dist + err + (sig if ahead or stale <= 0.0 else stale) * age
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
    # (tau_jsoon, at t_close): see :class:`Heard`
    tau_jlo = (_carry(v_dn - a_max * dt, dt, a_max) / v_dn if v_dn > a_max * dt
               else 0.0)
    tau_jsoon = (_receded(v_dn - a_max * dt, dt, a_max, r.t_close) / v_dn
                 if v_dn > a_max * dt else 0.0)
    turn_j = _carry(swj + k.al_max * (lag_j + age), dt, r.al_b)
    path_j = _carry(spj + sig, dt, a_b)
    rot_j = (path_j + 0.5 * k.l_max * turn_j) * turn_j
    e_j = v_up * tau_j + k.l_max * turn_j + rot_j
    # so far apart that no command of the box can meet a barrier
    gap0 = math.sqrt(gg) - 2.0 * k.l_max - dj
    near = not (k.share * (1.0 - _SPLIT) * (gap0 - r.e_i - e_j) >= r.w_i)
    oth += wj * age if ahead else 0.0
    # its heading as taken here is off by the pose's error, and by what it turned since a
    # pose ``age`` s old beyond what its motion says (``turn_closing``)
    dev_j = k.heading + (swj + k.al_max * (lag_j + age)) * age
    return Heard(near, ox, oy, dj, vxj, vyj, sig, v_dn, tau_j, tau_jlo, tau_jsoon, turn_j,
                 rot_j, e_j, math.cos(oth), math.sin(oth), path_j, dev_j)


@njit(cache=True)
def turn_closing(h: Heard, ellj: float, dx: float, dy: float, l_max: float) -> float:
    """How far [m] robot j's turn while it brakes (at most ``h.turn_j``) can bring its disc at
    offset ``ellj`` closer to the other along the unit vector (dx, dy) (from j's disc to
    the other's): its path (``h.path_j`` long) and the disc's offset swing by up to their
    length x the turn in all, |l (h(phi) - h(0))| <= l phi; along (dx, dy) that is at most
    l (phi |n . h_perp| + phi^2 / 2 |n . h|) <= l (phi |n . h_perp| + phi^2 / 2): the first
    order only sideways to its heading (known to within ``h.dev_j``), where a robot that
    drives along the line between the two moves little (the second order keeps the old
    bound's l_max phi^2 / 2 besides). The lesser of the two bounds. (Robot 1 ahead of
    robot 3 in paper-triangle3, turning at 0.2 rad/s, was counted 26-36 mm of closing for
    a turn that moves it across the line to robot 3, not along it: 1-6 mm.)"""
    whole = abs(ellj) * h.turn_j + h.rot_j
    perp = min(1.0, abs(dx * h.sj - dy * h.cj) + h.dev_j)
    arm = abs(ellj) + h.path_j
    side = (arm * perp + 0.5 * (arm + l_max) * h.turn_j) * h.turn_j
    return min(whole, side)


@njit(cache=True)
def share(gamma: float, a0: float, dx: float, dy: float, cj: float, sj: float) -> float:
    """This robot's share of a pair's slack. It is split by the poses, which both robots see
    alike: the more a robot heads towards the other (its closing factor ``a0``, along the
    unit vector (dx, dy) from the other's disc to its own) than the other towards it
    (heading (cj, sj)), the more is its own (19 parts in 20 for a robot behind another that
    drives away, 1 for the one ahead, which brakes or drives on without closing in); the two
    shares add up to 2 gamma <= 1."""
    return gamma * (1.0 + 0.5 * _SPLIT * (a0 - dx * cj - dy * sj))


@njit(cache=True)
def planes_room(count: int, n_discs: int) -> int:
    """How many half-planes ``pair_constraints`` can add for ``count`` robots heard: two per
    pair of discs."""
    return 2 * count * n_discs * n_discs


@njit(cache=True)
def pair_constraints(k: Numbers, r: Reach, w: Wish, p: Chords, h: Heard, x: float, y: float,
                     cth: float, sth: float, ha0: NDArray[np.float64], ha1: NDArray[np.float64],
                     hb: NDArray[np.float64], m: int) -> tuple[int, bool, bool]:
    """The half-planes ha0 v + ha1 (c w) >= hb that keep this robot's part of the braking
    invariant with robot ``h``, per pair of discs, added from row m on (only where the box
    does not keep one whole). Returns the new row count, whether one cuts the wish off (a
    barrier moves the command), and whether a pair's slack was already negative (outside
    the guarantee). A pair of discs: this robot's at offset ``ell``, robot j's at ``ellj``,
    (dx, dy) the unit vector from j's to this one's, ``dd`` apart; robot i keeps X_i(u) <=
    room = B_i + its share of the pair's slack (:func:`share`), h0 v + max(sp G, sm G) <=
    base with the chords: a half-plane per line of the max (slope sp or sm) the box reaches."""
    barrier = False
    infeasible = False
    # what every pair reads, as locals (a node runs this uncompiled: a named tuple's
    # field costs a lookup each time, and a call per pair of discs more than its sums)
    kw, c, g_off, ew_up, ew_dn, kv, v_off = p.kw, p.c, p.g_off, p.ew_up, p.ew_dn, p.kv, p.v_off
    bx0, bx1, by0, by1, zx, zy = p.bx0, p.bx1, p.by0, p.by1, p.zx, p.zy
    lines_p, lines_m, ev_up, ev_dn, e_i, w_i = p.lines_p, p.lines_m, p.ev_up, p.ev_dn, r.e_i, r.w_i
    path_i, q_i, f_b, g_b, a_b, a_max = r.path_i, r.q_i, r.f_b, r.g_b, r.a_b, k.a_max
    n_discs, gamma, off0, off1, off2 = k.n_discs, k.share, k.off0, k.off1, k.off2
    ox, oy, dj, e_j, cj, sj, sig = h.ox, h.oy, h.dj, h.e_j, h.cj, h.sj, h.sig
    vxj, vyj, v_dn, tau_j, l_max = h.vxj, h.vyj, h.v_dn, h.tau_j, k.l_max
    for a in range(n_discs):
        ell = off0 if a == 0 else (off1 if a == 1 else off2)
        sx, sy = x + ell * cth - ox, y + ell * sth - oy
        for b in range(n_discs):
            ellj = off0 if b == 0 else (off1 if b == 1 else off2)
            dx, dy = sx - ellj * cj, sy - ellj * sj
            dd = math.sqrt(dx * dx + dy * dy)
            if dd < 1e-9:  # coincident centres: no direction to keep
                continue
            if gamma * (1.0 - _SPLIT) * (dd - dj - e_i - e_j) >= w_i:
                continue  # this pair of discs is too far apart to matter
            dx, dy = dx / dd, dy / dd
            # robot i's closing displacement X_i(u) <= a0 F(v) + |a0| ev + max(sp G, sm G)
            # + max(|sp|, |sm|) ew: its disc moves along M(th, ell) = [[cos, -ell sin],
            # [sin, ell cos]], a0 = -n^T M e_v, a1c = -n^T M e_w = ell b
            a0 = -(dx * cth + dy * sth)
            bside = dx * sth - dy * cth
            a1c = ell * bside
            sp = a1c + (path_i * bside if bside > 0.0 else 0.0) + q_i
            sm = a1c + (path_i * bside if bside < 0.0 else 0.0) - q_i
            # braking now (vb, wb) closes in by b_i, as f and g give it (the chords of a
            # command may lie above: at a slack of 0 braking may be all that is left)
            b_i = a0 * f_b + (sp * g_b if g_b >= 0.0 else sm * g_b)
            # robot j's closing: its speed towards i over its braking time, its disc's
            # swing (:class:`Heard` has why)
            s_j = dx * vxj + dy * vyj + sig
            if s_j >= 0.0:
                r_j = s_j * tau_j
            elif v_dn > 0.0 and a0 * a_b * v_dn <= -s_j * a_max:
                r_j = s_j * h.tau_jlo
            else:
                r_j = s_j * h.tau_jsoon
            b_j = r_j + turn_closing(h, ellj, dx, dy, l_max)
            slack = dd - dj - b_i - b_j
            if slack < 0.0:
                infeasible = True
                slack = 0.0
            room = b_i + share(gamma, a0, dx, dy, cj, sj) * slack
            # X_i(u) <= room, as h0 v + (a line of the max) <= base
            h0 = a0 * kv
            base = room - a0 * v_off - (a0 * ev_up if a0 >= 0.0 else -a0 * ev_dn)
            top0 = h0 * bx1 if h0 >= 0.0 else h0 * bx0
            for li in range(2):
                if not (lines_p if li == 0 else lines_m):
                    continue
                slope = sp if li == 0 else sm
                h1 = slope * kw / c
                lim = base - slope * g_off - (slope * ew_up if slope >= 0.0 else -slope * ew_dn)
                # the largest h0 v + h1 (c w) over the box, at one of its corners
                if top0 + (h1 * by1 if h1 >= 0.0 else h1 * by0) <= lim:
                    continue  # holds over the whole box
                if h0 * zx + h1 * zy > lim + _TOL and not _wish_keeps(w, a0, a1c, bside, room):
                    barrier = True
                ha0[m] = -h0
                ha1[m] = -h1
                hb[m] = -lim
                m += 1
    return m, barrier, infeasible


@njit(cache=True)
def _wish_keeps(w: Wish, a0: float, a1c: float, bside: float, room: float) -> bool:
    """Whether the learned command keeps a pair of discs' X_i(u) <= room by its own bound
    (``pair_constraints``): its closing bounded as the box's commands are, but with its own
    path and turn in place of the box's largest. The chords, which make the feasible set a
    polygon, hold for every command of the box and lie above it; a learned command that
    keeps its own bound keeps the invariant, and passes (the paper's triangle on Pioneers:
    its desired motion kept it where the chords were off by 2-3 mm)."""
    if not w.judge:
        return False
    bend = w.path_n * bside
    g_n, q_n = w.g_n, w.q_n
    x_n = a0 * w.f_n + (
        (a1c + (bend if bside > 0.0 else 0.0) + q_n) * g_n if g_n >= 0.0
        else (a1c + (bend if bside < 0.0 else 0.0) - q_n) * g_n)
    return x_n <= room + _TOL
