"""Run files: a launched run's every choice in one YAML document.

``formation-ilc run-file SCENARIO [launch options] -o run.yaml`` writes one, complete and
commented (every key, its value, what it means); ``formation-ilc launch run.yaml`` runs
it, and each launch option given beside it overrides its key. A launch keeps the resolved
run file (every key with the value the run went with, none null, the run's id:
:func:`stored_run_text`) in its output folder as ``run.yaml``; ``launch --resume DIR``
reads it (or the ``run.json`` of launches before it).

A run file is checked with the launch options' own rules: an unknown key is refused naming
the closest one (``error: run.yaml: safety.margn: unknown key (did you mean 'margin'?)``),
a bad value names its key and why, exit status 2, before anything starts. Paths in a run
file are relative to its folder; in a stored one, ``@run/REL`` (the run's outputs: its
recording) is relative to the run's folder wherever it is: ``launch OUT/run.yaml --out NEW``
records into NEW.
"""

from __future__ import annotations

import argparse
import textwrap
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from formation_ilc.cli.options import OptionError, cli_type
from formation_ilc.config.option_table import Option, option, robot_entries
from formation_ilc.plan.options import (
    FIELD_KEYS,
    PATH_FIELDS,
    RUN_KEYS,
    SECTIONS,
    STORED_FIELDS,
    LaunchOptions,
    RunKey,
    closest,
    option_fields,
)

__all__ = ["RUN_YAML", "is_run_file", "load_run_file", "load_stored_run", "run_file_text",
           "launch_options", "RESUME_OPTIONS", "host_per_robot", "resumed_part",
           "add_parser", "run", "plan_of", "effective_values", "stored_run_text"]

#: the resolved run file in a run's output folder
RUN_YAML = "run.yaml"
#: a run file is a few hundred short lines
RUN_FILE_LIMIT = 1 << 20
#: a run file key's field, by the key's path
FIELD_KEYS_BY_PATH = {k.path: k.field for k in RUN_KEYS}
#: the launch options a resumed launch takes from its own command line (the rest are the run's)
RESUME_OPTIONS = frozenset({"max_restarts", "watchdog_scale", "domain_id", "no_plots"})


def _read_yaml(path: Path) -> Any:
    import yaml

    from formation_ilc.store.bounded import StateFileError, read_bounded

    try:
        raw = read_bounded(path, RUN_FILE_LIMIT, "a run file")
    except StateFileError as exc:
        raise OptionError(str(exc)) from None
    if raw is None:
        raise OptionError(f"{path}: no such file")
    try:
        return yaml.safe_load(raw)
    except yaml.YAMLError as exc:
        raise OptionError(f"{path}: not YAML: {' '.join(str(exc).split())[:160]}") from None


def is_run_file(text: str | None) -> bool:
    """Whether the SCENARIO argument ``text`` names a run file: a YAML file whose top level
    has a ``scenario`` key (a scenario file has none)."""
    if not text or not text.endswith((".yaml", ".yml")) or not Path(text).is_file():
        return False
    try:
        d = _read_yaml(Path(text))
    except OptionError:
        return False
    return isinstance(d, dict) and "scenario" in d


def _flatten(path: Path, d: Any) -> tuple[dict[str, Any], dict[str, list[str]]]:
    """The run file's values by field, and its ``hosts:`` mapping; OptionError naming the
    first key that is not a run file's (with the closest that is)."""
    if not isinstance(d, dict):
        raise OptionError(f"{path}: expected a mapping of run file keys, got "
                          f"{type(d).__name__}")
    top = {k.path for k in RUN_KEYS if "." not in k.path} | set(SECTIONS) - {""} | {"hosts"}
    values: dict[str, Any] = {}
    hosts: dict[str, list[str]] = {}
    for key, value in d.items():
        key = str(key)
        if key not in top:
            raise OptionError(f"{path}: {key}: unknown key{closest(key, top)}")
        if key == "hosts":
            hosts = _hosts(path, value)
        elif key in SECTIONS:
            if value is None:
                continue
            if not isinstance(value, dict):
                raise OptionError(f"{path}: {key}: expected a mapping ({SECTIONS[key]})")
            keys = {k.path.split(".", 1)[1]: k for k in RUN_KEYS if k.path.startswith(key + ".")}
            for sub, v in value.items():
                sub = str(sub)
                if sub not in keys:
                    raise OptionError(f"{path}: {key}.{sub}: unknown key{closest(sub, keys)}")
                values[keys[sub].path] = v
        else:
            values[key] = value
    return values, hosts


