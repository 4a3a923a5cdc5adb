"""run.json: the options of a run launched before run files, kept in its folder so that it
can be resumed; and what a run leaves in its folder.

``formation-ilc launch`` wrote ``DIR/run.json`` (atomically) when a run started; a launch
now keeps ``DIR/run.yaml`` only (``cli.runfile``), and ``launch --resume DIR`` reads a
run.json where there is no run.yaml (``save_run`` writes one, as those launches did).
The folder may have been moved or copied since: a path that pointed into the run's folder
(the recording, a scenario file kept beside it) is stored relative to the folder and
resolved against the folder being resumed, never against the folder the run was first
written to (:func:`reroot` also re-roots the absolute paths of run files written before).
The file is read bounded (a regular file of at most ``RUN_LIMIT`` bytes,
``formation_ilc.store.bounded``) and checked field by field.
"""

from __future__ import annotations

import json
from pathlib import Path, PurePath
from typing import Any

from formation_ilc.store.atomic import atomic_write_text
from formation_ilc.store.bounded import StateFileError, read_bounded

__all__ = ["RUN_FILE", "CONFIG_FILE", "CONFIG_LIMIT", "load_config", "RUN_LIMIT",
           "RunFileError", "save_run", "load_run", "reroot", "require", "PATH_KEYS", "relative",
           "RUN_STATE", "run_state_in", "used_folder_line"]

RUN_FILE = "run.json"
#: the run configuration every node shares (scenario text, options, run id), as JSON, in
#: the run's folder: what a recording that lost every copy of it is rebuilt from
CONFIG_FILE = "config.json"
#: a configuration holds its scenario's text (at most 1 MiB, config.scenario) and options
CONFIG_LIMIT = 2 << 20
#: a run's options are a few dozen short values
RUN_LIMIT = 64 << 10
#: options that hold paths: re-rooted when they point into the run's folder
PATH_KEYS = ("record", "scenario", "init_memory")
#: options whose type is checked on load (the rest are the launcher's own to check)
_TYPES: dict[str, tuple[type, ...]] = {
    "trials": (int,), "seed": (int, type(None)), "scenario": (str,),
    "record": (str, type(None)), "init_memory": (str, type(None)), "out": (str,),
    "run_id": (str,), "mode": (str, type(None)), "links": (str, type(None)),
    "container": (int,), "timeout": (int, float), "max_restarts": (int,)}


class RunFileError(ValueError):
    """A run.json that cannot be resumed from; the message names the file and the field."""


def _relative(value: str, folder: Path) -> str:
    """``value`` relative to ``folder`` when it lies inside it, else unchanged."""
    p = Path(value)
    if not p.is_absolute():
        return value
    try:
        return str(PurePath("@run") / p.relative_to(folder))
    except ValueError:
        return value


#: a path inside a run's folder as ``@run/REL`` (else unchanged)
relative = _relative


def save_run(folder: Path, options: dict[str, Any]) -> None:
    """Write ``folder/run.json``: ``options`` as JSON, each path of PATH_KEYS inside
    ``folder`` stored as ``@run/REL`` (relative to the folder, wherever it goes)."""
    folder = Path(folder).resolve()
    d = {k: (str(v) if isinstance(v, PurePath) else v) for k, v in options.items()}
    for k in PATH_KEYS:
        if isinstance(d.get(k), str):
            d[k] = _relative(d[k], folder)
    d["out"] = "@run"
    atomic_write_text(folder / RUN_FILE, json.dumps(d, indent=2) + "\n")


