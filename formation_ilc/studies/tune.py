"""Gain design: the fewest trials to a target error, under the check's guarantees.

The gains keep the paper's structure, Gamma_i = g_i [[cos th, sin th, 0], [0, 0, 1]] for the
predictive term and Gamma'_i = g'_i [...] for the current term, with one (g, g') pair per
*graph depth* (hops from the leader). The two gains do different jobs:

* g' closes a feedback loop within the trial: it sets how well trial 0 already goes and the
  "plant" that learning sees (the closed loop, a low-pass of bandwidth about g' dT per
  sample). Too large, with delays of up to 4 samples, and the loop rings.
* g learns between trials. Its diagonal rate is 1 - g dT (the spectral radius of the lifted
  map), but the ratio g / g' decides whether the error transient stays bounded; a robot
  further from the leader learns from a neighbour that is still learning, so it wants a
  different pair than the leader's neighbours.

Method:

1. **Guarantees first.** Every candidate must satisfy condition (20) (B with dT, as
   printed) and have a lifted heading map with spectral radius < 1 and a transient bound
   max_k ||M^k|| <= ``max_growth``.
2. **Screen** a grid of (g dT, g' dT) per depth by a short simulation (noise and delays on,
   the scenario's seed): trials until the position and heading errors stay below the target
   levels; any trial above trial 0's error rejects the candidate.
3. **Check** the best screened candidates in order (the lifted map is the expensive step)
   until ``finalists`` pass the guarantees.
4. **Verify** the finalists and the scenario's own gains by full simulations over several
   seeds; the winner has the fewest trials to both levels (worst seed), no trial above
   trial 0 and floors within ``floor_factor`` of the scenario's own floors.
"""

from __future__ import annotations

import itertools
import json
import math
import os
import sys
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario, ScenarioError
from formation_ilc.core.metrics import TARGET_HEADING, TARGET_POSITION
from formation_ilc.model.checks import condition20, heading_map
from formation_ilc.studies.study import apply_fields, point_id, scenario_text_with
from formation_ilc.studies.sweep import close_pools, map_tasks, points_progress

__all__ = ["graph_depths", "TuneOptions", "Candidate", "TuneResult", "tune"]

#: g dT and g' dT values tried per depth (dimensionless: the fraction of an error corrected
#: per sample)
GAIN_GRID = (0.04, 0.08, 0.12, 0.16, 0.2, 0.25, 0.3)
#: the largest default transient bound
MAX_GROWTH_CAP = 10.0
PRIME_GRID = (0.05, 0.075, 0.1, 0.15, 0.2, 0.25)


def graph_depths(sc: Scenario) -> NDArray[np.int64]:
    """Hops from the leader of each robot (1 = hears the leader), shape (n,)."""
    a = sc.graph.adjacency
    depth = np.full(sc.n, -1, dtype=np.int64)
    q: deque[int] = deque()
    for i in np.flatnonzero(sc.graph.leader > 0):
        depth[i] = 1
        q.append(int(i))
    while q:
        j = q.popleft()
        for i in np.flatnonzero(a[:, j] > 0):
            if depth[i] < 0:
                depth[i] = depth[j] + 1
                q.append(int(i))
    if (depth < 0).any():
        raise ScenarioError(f"{sc.source}: graph: robot(s) "
                            f"{', '.join(str(i + 1) for i in np.flatnonzero(depth < 0))} "
                            f"cannot be reached from the leader (Theorem 2)")
    return depth


@dataclass(frozen=True)
class TuneOptions:
    """position_level [m], heading_level [rad]: the targets; seeds: verification seeds;
    screen_trials / verify_trials: trials per screening / verification run; floor_window:
    floor = median of the last N trials; floor_factor: allowed floor against the scenario's
    own gains; max_growth: bound on max_k ||M^k|| of the lifted heading map (None: the
    scenario's own gains' value, at most MAX_GROWTH_CAP: no worse a transient); finalists:
    candidates verified; per_robot: one gain pair per graph depth (else one for all)."""

    position_level: float = TARGET_POSITION
    heading_level: float = TARGET_HEADING
    seeds: tuple[int, ...] = (1, 2, 3, 4, 5)
    screen_trials: int = 60
    verify_trials: int = 300
    floor_window: int = 100
    floor_factor: float = 1.5
    max_growth: float | None = None
    finalists: int = 6
    per_robot: bool = True
    gain_grid: tuple[float, ...] = GAIN_GRID
    prime_grid: tuple[float, ...] = PRIME_GRID