def _hosts(path: Path, value: Any) -> dict[str, list[str]]:
    if value is None:
        return {}
    if not isinstance(value, dict) or not all(
            isinstance(m, list) and all(isinstance(x, str) for x in m) for m in value.values()):
        raise OptionError(f"{path}: hosts: expected a mapping of host names to lists of "
                          f"member names (e.g. ground: [leader, sim])")
    return {str(h): list(m) for h, m in value.items()}


def _check(path: Path, key: str, opt: Option, value: Any) -> Any:
    """``value`` of run file key ``key`` as its field holds it, checked by its row of the
    option table (as the command line checks the flag); OptionError naming the key and
    why."""

    def bad(why: str) -> OptionError:
        return OptionError(f"{path}: {key}: {why}")

    if value is None:
        return None
    if opt.kind == "stored":  # a stored run's own: the run's id, the clocks' origin, ...
        want: type = int if opt.stored_as is int else str
        if not isinstance(value, want) or isinstance(value, bool):
            raise bad(f"expected {'an integer' if want is int else 'a string'}, got {value!r}")
        return value
    if opt.kind in ("bool", "switch"):
        if not isinstance(value, bool):
            raise bad(f"expected true or false, got {value!r}")
        return (not value) if opt.negated else value
    if opt.kind == "robots":
        try:
            return robot_entries(value)
        except ValueError as exc:
            why = str(exc)
            raise OptionError(f"{path}: {key}{'.' if why[:1].isdigit() else ': '}{why}") from None
    if opt.kind == "names":
        if not isinstance(value, list) or not value or not all(
                isinstance(v, (str, int)) for v in value):
            raise bad(f"expected a list of names, got {value!r}")
        return [str(v) for v in value]
    if isinstance(value, (dict, list)) or isinstance(value, bool):
        raise bad(f"expected a single value, got {value!r}")
    text = str(value)
    try:
        converted = Path(text) if opt.kind == "path" else opt.value(text)
        if opt.kind in ("folder", "file"):  # the command line's check that it can be written
            converted = cli_type(opt)(text)
    except (argparse.ArgumentTypeError, ValueError) as exc:
        raise bad(str(exc)) from None
    if opt.choices is not None and converted not in opt.choices:
        choices = [str(c) for c in opt.choices]
        raise bad(f"invalid choice: {converted!r} (choose from {', '.join(choices)})"
                  f"{closest(text, choices)}")
    return converted


def _fields(path: Path, values: Mapping[str, Any], base: Path | None) -> dict[str, Any]:
    """Each run file value (by key path) as its field's, checked; relative paths taken
    from ``base`` (a run file's folder; None: as given)."""
    by_path = {k.path: k for k in RUN_KEYS}
    out: dict[str, Any] = {}
    for key, value in values.items():
        k = by_path[key]
        if base is not None and isinstance(value, str) and k.field in PATH_FIELDS and (
                not Path(value).is_absolute()):
            parts = Path(value).parts
            if parts[:1] == ("@run",) and k.field not in ("record", "out"):
                # a stored run's file, launched again: its inputs are in its folder
                value = str(base.joinpath(*parts[1:]))
            elif parts[:1] != ("@run",):  # a recording of "@run" goes into the new run's
                value = str(base / value)
        if k.field == "scenario" and isinstance(value, str) and base is not None:
            near = base / value
            value = str(near) if near.is_file() else value
        out[k.field] = _check(path, key, option(k.field), value)
    return out


def load_run_file(path: Path) -> dict[str, Any]:
    """The fields a run file sets (its ``hosts:`` as ``host_members``); OptionError with the
    file, the key and why."""
    import yaml

    values, hosts = _flatten(path, _read_yaml(path))
    inline = values.pop("scenario") if isinstance(values.get("scenario"), dict) else None
    if inline is None and not isinstance(values.get("scenario"), str):
        raise OptionError(f"{path}: scenario: a built-in scenario's name, a scenario file, "
                          f"or a scenario written here (a mapping) is required")
    out = _fields(path, values, path.resolve().parent)
    if inline is not None:  # checked as a scenario file is, when the run is planned
        if "from" in inline:
            inline = _derived_scenario(path, inline)
        out["scenario_text"] = yaml.safe_dump(inline, sort_keys=False)
    for name in STORED_FIELDS:  # a stored run's own: a launch of its file is a new run
        out.pop(name, None)
    if hosts:
        out["host_members"] = hosts
    return out


