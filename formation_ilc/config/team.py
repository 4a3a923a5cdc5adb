"""The team of a run: which nodes the leader's schedule waits for before each trial.

One rule for the launcher (which tells the leader, ``nodes_expected``) and for a leader
started alone (``formation-ilc-leader`` without ``nodes_expected``): every robot, the
plant's nodes, the link emulator with emulated links, and the passive readers that must
not miss a trial (the launcher's monitor, a recorder).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from formation_ilc.core.names import (
    LINKS_NODE,
    MONITOR_NODE,
    PHYSICS_NODE,
    RECORDER_NODE,
    SIM_NODE,
    bridge_name,
    robot_name,
)

__all__ = ["PLANTS", "BRIDGED", "Team", "default_plant"]

#: what closes the loop: the kinematic simulator, the physics plant, another process
#: speaking the plant contract, or one bridge per robot (in front of a Pioneer driver, or
#: of any differential-drive base)
PLANTS = ("sim", "physics", "external", "pioneer", "base")
#: the plants whose nodes are one bridge per robot (wall-clock trials, direct links)
BRIDGED = ("pioneer", "base")


def default_plant(mode: str) -> str:
    """The plant a leader started alone assumes: bridges in wall-clock trials (real robots),
    else the simulator."""
    return "pioneer" if mode == "wallclock" else "sim"


@dataclass(frozen=True)
class Team:
    """The nodes of one run by role, in the order the schedule lists them.

    robots : ``robot_1`` .. ``robot_n``.
    plants : the plant's nodes (``robot_sim``; ``physics_sim``; ``bridge_i`` per robot; or
        an external plant's names).
    support : the link emulator with emulated links.
    passive : readers that say ready once for the whole run (monitor, recorder).
    """

    robots: tuple[str, ...]
    plants: tuple[str, ...]
    support: tuple[str, ...] = ()
    passive: tuple[str, ...] = ()

    @classmethod
    def of(cls, n: int, *, plant: str, links: str, external: Sequence[str] = (),
           monitor: bool = False, recorder: bool = False) -> Team:
        """The team of ``n`` robots with ``plant`` (one of PLANTS; ``external``: the
        external plant's node names) and ``links`` ('emulated' or 'direct')."""
        if plant not in PLANTS:
            raise ValueError(f"plant must be one of {', '.join(PLANTS)}, got {plant!r}")
        plants = ((SIM_NODE,) if plant == "sim" else (PHYSICS_NODE,) if plant == "physics"
                  else tuple(bridge_name(i + 1) for i in range(n)) if plant in BRIDGED
                  else tuple(external))
        return cls(robots=tuple(robot_name(i + 1) for i in range(n)), plants=plants,
                   support=(LINKS_NODE,) if links == "emulated" else (),
                   passive=((MONITOR_NODE,) if monitor else ())
                   + ((RECORDER_NODE,) if recorder else ()))

    @property
    def expected(self) -> list[str]:
        """Every node the schedule waits for (the leader's ``nodes_expected``)."""
        return [*self.robots, *self.plants, *self.support, *self.passive]
