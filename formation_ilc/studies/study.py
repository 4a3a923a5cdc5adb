"""One point of a parameter study: a scenario with some fields changed, run and reduced to a row.

``tune`` and ``sweep`` both evaluate points here, on this machine or on Dask workers: a point
travels as plain data (the scenario's YAML text, the changed fields, the seed), never as a
file path, and every worker rebuilds the scenario with the project's strict loader.

Fields a point may change (the ``field`` names of a sweep spec):

* ``law.gain``, ``law.gain_prime``: a number or one number per robot (g of Gamma, g' of
  Gamma').
* ``law.kind`` (9, 22, 23), ``law.memory`` (feedforward, literal).
* ``graph``: a whole ``graph:`` mapping of a scenario file.
* ``delay``: a model name (``none``, ``paper``) or a whole ``delay:`` mapping.
* ``noise_scale``: factor on every initial shift, disturbance and noise amplitude
  (0 = noise-free, 1 = the scenario's).
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
from dataclasses import replace
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario, ScenarioError, parse_yaml, scenario_from_data
from formation_ilc.core.uncertainty import Harmonic, Uncertainty

if TYPE_CHECKING:
    from formation_ilc.model.simulate import Problem

__all__ = ["FIELDS", "apply_fields", "point_id", "config_id", "settle_trial", "reduce_metrics",
           "run_sim_point", "run_check_point", "SIM_COLUMNS", "CHECK_COLUMNS",
           "scale_uncertainty", "scenario_text_with", "scenario_data"]

#: fields a study may vary
FIELDS = ("law.gain", "law.gain_prime", "law.kind", "law.memory", "graph", "delay",
          "noise_scale")

#: the columns a simulated point reduces to (metres, radians, trial indices; trial 0 first)
SIM_COLUMNS = ("trial0_position", "trial0_heading", "peak_position", "peak_trial",
               "above_trial0", "trials_to_position", "trials_to_heading", "floor_position",
               "floor_heading", "last_position", "last_heading")
#: the check's predictions for a configuration (independent of the seed)
CHECK_COLUMNS = ("cond20", "cond20_paper", "heading_norm", "heading_rho", "heading_growth",
                 "heading_growth_trial")


def _canonical(obj: Any) -> str:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"))


@lru_cache(maxsize=16)
def _digest(text: str) -> str:
    """SHA-256 of a scenario text, once per text (a sweep asks for it per point)."""
    return hashlib.sha256(text.encode()).hexdigest()


def config_id(scenario_text: str, fields: dict[str, Any], trials: int) -> str:
    """Stable id of a configuration (scenario text, changed fields, trials), 16 hex digits."""
    key = _canonical({"scenario": _digest(scenario_text), "fields": fields,
                      "trials": int(trials)})
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def point_id(scenario_text: str, fields: dict[str, Any], trials: int, seed: int) -> str:
    """Stable id of one simulated point: its configuration and its seed."""
    return f"{config_id(scenario_text, fields, trials)}-s{int(seed)}"


def scale_uncertainty(unc: Uncertainty, scale: float) -> Uncertainty:
    """Every shift, disturbance and noise amplitude times ``scale``; delays unchanged."""
    if scale == 0.0:
        return unc.without_noise()

    def h(x: Harmonic) -> Harmonic:
        return Harmonic(x.amplitude * scale, x.frequency, x.phase)

    s3 = tuple(float(v) * scale for v in unc.initial_shift)
    d2 = tuple(float(v) * scale for v in unc.disturbance_uniform)
    n3 = tuple(float(v) * scale for v in unc.noise_uniform)
    return replace(unc, initial_shift=(s3[0], s3[1], s3[2]),
                   disturbance_fixed=(h(unc.disturbance_fixed[0]), h(unc.disturbance_fixed[1])),
                   disturbance_uniform=(d2[0], d2[1]),
                   noise_fixed=(h(unc.noise_fixed[0]), h(unc.noise_fixed[1]),
                                h(unc.noise_fixed[2])),
                   noise_uniform=(n3[0], n3[1], n3[2]))


def apply_fields(scenario_text: str, fields: dict[str, Any], source: str = "<study point>",
                 seed: int | None = None, trials: int | None = None) -> Scenario:
    """The scenario of ``scenario_text`` with ``fields`` changed, validated strictly.

    Raises ScenarioError naming ``source`` and the scenario field if a value is invalid.
    """
    try:
        data = scenario_data(scenario_text)
    except ScenarioError as exc:
        raise ScenarioError(str(exc).replace("<study scenario>", source, 1)) from None
    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: the scenario is not a mapping")
    data = copy.deepcopy(data)
    scale = _set_fields(data, fields, source)
    if seed is not None:
        data["seed"] = int(seed)
    if trials is not None:
        data["trials"] = int(trials)
    # validated from the edited data as scenario_from_text would after parsing the text
    # written here: the fields are JSON-like (point ids hash them), which YAML writes and
    # reads back unchanged (tests/studies/test_sweep.py compares both ways)
    sc = scenario_from_data(data, yaml.safe_dump(data, sort_keys=False), source)
    if scale != 1.0:
        sc = replace(sc, uncertainty=scale_uncertainty(sc.uncertainty, scale))
    return sc


@lru_cache(maxsize=8)
def scenario_data(scenario_text: str) -> Any:
    """The data of a study's scenario text as the scenario loader reads it
    (``scenario.parse_yaml``), once per process (a study parses its one scenario for every
    configuration). Shared: callers copy before editing."""
    return parse_yaml(scenario_text, "<study scenario>")


def scenario_text_with(scenario_text: str, fields: dict[str, Any]) -> str:
    """The YAML text of the scenario with ``fields`` written in (not ``noise_scale``): what
    ``apply_fields`` loads, so a file written from it loads to the same scenario."""
    data = copy.deepcopy(parse_yaml(scenario_text, "<study scenario>"))
    if _set_fields(data, fields, "<fields>") != 1.0:
        raise ValueError("noise_scale cannot be written into a scenario file")
    return yaml.safe_dump(data, sort_keys=False)


def _set_fields(data: dict[str, Any], fields: dict[str, Any], source: str) -> float:
    scale = 1.0
    for name, value in fields.items():
        if name in ("law.gain", "law.gain_prime", "law.kind", "law.memory"):
            law = data.setdefault("law", {})
            if not isinstance(law, dict):
                raise ScenarioError(f"{source}: law: expected a mapping")
            law[name.split(".", 1)[1]] = value
        elif name == "graph":
            data["graph"] = value
        elif name == "delay":
            old = data.get("delay") or {}
            new = {"model": value} if isinstance(value, str) else dict(value)
            if isinstance(old, dict) and "leader_link" in old and "leader_link" not in new:
                new["leader_link"] = old["leader_link"]
            data["delay"] = new
        elif name == "noise_scale":
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                    math.isfinite(value) and value >= 0):
                raise ScenarioError(f"{source}: noise_scale: expected a number >= 0, "
                                    f"got {value!r}")
            scale = float(value)
        else:
            raise ScenarioError(f"{source}: {name}: not a field a study can vary "
                                f"(known: {', '.join(FIELDS)})")
    return scale


def settle_trial(err: NDArray[np.float64], level: float) -> int | None:
    """First trial index from which ``err`` stays below ``level`` to the end; None if the
    last trial is not below it."""
    above = np.flatnonzero(~(err < level))
    if len(above) == 0:
        return 0
    k = int(above[-1]) + 1
    return k if k < len(err) else None


def reduce_metrics(metrics: NDArray[np.float64], position_level: float, heading_level: float,
                   floor_window: int) -> dict[str, Any]:
    """A run's per-trial metrics (simulate's METRIC_COLUMNS) reduced to SIM_COLUMNS.

    Floors are medians of the last ``floor_window`` trials; ``above_trial0`` counts trials
    whose max position error exceeds trial 0's.
    """
    pos, head = metrics[:, 1], metrics[:, 2]
    w = max(1, min(int(floor_window), len(pos)))
    return {
        "trial0_position": float(pos[0]), "trial0_heading": float(head[0]),
        "peak_position": float(pos.max()), "peak_trial": int(pos.argmax()),
        "above_trial0": int(np.count_nonzero(pos[1:] > pos[0])),
        "trials_to_position": settle_trial(pos, position_level),
        "trials_to_heading": settle_trial(head, heading_level),
        "floor_position": float(np.median(pos[-w:])), "floor_heading": float(np.median(head[-w:])),
        "last_position": float(pos[-1]), "last_heading": float(head[-1]),
    }


_CACHE: dict[str, tuple[Scenario, Problem]] = {}
_DESIRED: dict[str, Any] = {}


def _desired_key(sc: Scenario) -> str:
    """A hash of what ``Scenario.desired`` is computed from."""
    h = hashlib.sha256()
    for a in (sc.reference, sc.offsets):
        arr = np.ascontiguousarray(a, dtype=float)
        h.update(repr(arr.shape).encode())
        h.update(arr.tobytes())
    h.update(repr((sc.scales, sc.dt, sc.frame, sc.heading_rule, sc.time_scale)).encode())
    return h.hexdigest()


def _cached_scenario(scenario_text: str, fields: dict[str, Any], source: str
                     ) -> tuple[Scenario, Problem]:
    """apply_fields and the simulator's Problem, remembered per (text, fields) in this
    process: the seeds of one configuration share them; configurations with the same
    reference, formation and dt (no study field changes them) share the desired
    trajectories."""
    from formation_ilc.model.simulate import Problem

    key = _digest(scenario_text) + _canonical(fields)
    hit = _CACHE.get(key)
    if hit is None:
        if len(_CACHE) >= 16:
            _CACHE.pop(next(iter(_CACHE)))
        sc = apply_fields(scenario_text, fields, source)
        dkey = _desired_key(sc)
        if dkey not in _DESIRED:
            if len(_DESIRED) >= 8:
                _DESIRED.pop(next(iter(_DESIRED)))
            _DESIRED[dkey] = sc.desired
        sc.__dict__["desired"] = _DESIRED[dkey]  # a cached_property's slot
        hit = _CACHE[key] = (sc, Problem.from_scenario(sc))
    return hit


def run_sim_point(task: dict[str, Any]) -> dict[str, Any]:
    """Simulate one point and reduce it (what a worker runs).

    task : {'id', 'scenario' (YAML text), 'fields', 'seed', 'trials', 'position_level' [m],
    'heading_level' [rad], 'floor_window', 'source'}. Returns {'id', **SIM_COLUMNS,
    'robot_samples'}.
    """
    from formation_ilc.model.simulate import simulate

    base, problem = _cached_scenario(task["scenario"], task["fields"],
                                     task.get("source", "<study point>"))
    sc = base.with_options(seed=task["seed"], trials=task["trials"])
    # the desired trajectories do not depend on the seed or the trial count: share them
    # (``desired`` is a cached_property, kept in the instance's __dict__), and the Problem
    sc.__dict__["desired"] = base.desired
    res = simulate(sc, problem=problem)
    row = reduce_metrics(res.metrics, task["position_level"], task["heading_level"],
                         task["floor_window"])
    row["id"] = task["id"]
    row["robot_samples"] = sc.n * sc.samples * sc.trials
    return row


def run_check_point(task: dict[str, Any]) -> dict[str, Any]:
    """Condition (20) and the lifted heading map of one configuration (what a worker runs).

    task : {'id', 'scenario', 'fields', 'trials', 'source'}, optional 'stop_above' (stop at
    the first ||M^k|| above it: enough to reject). The heading-map columns are None when the
    map is too large to build (checks.LIFTED_LIMIT).
    """
    from threadpoolctl import threadpool_limits

    from formation_ilc.model.checks import condition20, heading_map

    sc = apply_fields(task["scenario"], task["fields"], task.get("source", "<study point>"),
                      trials=task["trials"])
    g = np.asarray(sc.law.gain, dtype=float)
    # one BLAS thread, whatever the worker's environment: a threaded matrix product sums in
    # another order, and the table must be the same on every machine and pool
    with threadpool_limits(limits=1):
        row: dict[str, Any] = {"id": task["id"], "cond20": condition20(sc.graph, g, sc.dt),
                               "cond20_paper": condition20(sc.graph, g, sc.dt,
                                                           include_dt=False)}
        hm = heading_map(sc, early_stop=True, stop_above=task.get("stop_above"))
    row.update({"heading_norm": None if hm is None else hm.norm,
                "heading_rho": None if hm is None else hm.spectral_radius,
                "heading_growth": None if hm is None else hm.growth,
                "heading_growth_trial": None if hm is None else hm.growth_trial})
    return row