def _derived_scenario(path: Path, inline: dict[str, Any]) -> dict[str, Any]:
    """``scenario: {from: NAME, ...}``: scenario NAME (a built-in, or a file beside the run
    file) with the other keys written over its own, a mapping key by key (``law: {gains:
    ...}`` changes the gains and keeps the rest of ``law``); OptionError naming
    ``scenario.from``."""
    import yaml

    from formation_ilc.config.scenario import ScenarioError, load_scenario

    over = dict(inline)
    name = over.pop("from")
    if not isinstance(name, str) or not name.strip():
        raise OptionError(f"{path}: scenario.from: a built-in scenario's name or a scenario "
                          f"file, got {name!r}")
    near = path.resolve().parent / name
    try:
        base = yaml.safe_load(load_scenario(near if near.is_file() else name).text)
    except ScenarioError as exc:
        raise OptionError(f"{path}: scenario.from: {exc}") from None
    return _merged(base, over)


def _merged(base: Any, over: Any) -> Any:
    """``over`` written over ``base``: mappings key by key, anything else replaced."""
    if not (isinstance(base, dict) and isinstance(over, dict)):
        return over
    return {**base, **{k: _merged(base.get(k), v) for k, v in over.items()}}


def load_stored_run(folder: Path) -> dict[str, Any] | None:
    """The fields of the run in ``folder``: its resolved ``run.yaml``, else the
    ``run.json`` of a launch before run files; every path that pointed into the run's folder
    re-rooted in ``folder``. None when there is neither; OptionError naming the file."""
    from formation_ilc.store.runfile import RunFileError, load_run, require, reroot

    path = folder / RUN_YAML
    if path.is_file():
        values, hosts = _flatten(path, _read_yaml(path))
        values = reroot({FIELD_KEYS_BY_PATH[k]: v for k, v in values.items()}, folder)
        for f in PATH_FIELDS:  # every path the run's own, relative to its folder
            v = values.get(f)
            if isinstance(v, str) and Path(v).parts[:1] == ("@run",):
                values[f] = str(folder.resolve().joinpath(*Path(v).parts[1:]))
        d = _fields(path, {FIELD_KEYS[f].path: v for f, v in values.items()},
                    folder.resolve())
        if hosts:
            d["host_members"] = hosts
    else:
        try:
            legacy = load_run(folder)
        except RunFileError as exc:
            raise OptionError(f"--resume {exc}") from None
        if legacy is None:
            return None
        d = {k: v for k, v in legacy.items() if k in option_fields()}
    try:
        require(d, folder)
    except RunFileError as exc:
        raise OptionError(f"--resume {exc}") from None
    return d


def launch_options(args: argparse.Namespace) -> LaunchOptions:
    """The options of a launch: ``args`` holds only the options given on the command line
    (the launch parser has no defaults); they override a run file named as SCENARIO, or
    are all there is. With ``--resume DIR`` the stored run's own, and the few a resumed
    launch may change. OptionError for what cannot be combined."""
    given = {k: v for k, v in vars(args).items() if k in set(option_fields())}
    resume = given.get("resume")
    if resume is not None:
        return _resumed(Path(resume), given)
    scenario = given.get("scenario")
    if scenario is not None and is_run_file(scenario):
        given.pop("scenario")
        from_file = load_run_file(Path(scenario))
        opts = LaunchOptions().with_fields(from_file).with_fields(given)
        _unused_key(Path(scenario), opts, set(from_file) - set(given))
        return opts
    return LaunchOptions().with_fields(given)


def _unused_key(path: Path, opts: LaunchOptions, from_file: set[str]) -> None:
    """OptionError naming the run file's key (``plant.base``, not ``--base``) of the first
    option the file sets that the run's plant does not use (the planner refuses the same
    given on the command line, naming the flag)."""
    from formation_ilc.config.plants import plant
    from formation_ilc.plan.options import PLANT_USES

    try:
        row = plant(opts.plant)
    except ValueError:
        return  # an unknown plant: refused in its own words
    defaults = LaunchOptions()
    for name, (uses, which) in PLANT_USES.items():
        if (name in from_file and name in FIELD_KEYS
                and getattr(opts, name) != getattr(defaults, name) and not uses(row, opts)):
            raise OptionError(f"{path}: {FIELD_KEYS[name].path}: --plant {row.name} does not "
                              f"use it (it goes with {which})")


