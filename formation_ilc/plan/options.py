"""The options of a launched run: one frozen value, every default in one place.

``LaunchOptions`` is what the planner (``formation_ilc.plan.build.build_plan``) reads. It is
built from the command line (each option given overrides its field), from a run file (a
YAML document whose keys ``RUN_KEYS`` maps to fields), from a stored run (the resolved
``run.yaml`` a launch writes into its output folder, or a ``run.json`` of launches before
it) and from a ROS launch file's arguments (through the same command line). Its fields are
the launch options' destinations: ``--safety-margin`` is ``safety_margin``.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

__all__ = ["OptionError", "LaunchOptions", "RunKey", "RUN_KEYS", "FIELD_KEYS", "SECTIONS",
           "closest", "option_fields", "PATH_FIELDS", "STORED_FIELDS", "PLANT_USES",
           "unused_option"]


class OptionError(ValueError):
    """An option (on the command line or in a run file) that cannot be used; the message
    names the option or the key, and why."""


@dataclass(frozen=True)
class LaunchOptions:
    """Every choice of a launched run, with its default (``formation-ilc launch --help``
    says what each means; the run file ``formation-ilc run-file`` writes documents each
    key). None keeps what the scenario or the plant decides."""

    scenario: str | None = None
    #: a scenario written inline in a run file (its YAML text); the run's folder keeps it
    #: as scenario.yaml, which the nodes load
    scenario_text: str | None = None
    trials: int = 20
    law: int | None = None
    memory: str | None = None
    seed: int | None = None
    no_noise: bool = False
    no_delay: bool = False
    headings: str | None = None
    time_scale: float | None = None
    mode: str | None = None
    links: str | None = None
    plant: str = "sim"
    base: str = "turtlebot4"
    physics_bases: bool = False
    v_max: float = 0.0
    omega_max: float = 0.0
    a_max: float = 0.0
    alpha_max: float = 0.0
    params_file: Path | None = None
    robot_model: str = "p3dx"
    pose: str = "truth"
    pass_through: bool = False
    physics_rate: float = 240.0
    allow_contact: bool = False
    safety: bool | None = None
    body: str | None = None
    safety_margin: float | None = None
    safety_learning: str | None = None
    safety_motion: str | None = None
    on_contact: str = "stop"
    contact_retries: int = 2
    tilt_limit: float = 10.0
    driver: str = "rosaria"
    driver_ns: str = "/pioneer_{i}"
    cmd_type: str | None = None
    fake_drivers: bool = False
    lifecycle: bool = False
    return_timeout: float = 60.0
    init_memory: Path | None = None
    plant_nodes: tuple[str, ...] = ("plant",)
    namespace: str | None = None
    container: int = 0
    out: Path | None = None
    domain_id: int | None = None
    discovery: str = "localhost"
    timeout: float = 30.0
    watchdog_scale: float = 1.0
    no_plots: bool = False
    resume: Path | None = None
    max_restarts: int = 3
    record: Path | None = None
    live: int | None = None
    live_rate: float | None = None
    live_host: str = "127.0.0.1"
    hosts: str = "local"
    net_delay_ms: float = 0.0
    net_jitter_ms: float = 0.0
    net_loss: float = 0.0
    dds_profile: str | None = None
    clock_offset_ms: float = 0.0
    clock_drift_ppm: float = 0.0
    no_clock_sync: bool = False
    clock_fallback: str = "estimate"
    secure: Path | None = None
    #: the host whose members this launcher starts (a run file's hosts:); None: all
    host: str | None = None
    #: the run's identity (a new one for a new run; a stored run's own on --resume)
    run_id: str | None = None
    #: the emulated clocks' origin [ns] of a stored run (its robots keep their clocks)
    clock_origin_ns: int | None = None
    #: the run's first recording file, when ``record`` is a resumed launch's part
    record_root: Path | None = None
    #: which machine runs which members: host name -> member (process) names; empty: all
    #: on this machine
    host_members: tuple[tuple[str, tuple[str, ...]], ...] = field(default=())

    def with_fields(self, values: Mapping[str, Any]) -> LaunchOptions:
        """A copy with ``values`` (field -> value) set, each coerced to its field's type
        (paths to ``Path``, lists to tuples)."""
        return replace(self, **{k: _coerce(k, v) for k, v in values.items()})

    def stored(self) -> dict[str, Any]:
        """The fields as JSON values (paths as strings, tuples as lists)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, Path):
                v = str(v)
            elif f.name == "host_members":
                v = {h: list(m) for h, m in v}
            elif isinstance(v, tuple):
                v = list(v)
            out[f.name] = v
        return out


