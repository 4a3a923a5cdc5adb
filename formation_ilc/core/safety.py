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

from formation_ilc.core._jit import floats, njit
from formation_ilc.core.barrier import (
    PARAMS,
    chords,
    heard_motion,
    numbers,
    own_reach,
    pair_constraints,
    planes_room,
    wish_reach,
)
from formation_ilc.core.estimate import box_centre, box_error, box_start, box_step
from formation_ilc.core.limits import Limits
from formation_ilc.core.nearest import nearest_to_wish

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

#: the columns of a robot heard (``filter_command``'s ``others``): pose (x, y, theta),
#: motion (vx, vy, omega), 1 where that motion is the command the robot told (``told``),
#: 0 where it is estimated from its poses (``motion``), and how far this robot's position
#: and robot j's, as the filter has them, can be off together [m] (the pair's distance
#: grows by it: ``pose_error`` for raw poses, two boxes' half-diagonals for estimates,
#: ``core.estimate``)
OTHER_FIELDS = 8
#: at most this many discs cover a body
MAX_DISCS = 3
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

    The steps, each a kernel of its own: this robot's box and reach (``barrier.own_reach``),
    each other robot's motion (``barrier.heard_motion``), the pairs' half-planes with this
    robot's share of their slack (``barrier.pair_constraints``, ``barrier.share``), the
    command nearest to the wish (``nearest.nearest_to_wish``).
    """
    x, y = float(x), float(y)
    k = numbers(params)
    r = own_reach(float(v_prev), float(w_prev), k, params)
    w = wish_reach(float(v_n), float(w_n), k, r, float(params[15]) > 0.0)
    p = chords(k, r, w)
    flags = 0 if w.inside else CHANGED_LIMITS
    room = planes_room(count, k.n_discs)
    ha0, ha1, hb = np.empty(room), np.empty(room), np.empty(room)
    m = 0
    barrier = False
    infeasible = False
    cth, sth = math.cos(float(th)), math.sin(float(th))
    heard, heard_ages = floats(others[:count]), floats(ages[:count])
    for j in range(count):
        # robot j: its pose, motion (told or estimated), the pair's position error, age
        o = heard[j]
        h = heard_motion(o[0], o[1], o[2], o[3], o[4], o[5], o[6] > 0.0, o[7], heard_ages[j],
                         x, y, k, r)
        if h.near:
            m, bar, bad = pair_constraints(k, r, w, p, h, x, y, cth, sth, ha0, ha1, hb, m)
            barrier = barrier or bar
            infeasible = infeasible or bad
    if infeasible:
        # a pair's slack was negative before this sample (a pose or a body off by more
        # than the filter accounts for): outside the guarantee, flagged even where the
        # command closes in no more than braking and passes unchanged
        flags |= INFEASIBLE
    if not barrier and flags & CHANGED == 0:
        out[0] = w.zx
        out[1] = float(w_n)
        return flags
    if barrier:
        flags |= CHANGED_BARRIER
    return nearest_to_wish(k, r, w, ha0, ha1, hb, m, flags, out)


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