def load_run(folder: Path) -> dict[str, Any] | None:
    """The options in ``folder/run.json`` with every path re-rooted in ``folder``
    (:func:`reroot`); None when there is no such file, RunFileError naming the file and
    the field when it cannot be a run's."""
    path = Path(folder) / RUN_FILE
    try:
        raw = read_bounded(path, RUN_LIMIT, "a run.json")
    except StateFileError as exc:
        raise RunFileError(str(exc)) from None
    if raw is None:
        return None
    try:
        d = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        raise RunFileError(f"{path}: unreadable: not JSON: {str(exc)[:100]}") from None
    if not isinstance(d, dict):
        raise RunFileError(f"{path}: expected a JSON object, got {type(d).__name__}")
    for key, types in _TYPES.items():
        if key in d and (not isinstance(d[key], types) or isinstance(d[key], bool)):
            raise RunFileError(f"{path}: {key}: {str(d[key])[:60]!r} is not a valid value")
    if d["trials"] < 1 if "trials" in d else False:
        raise RunFileError(f"{path}: trials: {d['trials']} (at least 1)")
    return reroot(d, Path(folder))


def require(d: dict[str, Any], folder: Path) -> None:
    """RunFileError naming the first option a run.json must hold and ``d`` lacks."""
    for key in ("scenario", "run_id"):
        if key not in d:
            raise RunFileError(f"{Path(folder) / RUN_FILE}: {key} is missing")


def reroot(d: dict[str, Any], folder: Path) -> dict[str, Any]:
    """``d`` with each path of PATH_KEYS that pointed into the run's folder (``@run/REL``,
    or, in a run.json written before, an absolute path under the ``out`` it names) moved
    into ``folder``; ``out`` becomes ``folder``."""
    folder = Path(folder).resolve()
    out = dict(d)
    old = d.get("out")
    old_out = Path(old) if isinstance(old, str) and old != "@run" else None
    for k in PATH_KEYS:
        v = out.get(k)
        if not isinstance(v, str):
            continue
        p = PurePath(v)
        if p.parts[:1] == ("@run",):
            out[k] = str(folder.joinpath(*p.parts[1:]))
        elif old_out is not None and p.is_absolute():
            try:
                out[k] = str(folder / Path(v).relative_to(old_out))
            except ValueError:
                pass
    out["out"] = str(folder)
    return out


def load_config(path: Path) -> dict[str, Any] | None:
    """The run configuration JSON object in ``path`` (a run folder's ``CONFIG_FILE``),
    read bounded; None when there is none; RunFileError naming the file otherwise."""
    try:
        raw = read_bounded(path, CONFIG_LIMIT, "a run configuration")
    except StateFileError as exc:
        raise RunFileError(str(exc)) from None
    if raw is None:
        return None
    try:
        d = json.loads(raw)
    except (ValueError, RecursionError) as exc:
        raise RunFileError(f"{path}: not a run configuration: {exc}") from None
    if not isinstance(d, dict) or "scenario_text" not in d:
        raise RunFileError(f"{path}: not a run configuration (no scenario_text)")
    return d


#: what a run leaves in its folder: its options (run.yaml; run.json before run files), the
#: nodes' state (what --resume goes on from), its metrics rows, its configuration and summary
RUN_STATE = ("run.yaml", RUN_FILE, "state", "metrics.csv", CONFIG_FILE, "summary.json")


def run_state_in(folder: Path) -> list[str]:
    """The names of ``RUN_STATE`` that ``folder`` holds (a folder ``state`` only when
    something is in it): another run's, for a launch that is not its ``--resume``."""
    found = []
    for name in RUN_STATE:
        p = folder / name
        try:
            if p.is_dir():
                if any(p.iterdir()):
                    found.append(f"{name}/")
            elif p.exists():
                found.append(name)
        except OSError:  # unreadable: the folder is not a fresh one either
            found.append(name)
    return found


def used_folder_line(folder: Path) -> str:
    """Why a new run may not go into ``folder`` ("" when it may): it holds another run's
    state, which a new run would mix with its own (the leader went on from the other run's
    memory with this run's seed) and overwrite (its metrics rows)."""
    found = run_state_in(folder)
    if not found:
        return ""
    return (f"--out {folder}: holds another run ({', '.join(found)}); nothing was changed. "
            f"Go on with that run with `formation-ilc launch --resume {folder}`, or give a "
            f"fresh folder to --out")
