"""The options of a launched run: one frozen value, every default in one place.

``LaunchOptions`` is what the planner (``formation_ilc.plan.build.decide``) reads. It is
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

from formation_ilc.config.option_table import (
    OPTIONS,
    SECTIONS,
    RobotEntry,
    default,
    option,
    robot_entries,
)

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

    scenario: str | None = default("scenario")
    #: a scenario written inline in a run file (its YAML text); the run's folder keeps it
    #: as scenario.yaml, which the nodes load
    scenario_text: str | None = default("scenario_text")
    trials: int = default("trials")
    law: int | None = default("law")
    memory: str | None = default("memory")
    seed: int | None = default("seed")
    no_noise: bool = default("no_noise")
    no_delay: bool = default("no_delay")
    headings: str | None = default("headings")
    time_scale: float | None = default("time_scale")
    mode: str | None = default("mode")
    links: str | None = default("links")
    plant: str = default("plant")
    base: str = default("base")
    physics_bases: bool = default("physics_bases")
    #: the bridges' limits in their options' units (deg/s for omega_max); None: the
    #: preset's or the bridge's
    v_max: float | None = default("v_max")
    omega_max: float | None = default("omega_max")
    a_max: float | None = default("a_max")
    alpha_max: float | None = default("alpha_max")
    params_file: Path | None = default("params_file")
    robot_model: str = default("robot_model")
    pose: str = default("pose")
    pass_through: bool = default("pass_through")
    physics_rate: float = default("physics_rate")
    allow_contact: bool = default("allow_contact")
    safety: bool | None = default("safety")
    body: str | None = default("body")
    safety_margin: float | None = default("safety_margin")
    safety_learning: str | None = default("safety_learning")
    safety_motion: str | None = default("safety_motion")
    on_contact: str = default("on_contact")
    contact_retries: int = default("contact_retries")
    tilt_limit: float = default("tilt_limit")
    driver: str = default("driver")
    driver_ns: str = default("driver_ns")
    cmd_type: str | None = default("cmd_type")
    fake_drivers: bool = default("fake_drivers")
    lifecycle: bool = default("lifecycle")
    return_timeout: float = default("return_timeout")
    init_memory: Path | None = default("init_memory")
    plant_nodes: tuple[str, ...] = default("plant_nodes")
    namespace: str | None = default("namespace")
    container: int = default("container")
    out: Path | None = default("out")
    domain_id: int | None = default("domain_id")
    discovery: str = default("discovery")
    timeout: float = default("timeout")
    watchdog_scale: float = default("watchdog_scale")
    no_plots: bool = default("no_plots")
    resume: Path | None = default("resume")
    max_restarts: int = default("max_restarts")
    record: Path | None = default("record")
    live: int | None = default("live")
    live_rate: float | None = default("live_rate")
    live_host: str = default("live_host")
    hosts: str = default("hosts")
    net_delay_ms: float = default("net_delay_ms")
    net_jitter_ms: float = default("net_jitter_ms")
    net_loss: float = default("net_loss")
    dds_profile: str | None = default("dds_profile")
    clock_offset_ms: float = default("clock_offset_ms")
    clock_drift_ppm: float = default("clock_drift_ppm")
    no_clock_sync: bool = default("no_clock_sync")
    clock_fallback: str = default("clock_fallback")
    secure: Path | None = default("secure")
    #: the host whose members this launcher starts (a run file's hosts:); None: all
    host: str | None = default("host")
    #: the run's identity (a new one for a new run; a stored run's own on --resume)
    run_id: str | None = default("run_id")
    #: the emulated clocks' origin [ns] of a stored run (its robots keep their clocks)
    clock_origin_ns: int | None = default("clock_origin_ns")
    #: the run's first recording file, when ``record`` is a resumed launch's part
    record_root: Path | None = default("record_root")
    #: what robots do not share with the team: a run file's robots: (host, driver
    #: namespace, start pose), by robot
    robots: tuple[RobotEntry, ...] = default("robots")
    #: which machine runs which members: host name -> member (process) names; empty: all
    #: on this machine
    host_members: tuple[tuple[str, tuple[str, ...]], ...] = field(
        default=default("host_members"))

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
            elif f.name == "robots":
                v = {e.robot: e.as_dict() for e in v}
            elif isinstance(v, tuple):
                v = list(v)
            out[f.name] = v
        return out


#: fields that hold paths
PATH_FIELDS = tuple(o.field for o in OPTIONS if o.is_path)
#: fields a stored run keeps beyond the options a user gives
STORED_FIELDS = tuple(o.field for o in OPTIONS if o.kind == "stored" and o.key is not None)
#: the bridges' limits, where 0 meant "the preset's" before None did
_LIMITS = ("v_max", "omega_max", "a_max", "alpha_max")


def _coerce(name: str, value: Any) -> Any:
    if value is None:
        return None
    if name in _LIMITS and value == 0:  # a run file or run.json of before: the preset's
        return None
    if name in PATH_FIELDS:
        return Path(value)
    if name == "plant_nodes":
        return tuple(str(v) for v in value)
    if name == "robots":
        return robot_entries(value)
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


RUN_KEYS: tuple[RunKey, ...] = tuple(
    RunKey(o.key or "", o.field, o.negated) for o in sorted(
        (o for o in OPTIONS if o.key is not None), key=lambda o: list(SECTIONS).index(o.section)))
#: field -> its key
FIELD_KEYS: dict[str, RunKey] = {k.field: k for k in RUN_KEYS}


def closest(word: str, choices: Iterable[str]) -> str:
    """`` (did you mean 'X'?)`` for the choice closest to ``word``, or empty."""
    found = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {found[0]!r}?)" if found else ""


#: the options only some plants use: field -> (whether plant row ``p`` with options ``o``
#: uses it, the plants that do); a value other than the default on another plant is
#: refused (it was ignored). (--allow-contact is a permission, not a setting: not here.)
PLANT_USES: dict[str, tuple[Any, str]] = {o.field: o.uses for o in OPTIONS
                                          if o.uses is not None}


def unused_option(opts: LaunchOptions, row: Any) -> str | None:
    """The one line refusing the first option ``opts`` sets that plant ``row``
    (``config.plants.Plant``) does not use, or None."""
    given, defaults = vars(opts), vars(LaunchOptions())
    for name, (uses, which) in PLANT_USES.items():
        if given[name] != defaults[name] and not uses(row, opts):
            return (f"argument {option(name).flag}: --plant {row.name} does not use it (it "
                    f"goes with {which})")
    return None
