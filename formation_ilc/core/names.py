"""Node names of the distributed stack: the one place that spells them.

A node's name is what it says ready as, what its diagnostics carry, what the leader's
schedule waits for (``formation_ilc.config.team``) and what the launcher calls its process
and log file. Nodes, the launcher, the leader's membership rule and ``msgs_schema`` (which
re-exports them) import them from here; this module needs no ROS, so the launcher's plan
and the membership rule are testable without it.

Robots are 1-based in names (``robot_1``), as in topic names.
"""

from __future__ import annotations

from formation_ilc.core.clock import Malformed

__all__ = ["NAMESPACE", "CLOCK", "LEADER_NODE", "SIM_NODE", "LINKS_NODE", "MONITOR_NODE",
           "RECORDER_NODE", "FAKE_DRIVER_NODE", "PHYSICS_NODE", "BASES_NODE",
           "ROBOT_PREFIX", "BRIDGE_PREFIX", "robot_name",
           "robot_number", "bridge_name", "fake_driver_name", "robots_process_name",
           "namespace_remaps"]

#: the default namespace of every node of a formation
NAMESPACE = "/formation"
#: the ROS convention's absolute clock topic: the one name a namespaced formation remaps
#: (msgs_schema re-exports it with the other topic names)
CLOCK = "/clock"

#: the virtual leader (reference, schedule, run configuration)
LEADER_NODE = "virtual_leader"
#: the kinematic simulator, the plant of simulated runs
SIM_NODE = "robot_sim"
#: the physics plant (PyBullet, every robot in one world)
PHYSICS_NODE = "physics_sim"
#: physics robots behind a base's interface (cmd_vel in, odometry out), for runs of the
#: base bridges without robots
BASES_NODE = "physics_bases"
#: the link emulator (emulated links)
LINKS_NODE = "link_emulator"
#: the launcher's monitor (metrics from the wire)
MONITOR_NODE = "monitor"
#: the recorder (MCAP)
RECORDER_NODE = "recorder"
#: a fake Pioneer driver (tests and runs without robots); one per robot, in the driver's
#: namespace, so the node name is the same for every robot
FAKE_DRIVER_NODE = "fake_pioneer"

ROBOT_PREFIX = "robot_"
#: a hardware bridge's node name is ``bridge_<id>`` (what it says ready as)
BRIDGE_PREFIX = "bridge_"


def robot_name(i: int) -> str:
    """Name of robot ``i`` (1-based): ``robot_i``; also its node name and topic prefix."""
    return f"{ROBOT_PREFIX}{int(i)}"


def robot_number(name: str) -> int:
    """1-based robot number of ``robot_i``; Malformed if ``name`` is not one (ASCII digits,
    no leading zero, at least 1)."""
    digits = name[len(ROBOT_PREFIX):]
    if not (name.startswith(ROBOT_PREFIX) and digits.isascii() and digits.isdigit()
            and digits[0] != "0"):
        raise Malformed(f"not a robot name: {name!r}")
    return int(digits)


def bridge_name(i: int) -> str:
    """Node name of robot ``i``'s hardware bridge: ``bridge_i``."""
    return f"{BRIDGE_PREFIX}{int(i)}"


def fake_driver_name(i: int) -> str:
    """The launcher's process (and log) name of robot ``i``'s fake driver."""
    return f"{FAKE_DRIVER_NODE}_{int(i)}"


def robots_process_name(first: int, last: int) -> str:
    """The launcher's process (and log) name of a container of robots first..last."""
    return f"robots_{int(first)}-{int(last)}"


def namespace_remaps(namespace: str | None) -> list[str]:
    """ROS arguments that put a node into ``namespace``, /clock included (nothing for the
    default one)."""
    if namespace is None or namespace == NAMESPACE:
        return []
    return ["-r", f"__ns:={namespace}", "-r", f"{CLOCK}:={namespace}{CLOCK}"]

#: the live view's bridge to Foxglove viewers (``launch --live``)
LIVEVIEW_NODE = "liveview"
__all__ += ["LIVEVIEW_NODE"]