@dataclass
class Candidate:
    """A gain set with what is known about it: check results and per-seed rows."""

    gain: tuple[float, ...]
    gain_prime: tuple[float, ...]
    screen: dict[str, Any] | None = None
    cond20: float = math.nan
    rho: float = math.nan
    growth: float = math.nan
    growth_trial: int = 0
    rows: list[dict[str, Any]] = field(default_factory=list)

    @property
    def fields(self) -> dict[str, Any]:
        return {"law.gain": list(self.gain), "law.gain_prime": list(self.gain_prime)}

    def worst(self, key: str) -> float:
        vals = [r[key] for r in self.rows]
        return math.inf if any(v is None for v in vals) else float(max(vals))

    def median(self, key: str) -> float:
        vals = [r[key] for r in self.rows]
        return math.inf if any(v is None for v in vals) else float(np.median(vals))

    def summary(self) -> dict[str, Any]:
        def span(key: str) -> list[Any]:
            vals = [r[key] for r in self.rows]
            if any(v is None for v in vals):
                return [None if v is None else v for v in vals]
            return [min(vals), max(vals)]

        return {"gain": list(self.gain), "gain_prime": list(self.gain_prime),
                "cond20": self.cond20, "heading_rho": self.rho, "heading_growth": self.growth,
                "heading_growth_trial": self.growth_trial,
                "trials_to_position": span("trials_to_position"),
                "trials_to_heading": span("trials_to_heading"),
                "trial0_position": span("trial0_position"),
                "peak_position": span("peak_position"),
                "above_trial0": span("above_trial0"),
                "floor_position": span("floor_position"),
                "floor_heading": span("floor_heading"),
                "seeds": [r["seed"] for r in self.rows]}


@dataclass
class TuneResult:
    baseline: Candidate
    best: Candidate | None
    finalists: list[Candidate]
    screened: int
    checked: int
    ok: bool
    reason: str
    scenario_text: str
    baseline_trials: int
    max_growth: float


def _gains(depth: NDArray[np.int64], levels: list[int], per_level: tuple[float, ...],
           dt: float) -> tuple[float, ...]:
    by = dict(zip(levels, per_level, strict=True))
    return tuple(float(f"{by[int(d)] / dt:.6g}") for d in depth)


def _check(sc_text: str, cand: Candidate, source: str) -> None:
    sc = apply_fields(sc_text, cand.fields, source)
    cand.cond20 = condition20(sc.graph, np.asarray(sc.law.gain), sc.dt)
    hm = heading_map(sc, early_stop=True)
    if hm is None:
        raise ScenarioError(f"{source}: the lifted heading map is too large to build "
                            f"(robots x samples > checks.LIFTED_LIMIT): tune needs it for its "
                            f"guarantee")
    cand.rho, cand.growth, cand.growth_trial = hm.spectral_radius, hm.growth, hm.growth_trial


def _sim_tasks(sc_text: str, cand: Candidate, seeds: tuple[int, ...], trials: int,
               opt: TuneOptions, source: str, floor_window: int | None = None
               ) -> list[dict[str, Any]]:
    fw = min(opt.floor_window if floor_window is None else floor_window, trials)
    return [{"id": point_id(sc_text, cand.fields, trials, s), "scenario": sc_text,
             "fields": cand.fields, "seed": s, "trials": trials,
             "position_level": opt.position_level, "heading_level": opt.heading_level,
             "floor_window": fw, "source": source}
            for s in seeds]


def _score(row: dict[str, Any]) -> tuple[float, float]:
    tp, th = row["trials_to_position"], row["trials_to_heading"]
    if tp is None or th is None or row["above_trial0"] > 0:
        return (math.inf, math.inf)
    return (max(tp, th), tp + th)


def tune(sc: Scenario, opt: TuneOptions = TuneOptions(), workers: int | None = None,
         scheduler: str | None = None, log: Any = None) -> TuneResult:
    """Choose per-depth gains (g, g') for ``sc``; see ``_tune``. Local worker processes are
    stopped on return."""
    try:
        return _tune(sc, opt, workers, scheduler, log)
    finally:
        close_pools()


@dataclass
class _Run:
    """What every step of one tuning shares: the scenario (its text and source, for the
    tasks), the options, where tasks run and where messages go."""

    sc: Scenario
    opt: TuneOptions
    workers: int | None
    scheduler: str | None
    log: Any

    @property
    def text(self) -> str:
        return self.sc.text

    @property
    def source(self) -> str:
        return self.sc.source

    def rows(self, tasks: list[dict[str, Any]], label: str) -> Any:
        """The tasks' result rows as they finish, with a progress bar."""
        return _progress(map_tasks(tasks, self.workers, self.scheduler), len(tasks), label,
                         self.log)