#: fields that hold paths
PATH_FIELDS = ("params_file", "init_memory", "out", "resume", "record", "secure",
               "record_root")
#: fields a stored run keeps beyond the options a user gives
STORED_FIELDS = ("run_id", "clock_origin_ns", "record_root")


def _coerce(name: str, value: Any) -> Any:
    if value is None:
        return None
    if name in PATH_FIELDS:
        return Path(value)
    if name == "plant_nodes":
        return tuple(str(v) for v in value)
    if name == "host_members":
        items = value.items() if isinstance(value, Mapping) else value
        return tuple((str(h), tuple(str(m) for m in ms)) for h, ms in items)
    return value


def option_fields() -> tuple[str, ...]:
    """Every field of ``LaunchOptions``, in order."""
    return tuple(f.name for f in fields(LaunchOptions))


@dataclass(frozen=True)
class RunKey:
    """One key of a run file: ``path`` (``section.key``, or a top-level key), the
    ``LaunchOptions`` field it sets, and whether it is the field negated (``noise: true``
    is ``no_noise`` false)."""

    path: str
    field: str
    negated: bool = False


#: the sections of a run file, in the order it is written, and what each holds
SECTIONS: dict[str, str] = {
    "": "the run",
    "run": "the scenario's draws, the learning law and the reference",
    "plant": "the plant: what the robots are (formation-ilc launch --help: --plant)",
    "safety": "the safety filter and what a contact does (docs/safety.md)",
    "clocks": "the robots' clocks in realtime and wallclock runs",
    "processes": "how the processes run and are supervised",
    "network": "ROS networking, and robots on network namespaces (--hosts netns)",
    "recording": "what the run writes besides its output folder's tables",
    "live": "the Foxglove live view (docs/ros-tools.md)",
    "security": "DDS-Security (docs/security.md)",
}