def plan_of(args: argparse.Namespace) -> Any:
    """The plan (``plan.specs.RunPlan``) of parsed launch options; NoRun (one line, exit
    status) for a run file or options that give no run."""
    from formation_ilc.plan.build import build_plan
    from formation_ilc.plan.specs import NoRun

    try:
        opts = launch_options(args)
    except OptionError as exc:
        raise NoRun(str(exc)) from None
    try:
        return build_plan(opts)
    except NoRun as stop:
        raise NoRun(_in_file_words(stop.message, args), stop.status) from None


def _in_file_words(message: str, args: argparse.Namespace) -> str:
    """``message`` with each flag of an option that a run file set (and the command line
    did not) named as the file's key: ``run.yaml: plant.physics_rate: 5: ...`` for a
    refusal that starts ``--physics-rate 5: ...``, ``lower safety.margin in run.yaml`` for
    ``lower --safety-margin``."""
    import re

    given = vars(args)
    scenario = given.get("scenario")
    if given.get("resume") is not None or scenario is None or not is_run_file(scenario):
        return message
    path = Path(scenario)
    try:
        from_file = set(load_run_file(path)) - set(given)
    except OptionError:
        return message
    for name in from_file:
        opt = option(name)
        if opt.key is None or not (opt.flag or "").startswith("--"):
            continue
        flag = re.escape(opt.flag or "")
        head = re.match(rf"^(?:argument )?{flag}(?::| (?=\S))", message)
        if head is not None:
            message = f"{path}: {opt.key}: {message[head.end():].lstrip()}"
        message = re.sub(rf"(?<![\w-]){flag}(?![\w-])", f"{opt.key} in {path}", message)
    return message


def _resumed(out: Path, given: dict[str, Any]) -> LaunchOptions:
    if given.get("scenario") is not None:
        raise OptionError("--resume takes the run's own scenario and options: give no "
                          "SCENARIO")
    stored = load_stored_run(out)
    if stored is None:
        raise OptionError(f"--resume {out}: no {RUN_YAML} or run.json there (not the "
                          f"output folder of a `formation-ilc launch` run)")
    extra = set(given) - RESUME_OPTIONS - {"resume", "scenario"}
    if extra:  # before, silently ignored (--domain-id among them; now honoured)
        shown = ", ".join(f"--{k.replace('_', '-')}" for k in sorted(extra))
        raise OptionError(
            f"--resume takes the run's own options: {shown} cannot change a run going on "
            f"(with --resume: "
            f"{', '.join('--' + k.replace('_', '-') for k in sorted(RESUME_OPTIONS))})")
    opts = LaunchOptions().with_fields(stored)
    mine = {k: given[k] for k in RESUME_OPTIONS if k in given}
    mine["no_plots"] = bool(given.get("no_plots")) or opts.no_plots
    if opts.record is not None:
        mine["record_root"] = opts.record_root or opts.record
        mine["record"] = resumed_part(opts.record_root or opts.record)
    return opts.with_fields({**mine, "out": out, "resume": out})


def resumed_part(root: Path) -> Path:
    """Where a resumed launch records: the run's first file when no part of its recording
    exists yet (a launch killed before its recorder wrote it), else the next free
    ``RUN.resumedN.mcap`` (every part stays as it was written)."""
    from formation_ilc.recordings.recording import recording_parts

    if not any(p.exists() for p in recording_parts(root)):
        return root
    stem = root.with_suffix("")
    n = 1
    while Path(f"{stem}.resumed{n}.mcap").exists() or any(
            stem.parent.glob(f"{stem.name}.resumed{n}.part*.mcap")):
        n += 1
    return Path(f"{stem}.resumed{n}.mcap")


# --------------------------------------------------------------------------- writing

def host_per_robot(members: list[tuple[str, int | None]]) -> dict[str, list[str]]:
    """``hosts:`` with robot i's processes (its node, its bridge, its fake driver) on host
    ``r<i>`` and every other on ``ground``: ``members`` are (process name, robot number or
    None)."""
    hosts: dict[str, list[str]] = {"ground": []}
    for name, robot in members:
        hosts.setdefault("ground" if robot is None else f"r{robot}", []).append(name)
    return hosts


