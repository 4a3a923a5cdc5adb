"""Robot bases the stack can drive, and whether a scenario fits their limits.

A preset names a base's ROS interface (its velocity topic and message type, its odometry
topic, both relative to the base's namespace) and its published speed and acceleration
limits, with where they come from. ``formation-ilc launch --base NAME`` and the generic
bridge (``driver: base``) read them; every value can be overridden per robot
(``--v-max`` ..., or a params file).

Sources of the limits (check them against your robot's own configuration):

* turtlebot3 (Burger): ROBOTIS e-Manual, TurtleBot3 specifications: 0.22 m/s, 2.84 rad/s;
  accelerations: turtlebot3_navigation2's burger parameters (acc_lim_x 2.5, acc_lim_theta
  3.2).
* turtlebot4 (iRobot Create 3 base): Create 3 specifications, 0.306 m/s; 1.9 rad/s, the
  turtlebot4 teleop limit; accelerations as turtlebot3 (Nav2's defaults for this class).
* jackal: Clearpath jackal_control control.yaml: 2.0 m/s, 4.0 rad/s, 20 m/s^2, 25 rad/s^2.
* husky: Clearpath husky_control control.yaml: 1.0 m/s, 2.0 rad/s, 3.0 m/s^2, 6.0 rad/s^2.
Sizes (length x width): the same manufacturers' specifications.

* p3dx (Pioneer 3-DX through this package's RosAria bridge): the bridge's defaults
  0.75 m/s and 100 deg/s (inside the robot's 1.2 m/s and 300 deg/s); ARIA's default
  accelerations 0.3 m/s^2 and 100 deg/s^2.

This is the one limits table of a base: the bridges hold a preset's ``limits``, ``check
--base`` and the launcher check a scenario against them, the safety filter keeps them, and
the physics models of the same base (``model.physics.MODELS``: p3dx, husky, husky-imu)
enforce them on every command. ``hardware`` keeps the maker's maxima, for the record: no
part of the stack drives a base up to them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from formation_ilc.config.scenario import MAX_TIME_SCALE, Scenario
from formation_ilc.core.limits import Limits, check_inputs, scale_needed
from formation_ilc.core.names import bridge_name

__all__ = ["BasePreset", "BASES", "base_preset", "fit_limits", "limits_from_params",
           "with_given", "LIMIT_KEYS"]


@dataclass(frozen=True)
class BasePreset:
    """A base's ROS interface and limits. cmd_type: 'twist' or 'twist_stamped'."""

    name: str
    limits: Limits
    #: length x width [m] of the body, about the odometry's origin (the clearance check)
    size: tuple[float, float] = (0.5, 0.5)
    cmd_topic: str = "cmd_vel"
    cmd_type: str = "twist"
    odom_topic: str = "odom"
    source: str = ""
    #: the maker's maxima, where they are wider than ``limits`` (None: the same)
    hardware: Limits | None = None

    @property
    def limits_line(self) -> str:
        """The limits and where they come from, for a refusal: 'p3dx: 0.75 m/s, 100 deg/s,
        0.3 m/s^2, 100 deg/s^2 (this package's Pioneer bridge; ARIA)'."""
        v, w, a, al = self.limits.as_tuple()
        return (f"{self.name}: {v:g} m/s, {math.degrees(w):.0f} deg/s, {a:g} m/s^2, "
                f"{math.degrees(al):.0f} deg/s^2 "
                f"({self.source})")


BASES: dict[str, BasePreset] = {
    # Jazzy's TurtleBot 3 node takes TwistStamped (its enable_stamped_cmd_vel parameter;
    # with it false, run the bridge with cmd_type twist), and the TurtleBot 4 too
    "turtlebot3": BasePreset("turtlebot3", Limits(0.22, 2.84, 2.5, 3.2), (0.138, 0.178),
                             cmd_type="twist_stamped",
                             source="ROBOTIS e-Manual; turtlebot3_navigation2"),
    "turtlebot4": BasePreset("turtlebot4", Limits(0.306, 1.9, 2.5, 3.2), (0.342, 0.339),
                             cmd_type="twist_stamped",
                             source="Create 3 specifications; turtlebot4 teleop"),
    # Clearpath's ROS 2 platforms: TwistStamped on cmd_vel, wheel odometry on platform/odom
    "jackal": BasePreset("jackal", Limits(2.0, 4.0, 20.0, 25.0), (0.508, 0.430),
                         cmd_type="twist_stamped",
                         odom_topic="platform/odom", source="jackal_control control.yaml"),
    "husky": BasePreset("husky", Limits(1.0, 2.0, 3.0, 6.0), (0.990, 0.670),
                        cmd_type="twist_stamped",
                        odom_topic="platform/odom", source="husky_control control.yaml"),
    "p3dx": BasePreset("p3dx", Limits(0.75, math.radians(100), 0.3, math.radians(100)),
                       (0.455, 0.381),
                       odom_topic="pose", source="this package's Pioneer bridge; ARIA",
                       hardware=Limits(1.2, math.radians(300), 0.3, math.radians(100))),
}