def _tune(sc: Scenario, opt: TuneOptions, workers: int | None, scheduler: str | None,
          log: Any) -> TuneResult:
    """Choose per-depth gains (g, g') for ``sc`` (its law and memory reading).

    Returns the baseline (the scenario's own gains) and the chosen candidate, both verified
    over ``opt.seeds``. ``ok`` is False, with ``reason``, if no candidate met every
    requirement (then ``best`` is the best that met the guarantees, or None).
    """
    if log is None:
        def log(msg: str) -> None:
            print(msg, file=sys.stderr, flush=True)
    run = _Run(sc, opt, workers, scheduler, log)
    depth = graph_depths(sc)  # first: a robot the leader cannot reach is refused at once
    base = Candidate(tuple(sc.law.gain), tuple(sc.law.gain_prime))
    _check(sc.text, base, sc.source)
    max_growth = (min(base.growth, MAX_GROWTH_CAP) if opt.max_growth is None
                  else opt.max_growth)
    log(f"tune: the scenario's gains: (20) {base.cond20:.4f}, rho {base.rho:.4f}, max ||M^k|| "
        f"{base.growth:.3g}; candidates must keep max ||M^k|| <= {max_growth:.3g}")
    base_trials = _baseline(run, base)
    fp_max, fh_max = _floor_bounds(base, opt)
    cands = _candidates(run, depth)
    ranked = _screen(run, cands, fp_max, fh_max)
    finalists, checked = _check_in_order(run, ranked, max_growth)
    _verify(run, finalists)
    best, ok, reason = _choose(finalists, ranked, fp_max, fh_max, opt)
    return TuneResult(baseline=base, best=best, finalists=finalists, screened=len(cands),
                      checked=checked, ok=ok, reason=reason, scenario_text=sc.text,
                      baseline_trials=base_trials, max_growth=max_growth)


def _baseline(run: _Run, base: Candidate) -> int:
    """0. The scenario's own gains over the seeds: the floors to keep. Returns the trials
    each seed ran."""
    opt = run.opt
    base_trials = max(opt.verify_trials, run.sc.trials)
    tasks = _sim_tasks(run.text, base, opt.seeds, base_trials, opt, run.source)
    for row in run.rows(tasks, "baseline"):
        row["seed"] = int(row["id"].rsplit("-s", 1)[1])
        base.rows.append(row)
    base.rows.sort(key=lambda r: r["seed"])
    fp_max, fh_max = _floor_bounds(base, opt)
    run.log(f"tune: the scenario's gains over seeds {list(opt.seeds)} ({base_trials} "
            f"trials): floors {base.median('floor_position'):.4g} m, "
            f"{base.median('floor_heading'):.4g} rad (median over seeds); tuned floors must "
            f"stay below {fp_max:.4g} m, {fh_max:.4g} rad on every seed")
    return base_trials


def _floor_bounds(base: Candidate, opt: TuneOptions) -> tuple[float, float]:
    """The largest floors [m, rad] a candidate may reach: the scenario's own (median over
    the seeds) times ``floor_factor``."""
    return (base.median("floor_position") * opt.floor_factor,
            base.median("floor_heading") * opt.floor_factor)


def _candidates(run: _Run, depth: NDArray[np.int64]) -> list[Candidate]:
    """1. The grid of (g, g') per graph depth (``depth``: of each robot), g filtered by
    condition (20) (cheap, exact)."""
    sc, opt = run.sc, run.opt
    levels = sorted({int(d) for d in depth}) if opt.per_robot else [-1]
    dep = depth if opt.per_robot else np.full(sc.n, -1, dtype=np.int64)
    law22 = sc.law.kind == 22
    primes = (opt.prime_grid[0],) if law22 else opt.prime_grid
    gain_sets = []
    for combo in itertools.product(opt.gain_grid, repeat=len(levels)):
        g = _gains(dep, levels, combo, sc.dt)
        if condition20(sc.graph, np.asarray(g), sc.dt) < 1.0:
            gain_sets.append(g)
    prime_sets = [_gains(dep, levels, combo, sc.dt)
                  for combo in itertools.product(primes, repeat=len(levels))]
    if law22:  # no current term: g' does not matter, keep the scenario's
        prime_sets = [tuple(sc.law.gain_prime)]
    cands = [Candidate(g, gp) for g in gain_sets for gp in prime_sets]
    run.log(f"tune: {sc.n} robots at graph depths {sorted(set(depth.tolist()))}; "
            f"{len(gain_sets)} gain sets satisfy condition (20), x {len(prime_sets)} g' sets = "
            f"{len(cands)} candidates")
    return cands