def run_file_text(opts: LaunchOptions, *, folder: Path | None = None,
                  stored: Path | None = None, title: str = "",
                  effective: Mapping[str, Any] | None = None,
                  shown: Mapping[str, Any] | None = None) -> str:
    """``opts`` as a run file: each key its plant uses, in its section, with its value and
    what it means (its option's help, from the option table); a key left to the scenario,
    the plant or the machine is written as a comment with the value the plan gives it
    (``shown``, :func:`effective_values`), never as null. Paths relative to ``folder`` when
    they lie inside it; with ``stored`` (a run's folder, where the file goes), the run's
    outputs inside it as ``@run/REL`` (a launch of the file elsewhere writes into its own
    folder), its own folder as ``.`` and every other path relative to it. With
    ``effective`` (field -> value, :func:`effective_values`) those values, and only the
    keys that have one."""
    values = opts.stored() if effective is None else dict(effective)
    lines = [f"# {line}" for line in title.splitlines()] if title else []
    for section, about in SECTIONS.items():
        keys = [k for k in RUN_KEYS if (k.path.split(".")[0] if "." in k.path else "") == section
                and _written(k, opts, values, effective is None, shown)]
        if section and not keys:
            continue
        if section:
            lines += ["", f"# {about}", f"{section}:"]
        indent = "  " if section else ""
        for k in keys:
            lines += _key_lines(k, opts, values, indent, folder=folder, stored=stored,
                                shown=shown)
    lines += ["", "# which machine runs which members (formation-ilc launch RUN.yaml --host "
                  "NAME on each);", "# none: every member on this machine"]
    if opts.host_members:
        import yaml

        dumped = yaml.safe_dump({"hosts": {h: list(m) for h, m in opts.host_members}},
                                default_flow_style=None, sort_keys=False, width=88)
        lines += dumped.rstrip().splitlines()
    else:
        lines.append("hosts: {}")
    return "\n".join(lines) + "\n"


def _written(k: RunKey, opts: LaunchOptions, values: Mapping[str, Any], written: bool,
             shown: Mapping[str, Any] | None) -> bool:
    """Whether key ``k`` goes into the file: one its plant uses, with a value (or, in a
    written file, one the plan shows)."""
    if k.field == "scenario" and opts.scenario_text is not None:
        return True
    if values.get(k.field) is not None:
        return not written or _plant_uses(k.field, opts)
    if not written or shown is None or shown.get(k.field) is None:
        return False
    return option(k.field).kind != "stored" and _plant_uses(k.field, opts)


def _plant_uses(name: str, opts: LaunchOptions) -> bool:
    """Whether ``opts``' plant uses option ``name`` (a written file leaves out the others'
    keys: a Pioneer's file has no plant.base, no physics keys)."""
    from formation_ilc.config.plants import plant

    try:
        row = plant(opts.plant)
    except ValueError:
        return True
    if name in ("fake_drivers", "physics_bases"):  # the bridges' stand-ins
        return row.per_robot and (name == "fake_drivers" or row.driver == "base")
    uses = option(name).uses
    return uses is None or bool(uses[0](row, opts))


def _key_lines(k: RunKey, opts: LaunchOptions, values: Mapping[str, Any], indent: str, *,
               folder: Path | None, stored: Path | None,
               shown: Mapping[str, Any] | None) -> list[str]:
    """A key's lines: its comment, then ``name: value`` (or ``# name: value`` for a value
    the plan chose, ``shown``)."""
    import yaml

    if k.field == "scenario" and opts.scenario_text is not None:
        return [f"{indent}# SCENARIO: written here (a scenario file's keys)",
                *yaml.safe_dump({"scenario": yaml.safe_load(opts.scenario_text)},
                                sort_keys=False, width=88).rstrip().splitlines()]
    v = values.get(k.field)
    chosen = v is None  # left to the plan: shown as a comment
    if chosen:
        v = (shown or {}).get(k.field)
    if k.negated and v is not None:
        v = not v
    v = _file_value(k.field, v, folder=folder, stored=stored)
    lines = [f"{indent}# {line}" for line in textwrap.wrap(
        _help(option(k.field)), 88 - len(indent) - 2, break_on_hyphens=False)]
    text = yaml.safe_dump({k.path.rsplit(".", 1)[-1]: v}, default_flow_style=True,
                          width=10_000).strip()
    text = text[1:-1] if text.startswith("{") else text
    return [*lines, f"{indent}# {text}" if chosen else f"{indent}{text}"]