def base_preset(name: str) -> BasePreset:
    try:
        return BASES[name]
    except KeyError:
        raise ValueError(f"no base preset {name!r} (have: {', '.join(BASES)})") from None


def fit_limits(sc: Scenario, limits: list[Limits]) -> str | None:
    """None if the scenario's desired inputs stay inside every robot's limits; otherwise
    one line naming the robot, the time and the value exceeded, and the ``--time-scale``
    that makes it fit (checked on the stretched scenario) or why none does."""
    d = sc.desired
    v = check_inputs(d.u, sc.dt, limits)
    if v is None:
        return None
    guess = scale_needed(d.u, sc.dt, limits) * sc.time_scale
    # the estimate is exact for speeds; round up and check on the stretched plan
    s = math.ceil(guess * 20) / 20
    while s <= MAX_TIME_SCALE:
        stretched = sc.with_options(time_scale=s)
        if check_inputs(stretched.desired.u, stretched.dt, limits) is None:
            return f"{v.line(sc.dt)}; --time-scale {s:g} fits"
        s = math.ceil(s * 1.1 * 20) / 20
    return f"{v.line(sc.dt)}; no time scale up to {MAX_TIME_SCALE:g} fits"


#: a bridge's limit parameters: v_max [m/s], omega_max [deg/s], a_max [m/s^2], alpha_max
#: [deg/s^2] (``--v-max`` ... on the command line); 0 keeps the default
LIMIT_KEYS = ("v_max", "omega_max", "a_max", "alpha_max")


def with_given(base: Limits, given: Mapping[str, Any], where: str = "") -> Limits:
    """``base`` with each value of ``given`` (LIMIT_KEYS, in the bridge's units; 0 keeps
    ``base``'s) in its place: the one rule by which a bridge reads its limit parameters and
    the launcher predicts them. ValueError naming ``where`` and the entry that is not a
    limit."""
    vals = dict(zip(LIMIT_KEYS, base.as_tuple(), strict=True))
    for name, x in given.items():
        if name in LIMIT_KEYS:
            vals[name] = _limit_value(name, x, vals[name], f"{where}{name}")
    return Limits(**vals)


def limits_from_params(base: Limits, n: int, params: dict[str, Any] | None,
                       overrides: dict[str, float], namespace: str = "/formation"
                       ) -> list[Limits]:
    """Each robot's limits as its bridge will hold them: ``base`` (a preset's or the
    bridge's defaults), then a ROS 2 parameters file's entries for ``/**``, ``bridge_I``
    or ``NAMESPACE/bridge_I`` (``ros__parameters``, LIMIT_KEYS), then the command line's
    ``overrides`` (same units). ValueError naming the entry that is not a number."""
    out = []
    for i in range(1, n + 1):
        lim = base
        for key in ("/**", bridge_name(i), f"{namespace.rstrip('/')}/{bridge_name(i)}"):
            entry = (params or {}).get(key) or {}
            rp = entry.get("ros__parameters", {}) if isinstance(entry, dict) else {}
            if isinstance(rp, dict):
                lim = with_given(lim, rp, f"{key}: ")
        for name, x in overrides.items():
            lim = with_given(lim, {name: x}, "--")
        out.append(lim)
    return out


def _limit_value(name: str, x: Any, default: float, where: str) -> float:
    if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) or x < 0:
        where = where.replace("--" + name, "--" + name.replace("_", "-"))
        raise ValueError(f"{where}: a limit >= 0 is required (0 keeps the default), got {x!r}")
    if x == 0:
        return default
    return math.radians(x) if name in ("omega_max", "alpha_max") else float(x)
