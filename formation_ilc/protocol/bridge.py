"""The hardware bridge's logic, free of ROS: limits, watchdog, odometry, return to the start.

The bridge node (``formation_ilc.nodes.pioneer_bridge``) keeps the plant contract for one
robot on top of a Pioneer driver. Everything it decides is here:

* ``CommandLimits.clamp``: the robot node's (v, omega) clamped to the base's limits;
* ``Watchdog``: a zero command once the robot node has been silent longer than a timeout;
* ``compose`` / ``odom_to_world``: the driver's odometry starts where the robot was placed,
  so a world pose is the initial world pose composed with the odometry pose;
* ``ReturnController``: point stabilisation of a unicycle to a goal pose in polar
  coordinates (Astolfi 1999; Aicardi et al. 1995; the form of Siegwart & Nourbakhsh,
  "Introduction to Autonomous Mobile Robots", sec. 3.6.2.4), with a tolerance and a
  timeout, driving backwards when the goal is behind;
* ``initial_shift``: the achieved initial-state shift (b_xi0 of Assumption 2) of a trial.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["CommandLimits", "Watchdog", "compose", "odom_to_world", "wrap",
           "ReturnController", "ReturnStatus", "initial_shift", "PIONEER_V_MAX",
           "PIONEER_OMEGA_MAX"]

# Pioneer 3-DX specification (Adept MobileRobots data sheet): max forward speed 1.2 m/s,
# rotation 300 deg/s. The defaults stay well inside: |v| <= 0.75 m/s, |omega| <= 100 deg/s
# (the drivers' own defaults are of that order; paper-triangle3 needs at most ~0.5 m/s).
PIONEER_V_MAX = 0.75                     # [m/s]
PIONEER_OMEGA_MAX = math.radians(100.0)  # [rad/s]

Pose = tuple[float, float, float]


def wrap(a: float) -> float:
    """Angle in (-pi, pi]."""
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))


@dataclass(frozen=True)
class CommandLimits:
    """Velocity limits of the base [m/s, rad/s]; both must be positive."""

    v_max: float = PIONEER_V_MAX
    omega_max: float = PIONEER_OMEGA_MAX

    def __post_init__(self) -> None:
        if not (self.v_max > 0 and self.omega_max > 0
                and math.isfinite(self.v_max) and math.isfinite(self.omega_max)):
            raise ValueError(f"command limits must be positive and finite, got v_max "
                             f"{self.v_max}, omega_max {self.omega_max}")

    def clamp(self, v: float, omega: float) -> tuple[float, float, bool]:
        """(v, omega) within the limits, and whether anything was clipped. A non-finite
        input is a zero command (clipped)."""
        if not (math.isfinite(v) and math.isfinite(omega)):
            return 0.0, 0.0, True
        cv = max(-self.v_max, min(self.v_max, v))
        cw = max(-self.omega_max, min(self.omega_max, omega))
        return cv, cw, (cv != v or cw != omega)


class Watchdog:
    """A command holds for ``timeout`` seconds after it arrived; then the command is zero."""

    def __init__(self, timeout: float):
        if not timeout > 0:
            raise ValueError(f"watchdog timeout must be positive, got {timeout}")
        self.timeout = timeout
        self.last: float | None = None
        self.expired_count = 0
        self._expired = True

    def feed(self, now: float) -> None:
        self.last = now
        self._expired = False

    def expired(self, now: float) -> bool:
        """True once the last command is older than the timeout (and before any command);
        each silence is counted once in ``expired_count``."""
        if self.last is None or now - self.last > self.timeout:
            if not self._expired:
                self.expired_count += 1
            self._expired = True
            return True
        return False


def compose(a: Pose, b: Pose) -> Pose:
    """Pose ``b`` (given in the frame of pose ``a``) in ``a``'s parent frame (SE(2))."""
    x, y, th = a
    c, s = math.cos(th), math.sin(th)
    return (x + c * b[0] - s * b[1], y + s * b[0] + c * b[1], th + b[2])