RUN_KEYS: tuple[RunKey, ...] = (
    RunKey("scenario", "scenario"), RunKey("trials", "trials"), RunKey("mode", "mode"),
    RunKey("links", "links"), RunKey("out", "out"),
    RunKey("run.seed", "seed"), RunKey("run.law", "law"), RunKey("run.memory", "memory"),
    RunKey("run.noise", "no_noise", True), RunKey("run.delay", "no_delay", True),
    RunKey("run.headings", "headings"), RunKey("run.time_scale", "time_scale"),
    RunKey("run.init_memory", "init_memory"), RunKey("run.id", "run_id"),
    RunKey("plant.kind", "plant"), RunKey("plant.base", "base"),
    RunKey("plant.physics_bases", "physics_bases"), RunKey("plant.driver", "driver"),
    RunKey("plant.driver_ns", "driver_ns"), RunKey("plant.cmd_type", "cmd_type"),
    RunKey("plant.fake_drivers", "fake_drivers"), RunKey("plant.lifecycle", "lifecycle"),
    RunKey("plant.return_timeout", "return_timeout"),
    RunKey("plant.v_max", "v_max"), RunKey("plant.omega_max", "omega_max"),
    RunKey("plant.a_max", "a_max"), RunKey("plant.alpha_max", "alpha_max"),
    RunKey("plant.params_file", "params_file"), RunKey("plant.robot_model", "robot_model"),
    RunKey("plant.pose", "pose"), RunKey("plant.collide", "pass_through", True),
    RunKey("plant.physics_rate", "physics_rate"),
    RunKey("plant.allow_contact", "allow_contact"), RunKey("plant.nodes", "plant_nodes"),
    RunKey("safety.enabled", "safety"), RunKey("safety.body", "body"),
    RunKey("safety.margin", "safety_margin"), RunKey("safety.learning", "safety_learning"),
    RunKey("safety.motion", "safety_motion"),
    RunKey("safety.on_contact", "on_contact"),
    RunKey("safety.contact_retries", "contact_retries"),
    RunKey("safety.tilt_limit", "tilt_limit"),
    RunKey("clocks.offset_ms", "clock_offset_ms"), RunKey("clocks.drift_ppm", "clock_drift_ppm"),
    RunKey("clocks.sync", "no_clock_sync", True), RunKey("clocks.fallback", "clock_fallback"),
    RunKey("clocks.origin_ns", "clock_origin_ns"),
    RunKey("processes.container", "container"),
    RunKey("processes.max_restarts", "max_restarts"), RunKey("processes.timeout", "timeout"),
    RunKey("processes.watchdog_scale", "watchdog_scale"),
    RunKey("network.namespace", "namespace"), RunKey("network.domain_id", "domain_id"),
    RunKey("network.discovery", "discovery"), RunKey("network.hosts", "hosts"),
    RunKey("network.delay_ms", "net_delay_ms"), RunKey("network.jitter_ms", "net_jitter_ms"),
    RunKey("network.loss", "net_loss"), RunKey("network.dds_profile", "dds_profile"),
    RunKey("recording.record", "record"), RunKey("recording.record_root", "record_root"),
    RunKey("recording.plots", "no_plots", True),
    RunKey("live.port", "live"), RunKey("live.host", "live_host"),
    RunKey("live.rate", "live_rate"),
    RunKey("security.keystore", "secure"),
)
#: field -> its key
FIELD_KEYS: dict[str, RunKey] = {k.field: k for k in RUN_KEYS}


def closest(word: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'X'?)`` for the choice closest to ``word``, or empty."""
    found = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {found[0]!r}?)" if found else ""


#: the options only some plants use: field -> (whether plant row ``p`` with options ``o``
#: uses it, the plants that do); a value other than the default on another plant is
#: refused (it was ignored). (--allow-contact is a permission, not a setting: not here.)
PLANT_USES: dict[str, tuple[Any, str]] = {
    **{f: (lambda p, o: p.per_robot, "--plant pioneer or base")
       for f in ("params_file", "v_max", "omega_max", "a_max", "alpha_max", "return_timeout",
                 "driver_ns", "cmd_type", "lifecycle")},
    "driver": (lambda p, o: p.driver == "pioneer", "--plant pioneer"),
    "base": (lambda p, o: p.driver == "base", "--plant base"),
    "robot_model": (lambda p, o: p.physics or o.physics_bases,
                    "--plant physics or --physics-bases"),
    "pass_through": (lambda p, o: p.physics or o.physics_bases,
                     "--plant physics or --physics-bases"),
    "pose": (lambda p, o: p.physics or o.physics_bases, "--plant physics or --physics-bases"),
    "physics_rate": (lambda p, o: p.physics, "--plant physics"),
    "on_contact": (lambda p, o: p.physics or o.physics_bases,
                   "--plant physics or --physics-bases: their bodies touch"),
    "contact_retries": (lambda p, o: p.physics or o.physics_bases,
                        "--plant physics or --physics-bases: their bodies touch"),
    "tilt_limit": (lambda p, o: p.physics or o.physics_bases,
                   "--plant physics or --physics-bases: their bodies tilt"),
    "plant_nodes": (lambda p, o: p.entry is None, "--plant external"),
}


def unused_option(opts: LaunchOptions, row: Any) -> str | None:
    """The one line refusing the first option ``opts`` sets that plant ``row``
    (``config.plants.Plant``) does not use, or None."""
    given, defaults = vars(opts), vars(LaunchOptions())
    for name, (uses, which) in PLANT_USES.items():
        if given[name] != defaults[name] and not uses(row, opts):
            return (f"argument --{name.replace('_', '-')}: --plant {row.name} does not use "
                    f"it (it goes with {which})")
    return None
