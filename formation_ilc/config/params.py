"""The ROS parameters of the stack's nodes, described: what each means, its unit, its range.

Pure data (no ROS): ``formation_ilc.nodes.params`` turns a table of ``Param`` into
parameter descriptors (description, range, read-only) and checks what rclpy does not (the
choices of a string, the length of a list). Every parameter here is read at start-up and
read-only afterwards: ``ros2 param set`` of one is refused with rclpy's reason; the node
would not apply a new value mid-run (a run configuration is agreed by every node once).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from formation_ilc.config.bases import BASES
from formation_ilc.config.option_table import default
from formation_ilc.config.runconfig import MODES, PARAMS
from formation_ilc.core.law import MEMORY_MODES

__all__ = ["Param", "RUN", "ROBOT", "LEADER", "SIM", "BRIDGE", "FAKE_DRIVER", "by_name",
           "describe", "PLANT_NAMES", "ROS_NAMES", "known_names", "unknown_key"]

#: the largest integer a parameter range takes (rcl's ranges are int64)
BIG = 2**62


@dataclass(frozen=True)
class Param:
    """One ROS parameter: name, default (its type is the parameter's type), what it means,
    its unit ("" for none), an inclusive numeric range, or the strings it may be."""

    name: str
    default: Any
    description: str
    units: str = ""
    lo: float | None = None
    hi: float | None = None
    choices: tuple[Any, ...] = ()
    #: once the node runs, the parameter reads what the run uses, which the run
    #: configuration (the leader's ``config`` topic, or a preset) may override
    effective: str = ""

    def check(self, value: Any) -> str | None:
        """Why ``value`` is refused (what rclpy's descriptor does not check), or None."""
        if self.choices and value not in self.choices:
            return f"one of {choice_text(self.choices)}; got {value!r}"
        return None


def choice_text(choices: tuple[Any, ...]) -> str:
    """The choices of a parameter for a user: 'a, b' (an empty text shown as '')."""
    return ", ".join(str(c) if c != "" else repr(c) for c in choices)


def by_name(table: tuple[Param, ...]) -> dict[str, Param]:
    return {p.name: p for p in table}


def describe(p: Param) -> str:
    """The descriptor's description: the meaning, then unit and range or choices."""
    extra = []
    if p.units:
        extra.append(f"unit: {p.units}")
    if p.lo is not None or p.hi is not None:
        extra.append(f"range: {p.lo if p.lo is not None else '-inf'} .. "
                     f"{p.hi if p.hi is not None else 'inf'}")
    if p.choices:
        extra.append(f"one of: {choice_text(p.choices)}")
    if p.effective:
        extra.append(f"reads the value in use once running: {p.effective}")
    return p.description + (f" ({'; '.join(extra)})" if extra else "")


_LINKS = ("emulated", "direct")

#: the run configuration (``config.runconfig.PARAMS``): the leader's, and the robot's and
#: bridge's when they start without the leader's ``config`` topic
RUN: tuple[Param, ...] = (
    Param("scenario", PARAMS["scenario"], "scenario name (a built-in) or YAML file"),
    Param("seed", PARAMS["seed"], "seed of the uncertainty draws; -1 keeps the scenario's",
          lo=-1, hi=BIG),
    Param("trials", PARAMS["trials"], "number of trials; 0 keeps the scenario's",
          lo=0, hi=BIG),
    Param("law", PARAMS["law"], "learning law of the paper (eq. 9, 22 or 23); 0 keeps the "
          "scenario's", lo=0, hi=BIG, choices=(0, 9, 22, 23)),
    Param("memory", PARAMS["memory"], "memory variant of the law; empty keeps the "
          "scenario's", choices=("", *MEMORY_MODES)),
    Param("noise", PARAMS["noise"], "draw the scenario's disturbances and noises "
          "(false: --no-noise)"),
    Param("delay", PARAMS["delay"], "the scenario's link delays (false: --no-delay)"),
    Param("mode", PARAMS["mode"], "how the plant keeps time", choices=MODES),
    Param("links", PARAMS["links"], "emulated: the link emulator carries the scenario's "
          "delays; direct: the robots subscribe to each other", choices=_LINKS),
    Param("gap", PARAMS["gap"], "samples between two trials on the label grid",
          "samples", lo=1, hi=BIG),
    Param("monitored", PARAMS["monitored"], "a monitor (the launcher) reads trajectories: "
          "nodes wait for it before trial 0"),
    Param("recorded", PARAMS["recorded"], "a recorder writes the run: nodes that publish "
          "trajectories wait for it before trial 0"),
    Param("timeout", PARAMS["timeout"], "lockstep: how long the plant waits for a robot's "
          "command before it stops", "s", lo=1e-3, hi=1e6),
    Param("run_id", PARAMS["run_id"], "identity of the run; nodes of another run on the "
          "same domain and namespace are refused"),
    Param("headings", PARAMS["headings"], "desired headings: chord (fits the Euler model), "
          "arc (robots that drive arcs), auto (by plant); empty keeps the scenario's",
          choices=("", "chord", "arc", "auto")),
    Param("time_scale", PARAMS["time_scale"], "stretch the reference and formation in "
          "time by this factor; 0 keeps the scenario's", lo=0.0, hi=1e3),
    Param("safety", PARAMS["safety"], "the safety filter every robot's command goes "
          "through: JSON of formation_ilc.config.safety.SafetySettings (body, limits, "
          "margin, learning, sensing); empty: no filter"),
)

_RUN = by_name(RUN)

#: what the leader's parameters that "keep the scenario's" read once it runs
_SCENARIO_KEPT = "the scenario's value when it keeps the scenario's"
_LEADER_RUN = tuple(
    replace(p, effective=_SCENARIO_KEPT) if p.name in ("seed", "trials", "law", "memory",
                                                        "headings", "time_scale") else p
    for p in RUN)
#: what a robot's or a bridge's run parameters read once the leader's configuration came
_FROM_CONFIG = "the run configuration's (the leader's config topic), which overrides it"

LEADER: tuple[Param, ...] = _LEADER_RUN + (
    Param("start_margin", 1.0, "wallclock: from the start event to the agreed start time",
          "s", lo=1e-3, hi=1e6),
    Param("nodes_expected", [""], "node names that must say ready before a trial starts; "
          "empty: the default team", effective="the team waited for"),
    Param("state_dir", "", "folder of the leader's schedule (leader.json); empty: none"),
    Param("watchdog_scale", 1.0, "every bound of the leader's watchdog times this",
          lo=1e-3, hi=1e6),
    Param("clocks", "", "the clock estimator and emulated clocks of realtime and "
          "wall-clock runs, broadcast in the run configuration: JSON of "
          "formation_ilc.config.clocks.ClockSettings (sync, fallback, offset_ms, drift_ppm, "
          "origin_ns); empty: the defaults (the estimator on, no emulation)"),
    Param("exit_when_done", False, "end the leader's process (status 0) once it has said "
          "done: a launch file stops the other nodes with it"),
)

ROBOT: tuple[Param, ...] = (
    Param("robot_id", 1, "1-based robot number; the node is named robot_<id>", lo=1,
          hi=BIG),
    *(replace(_RUN[n], effective=_FROM_CONFIG)
      for n in ("scenario", "seed", "noise", "delay", "links", "mode")),
    Param("init_memory", "", "memory.npz of formation-ilc simulate: start from this "
          "robot's row of learned memory"),
    Param("state_dir", "", "folder of the robot's learning state (robot_<id>.npz); "
          "empty: none"),
)

SIM: tuple[Param, ...] = (
    Param("timeout", 0.0, "lockstep: how long the simulator waits for a robot's command; "
          "0: the run configuration's", "s", lo=0.0, hi=1e6,
          effective="the run configuration's when 0"),
)

#: a bridge's limit reads the limit in force (the preset's or the Pioneer's when 0)
_LIMIT_USED = "the limit in force (the preset's or the Pioneer's when 0)"

BRIDGE: tuple[Param, ...] = (
    Param("robot_id", 1, "1-based robot number; the node is named bridge_<id>", lo=1,
          hi=BIG),
    Param("driver", default("driver"), "the robot's driver (a base preset sets 'base')",
          choices=("rosaria", "p2os2", "ros2aria", "base"), effective="'base' with a preset"),
    Param("base", "", "a differential-drive base's preset (topics, message type, limits); "
          "empty: a Pioneer driver", choices=("", *BASES)),
    Param("driver_ns", "", "namespace of the driver's topics; empty: the driver's usual",
          effective="the namespace used"),
    Param("cmd_type", "", "type of the driver's command; empty: a base preset's, else twist",
          choices=("", "twist", "twist_stamped"), effective="the type sent"),
    Param("v_max", 0.0, "clamp of the linear speed; 0: the Pioneer's", "m/s", lo=0.0,
          hi=100.0, effective=_LIMIT_USED),
    Param("omega_max", 0.0, "clamp of the turn rate; 0: the Pioneer's", "deg/s", lo=0.0,
          hi=36000.0, effective=_LIMIT_USED),
    Param("a_max", 0.0, "limit of the linear acceleration; 0: the preset's (none for a "
          "Pioneer driver)", "m/s^2", lo=0.0, hi=1000.0, effective=_LIMIT_USED),
    Param("alpha_max", 0.0, "limit of the angular acceleration; 0: the preset's (none for "
          "a Pioneer driver)", "deg/s^2", lo=0.0, hi=1e6, effective=_LIMIT_USED),
    Param("max_tilt", 10.0, "largest roll or pitch of the odometry accepted (reported); "
          "beyond it the odometry is refused", "deg", lo=0.0, hi=90.0),
    Param("cmd_timeout", 0.0, "zero command once the robot node is silent this long; "
          "0: 2.5 dT", "s", lo=0.0, hi=1e6, effective="2.5 dT when 0"),
    Param("rate", 20.0, "rate the command is republished to the driver", "Hz", lo=0.1,
          hi=1000.0),
    Param("return_tol", 0.02, "between trials: position tolerance of the return", "m",
          lo=1e-6, hi=100.0),
    Param("return_tol_heading", 2.0, "between trials: heading tolerance of the return",
          "deg", lo=1e-6, hi=180.0),
    Param("return_timeout", default("return_timeout"), "between trials: longest return "
          "before it is counted as timed out", "s", lo=1e-3, hi=1e6),
    Param("initial_pose", [0.0], "x, y, theta [m, m, rad] where the robot is placed; "
          "[0.0]: the scenario's desired start"),
    Param("truth", False, "the base is simulated and publishes its true pose on 'truth' in "
          "the driver namespace (formation-ilc-physics-bases -p truth:=true): the bridge "
          "publishes each trial's true trajectory, for the metrics' true columns"),
    Param("pose_topic", "", "the robot's world pose (geometry_msgs/PoseStamped in the world "
          "frame, relative to the driver namespace unless absolute): motion capture or a "
          "localiser, what the bridge samples, returns on and tells the others under the "
          "safety filter; '': the driver's wheel odometry from where the robot was placed "
          "(it drifts: docs/safety.md)"),
    Param("lifecycle", False, "a managed (lifecycle) node: it starts unconfigured; "
          "configure checks the driver's topics, activate enables the motors and lets "
          "commands through, deactivate and shutdown send zero and stop"),
    Param("clock_wait", 10.0, "before trial 0: the longest wait, from the leader's first "
          "clock answer, for the estimate of its clock to converge; then it samples on the "
          "fallback", "s", lo=0.0, hi=1e6),
    replace(_RUN["scenario"], effective=_FROM_CONFIG),
    Param("mode", "wallclock", "how the plant keeps time (a bridge needs wallclock)",
          choices=MODES, effective=_FROM_CONFIG),
)

FAKE_DRIVER: tuple[Param, ...] = (
    Param("driver", "rosaria", "which driver's topics to speak", choices=("rosaria",
                                                                           "ros2aria")),
    Param("rate", 50.0, "odometry rate", "Hz", lo=0.1, hi=1000.0),
    Param("cmd_timeout", 0.6, "stop once the newest command is older", "s", lo=1e-3,
          hi=1e6),
    Param("odom_scale", 0.01, "odometry's scale error on distance", lo=-1.0, hi=1.0),
    Param("odom_turn_scale", -0.01, "odometry's scale error on rotation", lo=-1.0, hi=1.0),
    Param("odom_turn_bias", 0.002, "odometry's rotation bias", "rad/s", lo=-10.0, hi=10.0),
    Param("odom_noise", 0.002, "white noise on the published pose", "m", lo=0.0, hi=10.0),
    Param("seed", 0, "seed of the odometry noise", lo=0, hi=BIG),
    Param("cmd_type", "twist", "type of the command", choices=("twist", "twist_stamped")),
    Param("truth_period", 0.0, "tests: period of the truth report; 0: none", "s", lo=0.0,
          hi=1e6),
)

#: the parameters of the nodes whose tables live beside them (``robot_sim.physics_node``,
#: ``robot_sim.physics_base``: their choices come from layers above this one); a test
#: checks this list against those tables
PLANT_NAMES = frozenset({
    "model", "pose", "rate", "collide", "on_contact", "contact_retries", "tilt_limit",
    "robots", "poses", "tick", "ns_pattern", "cmd_type", "odom_topic", "cmd_timeout", "truth"})
#: parameters rclpy itself declares or reads on every node
ROS_NAMES = frozenset({"use_sim_time", "start_type_description_service"})


def known_names() -> frozenset[str]:
    """Every parameter name some node of the stack takes (a ``/**`` section of a params
    file may hold another node's)."""
    tables = (RUN, LEADER, ROBOT, SIM, BRIDGE, FAKE_DRIVER)
    return frozenset(p.name for t in tables for p in t) | PLANT_NAMES | ROS_NAMES


def unknown_key(key: str, own: tuple[str, ...] | list[str]) -> str | None:
    """Why ``key``, given to a node whose parameters are ``own``, is refused, naming the
    closest known name; None for a name some node of the stack takes (another node's,
    from a ``/**`` section, is left to that node) or one of ROS's."""
    import difflib

    if key in known_names() or key.startswith("qos_overrides."):
        return None
    close = (difflib.get_close_matches(key, list(own), n=1, cutoff=0.6)
             or difflib.get_close_matches(key, sorted(known_names()), n=1, cutoff=0.6))
    hint = f"did you mean {close[0]}?" if close else \
        f"this node's are {', '.join(own) if own else 'none'}"
    return f"parameter {key}: no node of formation-ilc has this parameter ({hint})"