def _file_value(name: str, v: Any, *, folder: Path | None, stored: Path | None) -> Any:
    """A path's value as the file writes it (relative to ``folder``, or to the run's
    folder ``stored`` with its outputs as ``@run/REL``); any other value as it is."""
    import os

    from formation_ilc.store.runfile import relative

    if isinstance(v, str) and name in PATH_FIELDS:
        if stored is not None:
            p = Path(v)
            if name == "out" and p.resolve() == stored.resolve():
                v = "."
            elif name in ("record", "record_root"):
                v = relative(str(p.resolve()) if p.parts[:1] != ("@run",) else v,
                             stored.resolve())
            elif p.is_absolute():
                v = os.path.relpath(p, stored.resolve())
        elif folder is not None:
            try:
                v = str(Path(v).resolve().relative_to(folder.resolve()))
            except ValueError:
                pass
    if name == "scenario" and isinstance(v, str) and Path(v).is_file():
        v = str(Path(v).resolve())
        if stored is not None:
            v = os.path.relpath(v, stored.resolve())
    return v


def effective_values(plan: Any, options: Mapping[str, Any]) -> dict[str, Any]:
    """The stored run's keys, field -> the value the run went with (``options``: the
    plan's ``run_json``; ``plan``: ``plan.specs.RunPlan``): what a default left to the
    scenario, the plant, the preset or the machine (seed, law, headings, the limits, the
    safety filter's settings, the namespace and ROS domain, ...) became; None for a key
    the run has no value of (no recording, no live view, an option its plant does not
    use): the key is left out, not written as null or as a 0 meaning "the preset's"."""
    import math

    from formation_ilc.config.bases import LIMIT_KEYS
    from formation_ilc.config.plants import plant
    from formation_ilc.plan.options import PLANT_USES
    from formation_ilc.protocol.bridge import bridge_limits

    d = dict(options)
    opts = LaunchOptions().with_fields({k: v for k, v in d.items() if k in option_fields()})
    cfg, sc = plan.config, plan.config.scenario
    row = plant(opts.plant)
    for name, (uses, _) in PLANT_USES.items():
        if not uses(row, opts):
            d[name] = None
    if not row.per_robot:  # the stand-ins of the bridges' drivers
        d.update(fake_drivers=None, physics_bases=None)
    d.update(trials=sc.trials, seed=sc.seed, law=sc.law.kind, memory=sc.law.memory,
             headings=sc.headings, time_scale=sc.time_scale, mode=cfg.mode, links=cfg.links,
             run_id=cfg.run_id, namespace=plan.namespace, domain_id=plan.domain)
    bridge = plan.bridge
    if bridge is not None:
        d.update(driver_ns=bridge.driver_ns, cmd_type=bridge.sent_type)
        given = dict(bridge.limits)
        held = bridge_limits(bridge.base, given)
        for key, x in zip(LIMIT_KEYS, held.as_tuple(), strict=True):
            # a parameters file may set a robot's own: only what was given is the run's
            known = bridge.params_file is None or key in given
            d[key] = (_in_option_units(key, x) if known and math.isfinite(x) else None)
    safety = cfg.safety
    d["safety"] = safety is not None
    d.update(body=None, safety_margin=None, safety_learning=None, safety_motion=None)
    if safety is not None:
        d.update(safety_margin=safety.margin, safety_learning=safety.learning,
                 safety_motion=safety.motion)
        if not row.bodies:  # (a plant with bodies knows its own: --body is refused there)
            d["body"] = safety.body
    if plan.live is None:
        d.update(live=None, live_rate=None, live_host=None)
    else:
        d["live_rate"] = plan.live_rate
    if d.get("record") is None:
        d["record_root"] = None
    if not cfg.clocks.emulated:
        d["clock_origin_ns"] = None
    return d


