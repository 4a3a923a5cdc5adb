"""The processes of a plan: one ``NodeSpec`` per roster member that has an entry script,
with its arguments, ROS remaps and parameters (``node_specs``), and the entry scripts'
modules and ``ros2 run`` executables."""

from __future__ import annotations

import functools
import json
from typing import Any

from formation_ilc.config.clocks import ClockSettings
from formation_ilc.config.roster import ENTRY_SCRIPTS, Member
from formation_ilc.core.names import (
    BASE_TRUTH,
    BASES_NODE,
    namespace_remaps,
    robots_process_name,
)
from formation_ilc.plan.specs import NodeSpec, NoRun, RestartPolicy, RunPlan

__all__ = ["node_specs", "entry_module", "ROS2_RUN", "ros2_executable"]


def node_specs(plan: RunPlan, scenario: str) -> tuple[NodeSpec, ...]:
    """Every process of ``plan``: the roster's members that have an entry script, in its
    start order (the recorder, which listens before the run starts, the live view, the
    leader, the plant and what it drives, the link emulator, the robots), each with its
    launch parameters. ``scenario`` is what the leader loads (``scenario_reference``)."""
    nsa = tuple(namespace_remaps(plan.namespace))
    policy = RestartPolicy(plan.max_restarts)
    specs: list[NodeSpec] = []
    robots: list[Member] = []
    for m in plan.roster.processes:
        if m.role == "robot":
            robots.append(m)
            continue
        args, remaps, params = _launch(plan, m, scenario, nsa)
        specs.append(NodeSpec(m.name, entry_module(m.entry or ""), args=args, remaps=remaps,
                              params=params, restart=policy, passive=m.waits == "once",
                              optional=m.optional))
    state_dir = str(plan.out / "state")
    robot: tuple[tuple[str, Any], ...] = (
        ((("init_memory", str(plan.init_memory.resolve())),) if plan.init_memory else ())
        + (("state_dir", state_dir),))
    module = entry_module("formation-ilc-robot")
    if plan.container > 0:
        for c in range(0, len(robots), plan.container):
            grp = [m.robot or 0 for m in robots[c:c + plan.container]]
            specs.append(NodeSpec(robots_process_name(grp[0], grp[-1]), module,
                                  args=("--robots", *map(str, grp)), remaps=nsa, params=robot,
                                  restart=policy))
    else:
        for m in robots:
            specs.append(NodeSpec(m.name, module, remaps=nsa,
                                  params=(("robot_id", m.robot), *robot), restart=policy,
                                  host=m.robot if plan.hosts is not None else None))
    return tuple(specs)


Launch = tuple[tuple[str, ...], tuple[str, ...], tuple[tuple[str, Any], ...]]


def _launch(plan: RunPlan, m: Member, scenario: str, nsa: tuple[str, ...]) -> Launch:
    """(arguments, ROS remaps, ROS parameters) of member ``m``'s process, from the plan's
    options."""
    cfg = plan.config
    if m.role == "recorder":
        return ("--output", str(plan.record)), nsa, ()
    if m.role == "liveview":
        assert plan.live is not None
        # the view topics come from the recorder; without one the bridge makes them
        return (("--host", plan.live[0], "--port", str(plan.live[1]),
                 *(("--observe",) if plan.record is None else ()),
                 # the simulator and the physics plant publish a preview
                 *(("--preview",) if plan.row.true_state else ()),
                 *(("--rate", repr(plan.live_rate)) if plan.live_rate is not None else ())),
                nsa, ())
    if m.role == "leader":
        leader = {**cfg.to_params(scenario), "state_dir": str(plan.out / "state"),
                  "nodes_expected": plan.team.expected}
        if plan.watchdog_scale != 1.0:
            leader["watchdog_scale"] = float(plan.watchdog_scale)
        if cfg.clocks != ClockSettings():
            leader["clocks"] = json.dumps(cfg.clocks.to_json())
        return (), nsa, tuple(leader.items())
    bridge, phys = plan.bridge, plan.physics
    if m.role == "support" and m.name != BASES_NODE:  # the link emulator
        return (), nsa, ()
    if m.role == "plant" and m.robot is None:  # one node for the team
        params: tuple[tuple[str, Any], ...] = (("timeout", float(cfg.timeout)),)
        if plan.row.physics and phys is not None:
            params += (("model", phys.model), ("pose", phys.pose), ("collide", phys.collide),
                       ("rate", float(phys.rate)), ("on_contact", phys.on_contact),
                       ("contact_retries", phys.contact_retries),
                       ("tilt_limit", float(phys.tilt_limit)))
        return (), nsa, params
    if m.role == "plant":  # robot i's bridge
        assert bridge is not None and m.robot is not None
        # a params file goes with the ROS arguments, before the -p parameters (which win)
        pf = () if bridge.params_file is None else ("--params-file", str(bridge.params_file))
        truth: tuple[tuple[str, Any], ...] = ()
        if plan.roster.lineup.bases_truth:
            truth = (("truth", True),)
            if phys is not None and phys.pose == "truth":
                # the physics bases' ground truth is the rehearsal's motion capture: the
                # bridge samples, returns and is avoided on it, not on drifting odometry
                truth += (("pose_topic", BASE_TRUTH),)
        return (), nsa + pf, bridge.params(m.robot) + truth
    if m.robot is not None:  # robot i's fake driver, in the driver's namespace
        assert bridge is not None
        return ((), ("-r", f"__ns:={bridge.namespace(m.robot)}"),
                (("seed", m.robot), ("cmd_type", bridge.sent_type), ("driver", bridge.driver)))
    # the physics bases: every robot's base in one world
    from formation_ilc.config.bases import base_preset

    assert bridge is not None and bridge.base is not None and phys is not None
    preset = base_preset(bridge.base)
    starts = [float(x) for x in plan.scenario.desired.eta[:, 0].ravel()]
    return (), nsa, (("robots", plan.scenario.n), ("poses", starts),
                     ("ns_pattern", bridge.driver_ns), ("cmd_type", bridge.sent_type),
                     ("odom_topic", preset.odom_topic), ("model", phys.model),
                     ("collide", phys.collide), ("truth", True),
                     ("on_contact", phys.on_contact), ("contact_retries", phys.contact_retries),
                     ("tilt_limit", float(phys.tilt_limit)))


def entry_module(script: str) -> str:
    """The module an entry script runs (``pyproject.toml``'s ``[project.scripts]``, as
    installed), started as ``python -m MODULE``; NoRun when it is not installed."""
    found = _entry_modules().get(script)
    if found is None:
        raise NoRun(f"the entry script {script!r} is not installed: install the package "
                    f"again (pip install -e .)")
    return found


@functools.cache
def _entry_modules() -> dict[str, str]:
    from importlib.metadata import entry_points

    return {ep.name: ep.value.split(":")[0]
            for ep in entry_points(group="console_scripts") if ep.name.startswith("formation-ilc")}


# --------------------------------------------------------------------------- ros2 launch

#: the ``ros2 run formation_ilc`` executable of each node's entry script (``ros2_run/``):
#: the script's name without its prefix, dashes as underscores (one list: ENTRY_SCRIPTS)
ROS2_RUN = {s: s.removeprefix("formation-ilc-").replace("-", "_") for s in ENTRY_SCRIPTS}


def ros2_executable(module: str) -> str:
    """The ``ros2 run formation_ilc`` executable that runs node module ``module``."""
    script = {m: s for s, m in _entry_modules().items()}[module]
    return ROS2_RUN[script]
