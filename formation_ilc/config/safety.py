"""A run's safety filter settings, as the nodes share them in the run configuration.

The launcher decides them (``formation-ilc launch --safety``; on by default on every plant
with bodies) and the leader broadcasts them inside the run configuration, so every robot
filters with the same body, limits and margin (``formation_ilc.model.safety.spec_of``
turns them into the filter's ``core.safety.SafetySpec``).

body : the name of the robots' body (``model.footprint.BODIES``): its footprint, covered by
    two discs.
limits : the base's speed and acceleration limits the filter keeps (and the learned
    commands are held inside): v_max [m/s], omega_max [rad/s], a_max [m/s^2],
    alpha_max [rad/s^2].
margin : [m] the least gap between two robots' covering discs.
learning : how the memory learns where the filter changed a command (``core.safety.LEARNING``).
sensing : how a robot hears the other robots' poses: 'team' (the plant's ``team/poses``,
    every robot's pose of a sample in one message) or 'peers' (every other robot's
    ``pose`` topic: plants of one bridge per robot).
motion : where a robot takes the other robots' speeds from: 'poses' (estimated from two
    of their poses, widened by what the poses' noise allows) or 'commands' (each robot
    tells the others the command it applies, on ``robot_i/applied``: the speed is known,
    only its direction comes from a pose; a robot whose command is not heard is estimated
    from its poses).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from formation_ilc.core.clock import Rejected
from formation_ilc.core.limits import Limits
from formation_ilc.core.safety import LEARNING

__all__ = ["SafetySettings", "SENSING", "MOTION", "TOLD_UP_TO", "default_motion", "BODIES",
           "SKID_STEER", "default_learning", "default_margin", "MARGIN", "SKID_MARGIN"]

SENSING = ("team", "peers")
#: where a robot takes another robot's speed from
MOTION = ("poses", "commands")
#: teams up to this size tell each other their commands unless told otherwise (every
#: robot hears every other's: N (N - 1) messages a sample); larger teams estimate speeds
#: from the poses they already hear (docs/safety.md, "Speeds told, not guessed")
TOLD_UP_TO = 12


def default_motion(n: int, bridged: bool = False) -> str:
    """Where a team of ``n`` robots takes the others' speeds from unless told otherwise:
    'commands' up to TOLD_UP_TO robots, 'poses' beyond, and behind bridges (``bridged``:
    each base on its own clock, a robot commands without waiting for the others' told
    commands, and one that is late turns that sample's filter back to the estimate: two
    wall-clock runs of the same rehearsal then differed by 0.28 m in a trial)."""
    return "commands" if n <= TOLD_UP_TO and not bridged else "poses"
#: [m] added to two disc radii: the least gap the filter keeps between two bodies'
#: covering discs unless told (it covers the discs' excess over the rectangle, the arcs a
#: robot drives within a sample and the poses' noise): on two wheels, and on skid steer
#: (default_margin)
MARGIN = 0.1
SKID_MARGIN = 0.25
#: bodies the filter knows (``model.footprint.BODIES``, kept here for the config layer)
BODIES = ("p3dx", "husky", "husky-imu", "turtlebot3", "turtlebot4", "jackal")
#: the skid-steer bodies among them
SKID_STEER = ("husky", "husky-imu", "jackal")


def default_learning(body: str, noisy: bool = False) -> str:
    """How a team of ``body`` robots learns through its filter unless told otherwise
    (docs/safety.md measured it): ``damped`` on two wheels, ``robust`` there when the
    scenario's poses are noisy (the Q-filter on every learning step: the paper's law would
    learn the noise, and the filter's limits clip it more every trial); ``split`` on skid
    steer (``robust`` was not measured there)."""
    if body in SKID_STEER:
        return "split"
    return "robust" if noisy else "damped"


def default_margin(body: str) -> float:
    """The gap [m] the filter keeps between ``body`` robots' covering discs unless told
    otherwise: 0.1 m on two wheels; 0.25 m on skid steer, whose wheels slip sideways in
    every turn, so that the body is where its command says only to within centimetres
    (docs/safety.md: a Husky team touched by 1.7 cm with 0.1 m, not with 0.25 m)."""
    return SKID_MARGIN if body in SKID_STEER else MARGIN


@dataclass(frozen=True)
class SafetySettings:
    body: str = "p3dx"
    limits: Limits = Limits()
    margin: float = MARGIN
    learning: str = "damped"
    sensing: str = "team"
    motion: str = "poses"

    def __post_init__(self) -> None:
        if self.body not in BODIES:
            raise ValueError(f"safety body: one of {', '.join(BODIES)}, got {self.body!r}")
        if not (self.margin >= 0 and math.isfinite(self.margin)):
            raise ValueError(f"safety margin: a distance >= 0 [m], got {self.margin!r}")
        if self.learning not in LEARNING:
            raise ValueError(f"safety learning: one of {', '.join(LEARNING)}, got "
                             f"{self.learning!r}")
        if self.sensing not in SENSING:
            raise ValueError(f"safety sensing: one of {', '.join(SENSING)}, got "
                             f"{self.sensing!r}")
        if self.motion not in MOTION:
            raise ValueError(f"safety motion: one of {', '.join(MOTION)}, got "
                             f"{self.motion!r}")

    def to_json(self) -> dict[str, Any]:
        return {"body": self.body, "limits": [_num(x) for x in self.limits.as_tuple()],
                "margin": self.margin, "learning": self.learning, "sensing": self.sensing,
                "motion": self.motion}

    @classmethod
    def from_json(cls, d: Any) -> SafetySettings:
        """Settings of a JSON object; Rejected (malformed) naming what is wrong."""
        try:
            lim = [math.inf if x is None else float(x) for x in d["limits"]]
            if len(lim) != 4:
                raise ValueError("limits: 4 numbers")
            # a run stored before "motion" existed took the speeds from poses
            return cls(str(d["body"]), Limits(*lim), float(d["margin"]),
                       str(d["learning"]), str(d["sensing"]), str(d.get("motion", "poses")))
        except (KeyError, TypeError, ValueError) as exc:
            raise Rejected("malformed", f"bad safety settings: {exc}") from None


def _num(x: float) -> float | None:
    """JSON has no inf: an absent limit is null."""
    return None if math.isinf(x) else x