def _screen(run: _Run, cands: list[Candidate], fp_max: float, fh_max: float
            ) -> list[Candidate]:
    """2. A short run of each candidate on the scenario's seed; those that reach both
    levels, never above trial 0 and with floors within the bounds, best first."""
    opt = run.opt
    window = max(1, opt.screen_trials // 3)
    tasks = []
    by_id: dict[str, Candidate] = {}
    for c in cands:
        t = _sim_tasks(run.text, c, (run.sc.seed,), opt.screen_trials, opt, run.source,
                       floor_window=window)[0]
        tasks.append(t)
        by_id[t["id"]] = c
    for row in run.rows(tasks, "screen"):
        by_id[row["id"]].screen = row
    ranked = sorted((c for c in cands if c.screen is not None
                     and _score(c.screen)[0] < math.inf
                     and c.screen["floor_position"] <= fp_max
                     and c.screen["floor_heading"] <= fh_max),
                    key=lambda c: _score(c.screen or {}))
    run.log(f"tune: {len(ranked)} candidates reach both levels within {opt.screen_trials} "
            f"trials, without a trial above trial 0 and with floors (median of the last "
            f"{window}) within the bounds")
    return ranked


def _check_in_order(run: _Run, ranked: list[Candidate], max_growth: float
                    ) -> tuple[list[Candidate], int]:
    """3. The guarantees of the screened candidates, best first, a batch at a time on the
    workers, until ``opt.finalists`` pass. Returns them and how many were checked."""
    sc, opt = run.sc, run.opt
    finalists: list[Candidate] = []
    checked = 0
    batch = 2 * max(1, run.workers or os.cpu_count() or 1)
    pos = 0
    while len(finalists) < opt.finalists and pos < len(ranked):
        group = ranked[pos:pos + batch]
        pos += batch
        tasks = [{"id": f"check-{i}", "scenario": run.text, "fields": c.fields,
                  "trials": sc.trials, "source": run.source, "stop_above": max_growth}
                 for i, c in enumerate(group)]
        for row in map_tasks(tasks, run.workers, run.scheduler):
            c = group[int(row["id"].split("-")[1])]
            c.cond20, c.rho = row["cond20"], row["heading_rho"]
            c.growth, c.growth_trial = row["heading_growth"], row["heading_growth_trial"]
            if c.rho is None:
                raise ScenarioError(f"{run.source}: the lifted heading map is too large to "
                                    f"build (robots x samples > checks.LIFTED_LIMIT): tune "
                                    f"needs it for its guarantee")
        checked += len(group)
        for c in group:
            kept = c.cond20 < 1.0 and c.rho < 1.0 and c.growth <= max_growth
            run.log(f"tune: check g = {_fmt(c.gain)}, g' = {_fmt(c.gain_prime)}: (20) "
                    f"{c.cond20:.4f}, rho {c.rho:.4f}, max ||M^k|| "
                    f"{'>' if not kept and c.growth > max_growth else ''}{c.growth:.3g} -> "
                    f"{'kept' if kept else 'rejected'}")
            if kept and len(finalists) < opt.finalists:
                finalists.append(c)
    return finalists, checked


def _verify(run: _Run, finalists: list[Candidate]) -> None:
    """4. Each finalist over the seeds (its ``rows``, by seed)."""
    opt = run.opt
    tasks, owner = [], {}
    for c in finalists:
        for t in _sim_tasks(run.text, c, opt.seeds, opt.verify_trials, opt, run.source):
            tasks.append(t)
            owner[t["id"]] = c
    for row in run.rows(tasks, "verify"):
        row["seed"] = int(row["id"].rsplit("-s", 1)[1])
        owner[row["id"]].rows.append(row)
    for c in finalists:
        c.rows.sort(key=lambda r: r["seed"])


def _choose(finalists: list[Candidate], ranked: list[Candidate], fp_max: float,
            fh_max: float, opt: TuneOptions) -> tuple[Candidate | None, bool, str]:
    """The winner (fewest trials to both levels on the worst seed) among the finalists
    that met every requirement, whether there is one, and why not."""
    good = [c for c in finalists
            if c.worst("above_trial0") == 0 and c.worst("floor_position") <= fp_max
            and c.worst("floor_heading") <= fh_max and c.worst("trials_to_position") < math.inf
            and c.worst("trials_to_heading") < math.inf]

    def key(c: Candidate) -> tuple[float, float, float]:
        tp, th = c.worst("trials_to_position"), c.worst("trials_to_heading")
        return (max(tp, th), tp + th, c.worst("floor_position"))

    if good:
        return min(good, key=key), True, "all requirements met"
    if finalists:
        return min(finalists, key=key), False, (
            "no candidate met every requirement over all seeds (no trial above trial 0, "
            "floors within the factor); the best one that met the guarantees is shown")
    if not ranked:
        return None, False, (
            f"no candidate reached both levels within {opt.screen_trials} trials without a "
            f"trial above trial 0 and with floors within the bounds; try more "
            f"--screen-trials, a finer --gain-grid / --prime-grid or a larger --floor-factor")
    return None, False, (
        f"none of the {len(ranked)} candidates that passed the screening met the "
        f"guarantees; raise --max-growth or give a finer grid")


def _progress(rows: Any, total: int, label: str, log: Any) -> Any:
    with points_progress(total, 0, f"tune {label}") as bar:
        for row in rows:
            bar.step()
            yield row


def _fmt(v: tuple[float, ...]) -> str:
    if len(set(v)) == 1:
        return f"{v[0]:.4g}"
    return "[" + ", ".join(f"{x:.4g}" for x in v) + "]"


def tuned_text(res: TuneResult, sc: Scenario) -> str:
    """The tuned scenario file: the original with law.gain and law.gain_prime replaced."""
    assert res.best is not None
    body = scenario_text_with(res.scenario_text, res.best.fields)
    head = (f"# {sc.name} with gains chosen by `formation-ilc tune` (one pair per graph depth).\n"
            f"# gain = g of Gamma per robot, gain_prime = g' of Gamma' per robot.\n")
    return head + body


def report_lines(res: TuneResult, sc: Scenario, opt: TuneOptions) -> list[str]:
    """A Markdown report: the scenario's gains beside the tuned ones."""

    def rng(c: Candidate, key: str, fmt: str) -> str:
        vals = [r[key] for r in c.rows]
        if any(v is None for v in vals):
            return "never (" + ", ".join("never" if v is None else format(v, fmt)
                                         for v in vals) + ")"
        lo, hi = min(vals), max(vals)
        return format(lo, fmt) if lo == hi else f"{format(lo, fmt)} to {format(hi, fmt)}"

    out = [f"# Tuning {sc.name}: law ({sc.law.kind}), memory {sc.law.memory}", "",
           f"Verified over seeds {', '.join(map(str, opt.seeds))}; noise and delays as in the "
           f"scenario. Floor = median of the last {opt.floor_window} trials. Scenario gains "
           f"run {res.baseline_trials} trials, tuned gains {opt.verify_trials}.", "",
           "| | scenario's gains | tuned |" if res.best is not None else
           "| | scenario's gains |",
           "| --- | --- | --- |" if res.best is not None else "| --- | --- |"]
    cands = [res.baseline] + ([res.best] if res.best is not None else [])
    rows = [
        ("g (Gamma)", lambda c: _fmt(c.gain)),
        ("g' (Gamma')", lambda c: _fmt(c.gain_prime)),
        ("condition (20), B with dT", lambda c: f"{c.cond20:.6f}"),
        ("heading map spectral radius", lambda c: f"{c.rho:.4f}"),
        (r"heading map max_k \|\|M^k\|\| (at k)", lambda c: f"{c.growth:.3g} ({c.growth_trial})"),
        (f"trials to {opt.position_level:g} m", lambda c: rng(c, "trials_to_position", "d")),
        (f"trials to {opt.heading_level:g} rad", lambda c: rng(c, "trials_to_heading", "d")),
        ("trial 0 position [m]", lambda c: rng(c, "trial0_position", ".3f")),
        ("peak position [m]", lambda c: rng(c, "peak_position", ".3f")),
        ("trials above trial 0", lambda c: rng(c, "above_trial0", "d")),
        ("floor position [m]", lambda c: rng(c, "floor_position", ".4f")),
        ("floor heading [rad]", lambda c: rng(c, "floor_heading", ".5f")),
    ]
    for name, f in rows:
        out.append(f"| {name} | " + " | ".join(f(c) for c in cands) + " |")
    out += ["", f"Guarantees: condition (20) < 1, spectral radius < 1, max ||M^k|| <= "
                f"{res.max_growth:.3g}. Candidates screened: {res.screened}; lifted maps "
                f"built: {res.checked}; verdict: {res.reason}."]
    return out


def result_json(res: TuneResult) -> str:
    return json.dumps({"ok": res.ok, "reason": res.reason,
                       "baseline": res.baseline.summary(),
                       "tuned": None if res.best is None else res.best.summary(),
                       "finalists": [c.summary() for c in res.finalists],
                       "screened": res.screened, "checked": res.checked}, indent=1) + "\n"
