"""The plant table: one row per kind of plant, everything the stack knows of it.

A plant closes the loop for the robots (the contract is in ``msgs_schema``'s docstring):
the kinematic simulator, the physics plant, another process speaking the contract, or one
bridge per robot in front of a driver (a Pioneer's, or any differential-drive base's). The
roster (``formation_ilc.config.roster``) builds a run's processes, the leader's team and
every enclave's permissions from a row; the launcher's options, refusals and report read
it too. A new plant is one row here, its node file and its entry script
(docs/architecture.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from formation_ilc.core.names import PHYSICS_NODE, SIM_NODE

__all__ = ["Plant", "PLANT_TABLE", "PLANTS", "BRIDGED", "SECURE_PLANTS", "plant",
           "default_plant"]


@dataclass(frozen=True)
class Plant:
    """One kind of plant.

    name : ``--plant NAME``.
    node : the node name of a plant that drives the whole team from one process (the
        simulator's, the physics plant's); None for one node per robot (``per_robot``) or an
        external plant (its names are the user's, ``--plant-nodes``).
    entry : the entry script that starts its node (``pyproject.toml``); None: the launcher
        starts nothing for it (an external plant).
    per_robot : one bridge per robot (``bridge_i``) in front of a driver: real robots, with
        wall-clock trials and direct links only.
    driver : what each bridge drives: 'pioneer' (a Pioneer driver, ``names.DRIVERS``; fake
        drivers possible) or 'base' (a base preset of ``config.bases``; physics bases
        possible); None without bridges.
    true_state : it publishes the robots' true trajectories (metrics' true columns) and a
        preview of the team for the live view.
    clock : it publishes ``/clock`` (simulated time: lockstep or realtime trials).
    physics : its node takes the physics options (``--robot-model``, ``--pose``, ...).
    reports : the launcher waits for its last trial's diagnostics (timing, missed samples,
        the bridges' returns) before it writes the report.
    headings : the desired headings an 'auto' run takes on it: 'arc' on plants that drive
        arcs (and came with the option), 'euler' (chords) where runs and learned memories
        keep their numbers from before.
    bodies : the robots have bodies: the safety filter is on by default, the batch
        simulator's contact check runs first, and ``--body`` is the plant's to say.
    secure : ``launch --secure`` and ``keystore create --plant NAME`` grant its nodes.
    hosts : ``--hosts netns`` (each robot on a network host of its own) can run it.
    help : one line for ``--plant``'s help.
    """

    name: str
    node: str | None
    entry: str | None
    per_robot: bool = False
    driver: str | None = None
    true_state: bool = False
    clock: bool = False
    physics: bool = False
    reports: bool = True
    headings: str = "euler"
    bodies: bool = False
    secure: bool = True
    hosts: bool = False
    help: str = ""

    @property
    def sensing(self) -> str | None:
        """How a robot's safety filter hears the others on this plant: 'team' (the plant's
        ``team/poses``, every robot's pose of a sample in one message), 'peers' (each other
        robot's own pose topic, behind bridges), None (an external plant: no filter)."""
        return "peers" if self.per_robot else "team" if self.node is not None else None


#: every kind of plant, in the order ``--plant`` lists them
PLANT_TABLE: tuple[Plant, ...] = (
    Plant("sim", SIM_NODE, "formation-ilc-robot-sim", true_state=True, clock=True, hosts=True,
          help="start the kinematic simulator"),
    Plant("physics", PHYSICS_NODE, "formation-ilc-physics-sim", true_state=True, clock=True,
          physics=True, headings="arc", bodies=True,
          help="the PyBullet rigid-body plant (docs/physics.md)"),
    Plant("external", None, None, reports=False, secure=False,
          help="another process speaks the plant contract (docs/distributed-stack.md) and "
               "says ready as one of --plant-nodes"),
    Plant("pioneer", None, "formation-ilc-bridge", per_robot=True, driver="pioneer",
          bodies=True, help="one Pioneer bridge per robot (formation-ilc-bridge, "
                            "docs/real-robots.md) in front of a driver (--driver), "
                            "wall-clock trials, direct links"),
    Plant("base", None, "formation-ilc-bridge", per_robot=True, driver="base",
          headings="arc", bodies=True,
          help="the same bridges in front of any differential-drive base (--base)"),
)

#: the plants by name
PLANT_ROWS: dict[str, Plant] = {p.name: p for p in PLANT_TABLE}
#: their names, in the order ``--plant`` lists them
PLANTS: tuple[str, ...] = tuple(PLANT_ROWS)
#: the plants whose nodes are one bridge per robot (wall-clock trials, direct links)
BRIDGED: tuple[str, ...] = tuple(p.name for p in PLANT_TABLE if p.per_robot)
#: the plants whose nodes the keystore grants (``launch --secure``)
SECURE_PLANTS: tuple[str, ...] = tuple(p.name for p in PLANT_TABLE if p.secure)


def plant(name: str) -> Plant:
    """The row of plant ``name``; ValueError naming the plants if there is none."""
    try:
        return PLANT_ROWS[name]
    except KeyError:
        raise ValueError(f"plant must be one of {', '.join(PLANTS)}, got {name!r}") from None


def default_plant(mode: str) -> str:
    """The plant a leader started alone assumes: bridges in wall-clock trials (real robots),
    else the simulator."""
    return "pioneer" if mode == "wallclock" else "sim"