def odom_to_world(initial: Pose, odom: Pose) -> Pose:
    """The world pose of a robot whose odometry (starting at 0 where it was placed) reads
    ``odom``, placed at ``initial`` in the world frame."""
    return compose(initial, odom)


def initial_shift(achieved: Pose, desired: Pose) -> Pose:
    """b_xi0 of Assumption 2: the achieved start minus the desired one (heading wrapped)."""
    return (achieved[0] - desired[0], achieved[1] - desired[1],
            wrap(achieved[2] - desired[2]))


@dataclass(frozen=True)
class ReturnStatus:
    """What the return controller says: a command, and whether it is done (``reached`` or
    ``timed_out``); ``error`` is the pose error (rho [m], heading [rad])."""

    v: float
    omega: float
    reached: bool
    timed_out: bool
    rho: float
    heading_error: float

    @property
    def done(self) -> bool:
        return self.reached or self.timed_out


class ReturnController:
    """Drive a unicycle to ``goal`` (world pose) from wherever it is.

    Polar coordinates of the goal seen from the robot: rho (distance), alpha (bearing of
    the goal from the heading), beta = -theta - alpha + theta_goal; the law
    v = k_rho rho, omega = k_alpha alpha + k_beta beta is locally exponentially stable for
    k_rho > 0, k_beta < 0, k_alpha - k_rho > 0 (Siegwart & Nourbakhsh, eq. 3.96). With the
    goal behind (|alpha| > pi/2) it drives backwards (the same law on the reversed heading).
    Inside ``tol_pos`` it turns in place to the goal heading; it is done when within
    ``tol_pos`` and ``tol_heading``, or after ``timeout`` seconds (reported, never hidden).
    Commands are clamped to ``limits``.
    """

    def __init__(self, goal: Pose, limits: CommandLimits, *, tol_pos: float = 0.02,
                 tol_heading: float = math.radians(2.0), timeout: float = 60.0,
                 k_rho: float = 0.6, k_alpha: float = 1.6, k_beta: float = -0.5,
                 k_turn: float = 1.5):
        if not (k_rho > 0 and k_beta < 0 and k_alpha - k_rho > 0):
            raise ValueError("gains: k_rho > 0, k_beta < 0 and k_alpha > k_rho are required")
        if not (tol_pos > 0 and tol_heading > 0 and timeout > 0):
            raise ValueError("tolerances and timeout must be positive")
        self.goal = goal
        self.limits = limits
        self.tol_pos, self.tol_heading, self.timeout = tol_pos, tol_heading, timeout
        self.k_rho, self.k_alpha, self.k_beta, self.k_turn = k_rho, k_alpha, k_beta, k_turn
        self.t0: float | None = None

    def step(self, pose: Pose, now: float, stale: bool = False) -> ReturnStatus:
        """The command at ``now`` [s] for the robot at ``pose``. ``stale``: the pose is
        old (odometry stopped): stop and wait (the timeout still runs)."""
        if self.t0 is None:
            self.t0 = now
        gx, gy, gth = self.goal
        x, y, th = pose
        dx, dy = gx - x, gy - y
        rho = math.hypot(dx, dy)
        dth = wrap(gth - th)
        if rho <= self.tol_pos and abs(dth) <= self.tol_heading:
            return ReturnStatus(0.0, 0.0, True, False, rho, dth)
        if now - self.t0 > self.timeout:
            return ReturnStatus(0.0, 0.0, False, True, rho, dth)
        if stale:
            return ReturnStatus(0.0, 0.0, False, False, rho, dth)
        if rho <= self.tol_pos:
            v, w = 0.0, self.k_turn * dth
        else:
            alpha = wrap(math.atan2(dy, dx) - th)
            sign = 1.0
            if abs(alpha) > math.pi / 2:  # goal behind: drive backwards
                sign = -1.0
                alpha = wrap(alpha + math.pi)
            # beta on the reversed heading is the same expression (both headings + pi)
            beta = wrap(gth - th - alpha)
            v = sign * self.k_rho * rho
            w = self.k_alpha * alpha + self.k_beta * beta
        cv, cw, _ = self.limits.clamp(v, w)
        return ReturnStatus(cv, cw, False, False, rho, dth)