def _in_option_units(key: str, x: float) -> float:
    """A limit [SI] in its option's units (deg/s, deg/s^2 for the angular ones): the
    float that the option reads back as ``x`` exactly."""
    import math

    if key not in ("omega_max", "alpha_max"):
        return float(x)
    deg = math.degrees(x)
    for candidate in (round(deg, 12), deg, math.nextafter(deg, math.inf),
                      math.nextafter(deg, -math.inf)):
        if math.radians(candidate) == x:
            return candidate
    return deg


def stored_run_text(plan: Any, options: Mapping[str, Any], title: str) -> str:
    """The resolved run file a launch keeps in its output folder: every key with the value
    the run went with (:func:`effective_values`), none null, paths relative to the folder."""
    d = effective_values(plan, options)
    if isinstance(d.get("scenario"), str) and Path(d["scenario"]).is_file():
        d["scenario"] = str(Path(d["scenario"]).resolve())
    opts = LaunchOptions().with_fields({k: v for k, v in d.items()
                                        if k in option_fields() and k != "out"})
    return run_file_text(opts, stored=plan.out.resolve(), title=title, effective=d)


def _help(opt: Option) -> str:
    """A key's comment: its flag (or what false means), its choices, its help."""
    text = opt.help_text()
    if opt.choices is not None:
        text = f"{' | '.join(map(str, opt.choices))}: {text}"
    if opt.flag is None:
        return text
    flag = opt.flag if opt.flag.startswith("-") else "SCENARIO"
    return f"false is {flag}: {text}" if opt.negated else f"{flag}: {text}"


# --------------------------------------------------------------------------- the command

def add_parser(sub: Any) -> None:
    """``formation-ilc run-file SCENARIO [launch options] -o RUN.yaml [--host-per-robot]``."""
    from formation_ilc.cli.launchargs import add_arguments, without_defaults
    from formation_ilc.cli.options import output_file_arg

    p = sub.add_parser(
        "run-file", help="write a run file: a launch's every choice, commented",
        description="Write a complete, commented run file of a launch's options (every key "
                    "with its value: the options given, the defaults for the rest), checked "
                    "as `launch` checks them. Run it with `formation-ilc launch RUN.yaml` "
                    "(options given beside it override its keys).")
    add_arguments(p)
    without_defaults(p)
    p.add_argument("-o", "--output", type=output_file_arg, required=True, metavar="RUN.yaml",
                   help="the run file to write")
    p.add_argument("--host-per-robot", action="store_true",
                   help="a hosts: mapping with the leader, the plant, the link emulator, the "
                        "recorder and the monitor on host 'ground' and robot i's node (with "
                        "its bridge and driver where there are) on host 'r<i>'")


def run(args: argparse.Namespace) -> int:
    """Write the run file ``args.output``: the options, planned as ``launch`` plans them
    (refused the same way), with the hosts asked for."""
    from formation_ilc.plan.build import decide, hosted_members, unmade_folder
    from formation_ilc.plan.machine import Machine
    from formation_ilc.plan.specs import NoRun
    from formation_ilc.store.atomic import atomic_write_text

    opts = launch_options(args)
    if opts.resume is not None:
        raise OptionError("run-file: --resume: a stored run's file is its folder's run.yaml")
    machine = Machine.probe()
    try:  # planned, not prepared: no folder made, nothing started
        plan = decide(opts.with_fields({"out": unmade_folder(machine)}), machine)
    except NoRun as stop:
        return stop.report()
    # what the plan chose for the keys left open, shown as comments (a launch chooses its
    # ROS domain afresh)
    shown = {**effective_values(plan, opts.stored()), "domain_id": None, "run_id": None}
    if args.host_per_robot:
        opts = opts.with_fields({"host_members": host_per_robot(list(hosted_members(plan)))})
    if opts.scenario is not None and Path(opts.scenario).is_file():
        opts = opts.with_fields({"scenario": str(Path(opts.scenario).resolve())})
    path: Path = args.output
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, run_file_text(
        opts, folder=path.parent, shown=shown,
        title=f"a formation-ilc run: formation-ilc launch {path.name} runs it "
              f"(formation-ilc launch --help says what each key's option does)"))
    hosts = f", hosts {', '.join(h for h, _ in opts.host_members)}" if opts.host_members else ""
    print(f"wrote {path} ({plan.scenario.name}, {plan.scenario.n} robots, plant "
          f"{opts.plant}{hosts}): formation-ilc launch {path}")
    return 0
