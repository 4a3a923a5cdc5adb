"""``formation-ilc tune`` and ``sweep``: gain design and parameter sweeps."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

from formation_ilc.cli.options import (
    OptionError,
    int_range,
    make_out_dir,
    out_dir_arg,
    paragraphs,
    positive_float,
    positive_int,
    scenario_arg,
)
from formation_ilc.cli.simulate import _fits, _out_dir
from formation_ilc.config.scenario import Scenario, ScenarioError, load_scenario

SWEEP_EXAMPLE = """\
example spec (study.yaml):
  scenario: paper-hexagon6        # built-in name or scenario file (relative to the spec)
  trials: 300                     # per point
  seeds: {first: 1, count: 5}     # or [1, 2, 3]
  grid:                           # every combination; or random: {count, seed, fields}
    law.gain: [0.08, 0.4, 0.8]    # a number, or one per robot: [0.4, 1.2, 1.2, 0.4, 1.2, 1.2]
    law.kind: [9, 22, 23]
    delay: [paper, none]
then: formation-ilc sweep study.yaml --out runs/study   (again after Ctrl-C: resumes)
"""


def _add_tune(sub: Any) -> None:
    p = sub.add_parser(
        "tune", help="choose learning gains: fewest trials, under condition (20) and a "
                     "bounded heading map",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=paragraphs(
                    "Choose g (Gamma, predictive term) and g' (Gamma', current term), one pair "
                    "per graph depth (hops from the leader), for the fewest trials to the "
                    "target errors.\n\nGuarantee: every candidate satisfies condition (20) "
                    "and has a lifted heading map with spectral radius < 1 and max_k ||M^k|| "
                    "<= --max-growth (the transient bound). Candidates are screened by short "
                    "simulations, checked best first, and the finalists verified by full "
                    "simulations over --seeds with noise and delays on, beside the "
                    "scenario's own gains. Writes DIR/SCENARIO-tuned.yaml (loads with the "
                    "strict loader and reproduces the report), DIR/report.md and "
                    "DIR/tune.json. Exit status 1 if no candidate met every requirement.\n\n"
                    "Method and results: docs/tuning.md."))
    scenario_arg(p)
    p.add_argument("--law", type=int, choices=(9, 22, 23), help="law to tune (default: the "
                   "scenario's)")
    p.add_argument("--memory", choices=("feedforward", "literal"),
                   help="memory reading to tune (default: the scenario's)")
    p.add_argument("--position-level", type=positive_float, default=1.0, metavar="M",
                   help="target max position error [m] (default 1)")
    p.add_argument("--heading-level", type=positive_float, default=0.1, metavar="RAD",
                   help="target max heading error [rad] (default 0.1)")
    p.add_argument("--seeds", type=int_range(1, 10_000), default=5, metavar="S",
                   help="verify over seeds 1..S (default 5)")
    p.add_argument("--verify-trials", type=positive_int, default=300, metavar="K",
                   help="trials of each verification run (default 300; the scenario's own "
                        "gains run max(K, its trials))")
    p.add_argument("--screen-trials", type=positive_int, default=60, metavar="K",
                   help="trials of each screening run (default 60): tune finds gains that "
                        "reach the levels within K trials")
    p.add_argument("--floor-window", type=positive_int, default=100, metavar="N",
                   help="floor = median of the last N trials (default 100)")
    p.add_argument("--floor-factor", type=positive_float, default=1.5, metavar="F",
                   help="tuned floors may be at most F times the scenario's own (default 1.5)")
    p.add_argument("--max-growth", type=positive_float, metavar="G",
                   help="bound on max_k ||M^k|| of the lifted heading map, the transient "
                        "bound (default: the scenario's own gains' value, at most 10)")
    p.add_argument("--gain-grid", metavar="C1,C2,...",
                   help="values of g dT tried per graph depth (default "
                        "0.04,0.08,0.12,0.16,0.2,0.25,0.3)")
    p.add_argument("--prime-grid", metavar="A1,A2,...",
                   help="values of g' dT tried per graph depth (default "
                        "0.05,0.075,0.1,0.15,0.2,0.25)")
    p.add_argument("--uniform", action="store_true",
                   help="one gain pair for all robots instead of one per graph depth")
    p.add_argument("--workers", type=int_range(1, 4096), metavar="N",
                   help="local processes (default: all cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the simulations on a Dask cluster (tcp://HOST:PORT)")
    p.add_argument("--out", type=out_dir_arg, metavar="DIR", help="output folder (default: "
                   "runs/SCENARIO-tune-TIME)")


def _add_sweep(sub: Any) -> None:
    p = sub.add_parser(
        "sweep", help="run a parameter study from a spec file, resumable, locally or on Dask",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=paragraphs(
                    "Run a study: a grid or random draws over scenario fields (law.gain, "
                    "law.gain_prime, law.kind, law.memory, graph, delay, noise_scale) times "
                    "seeds. Each point is a batch simulation reduced to one row (trials to "
                    "the levels, floors, peak, and the check's predictions per "
                    "configuration). Writes DIR/results.csv, a heat map and a line plot.\n\n"
                    "Resumable: each finished point is written at once to "
                    "DIR/points/ID.json; run the same command again after a crash or Ctrl-C "
                    "and only the missing points run. The same spec gives the same table "
                    "locally and on a Dask cluster.\n\nSpec format: docs/tuning.md, "
                    "'sweep: parameter studies'."),
        epilog=SWEEP_EXAMPLE)
    p.add_argument("spec", type=Path, metavar="SPEC.yaml",
                   help="the study (see the example below)")
    p.add_argument("--out", type=out_dir_arg, metavar="DIR",
                   help="output folder (default: runs/SPEC-sweep)")
    p.add_argument("--workers", type=int_range(1, 4096), metavar="N",
                   help="local processes (default: every core; 1 = in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address, e.g. tcp://127.0.0.1:8786 (pip install -e "
                        "'.[cluster]'); workers get the scenario text, no shared disk needed")
    p.add_argument("--metric", default="trials_to_position",
                   help="column the plots show (default trials_to_position)")
    p.add_argument("--no-plots", action="store_true", help="table only")


def cmd_tune(args: argparse.Namespace) -> int:
    from dataclasses import replace as dc_replace

    from formation_ilc.config.scenario import scenario_from_text
    from formation_ilc.studies.study import scenario_text_with
    from formation_ilc.studies.tune import TuneOptions, report_lines, result_json, tune, tuned_text

    sc = load_scenario(args.scenario)
    over: dict[str, Any] = {}
    if args.law is not None:
        over["law.kind"] = args.law
    if args.memory is not None:
        over["law.memory"] = args.memory
    if over:
        sc = scenario_from_text(scenario_text_with(sc.text, over), sc.source)
    if args.floor_window > args.verify_trials:
        raise OptionError("--floor-window must be <= --verify-trials")
    grids: dict[str, Any] = {}
    for name in ("gain_grid", "prime_grid"):
        val = getattr(args, name)
        if val is None:
            continue
        try:
            grids[name] = tuple(float(x) for x in val.split(",") if x.strip())
        except ValueError:
            raise OptionError(f"--{name.replace('_', '-')}: expected numbers like "
                              f"0.08,0.16, got {val[:60]!r}") from None
        if not grids[name] or not all(math.isfinite(x) and x > 0 for x in grids[name]):
            raise OptionError(f"--{name.replace('_', '-')}: values must be finite and > 0, "
                              f"got {val[:60]!r}")
        if len(grids[name]) > 64:
            raise OptionError(f"--{name.replace('_', '-')}: at most 64 values, got "
                              f"{len(grids[name])}")
    opt = TuneOptions(**grids, position_level=args.position_level, heading_level=args.heading_level,
                      seeds=tuple(range(1, args.seeds + 1)), screen_trials=args.screen_trials,
                      verify_trials=args.verify_trials, floor_window=args.floor_window,
                      floor_factor=args.floor_factor, max_growth=args.max_growth,
                      per_robot=not args.uniform)
    if args.scheduler is None:
        _fits_points(sc, max(args.verify_trials, sc.trials), args.workers)
    out = _out_dir(args.out, sc, "tune")
    res = tune(sc, opt, workers=args.workers, scheduler=args.scheduler)
    lines = report_lines(res, sc, opt)
    print("\n".join(lines))
    (out / "report.md").write_text("\n".join(lines) + "\n")
    (out / "tune.json").write_text(result_json(res))
    files = ["report.md", "tune.json"]
    if res.best is not None:
        name = f"{sc.name}-tuned.yaml"
        (out / name).write_text(tuned_text(res, dc_replace(sc)))
        files.insert(0, name)
    print(f"results in {out}/ ({', '.join(files)})")
    return 0 if res.ok else 1


def _fits_points(sc: Scenario, trials: int, workers: int | None) -> None:
    """Refuse a study whose workers would together need more memory than is available: each
    runs one simulation (metrics kept) or one check at a time."""
    from formation_ilc.model.checks import check_bytes
    from formation_ilc.model.simulate import simulate_bytes

    per = max(simulate_bytes(sc, trials), check_bytes(sc))
    _fits(sc, per * (workers or os.cpu_count() or 1), "a study point per worker")


def _regular_file(path: Path) -> None:
    if not path.is_file():
        why = "not a regular file" if path.exists() else "no such file"
        raise ScenarioError(f"{path}: {why}")


def cmd_sweep(args: argparse.Namespace) -> int:
    from formation_ilc.studies.study import CHECK_COLUMNS, SIM_COLUMNS
    from formation_ilc.studies.sweep import load_spec, plot_table, run_sweep

    if args.metric not in SIM_COLUMNS + CHECK_COLUMNS:  # before the study runs, not after
        raise OptionError(f"--metric: no column {args.metric[:60]!r} (columns: "
                          f"{', '.join(SIM_COLUMNS + CHECK_COLUMNS)})")
    spec = load_spec(args.spec)
    out = make_out_dir(args.out or Path("runs") / f"{args.spec.stem}-sweep")
    if args.scheduler is None:
        from formation_ilc.studies.study import apply_fields

        graphs: dict[str, dict[str, Any]] = {}  # only 'graph' changes robots x samples
        for cfg in spec.configs:
            graphs.setdefault(json.dumps(cfg.get("graph"), sort_keys=True, default=str), cfg)
        for cfg in list(graphs.values())[:16]:
            sc = apply_fields(spec.scenario_text, cfg, spec.source, trials=spec.trials)
            _fits_points(sc, spec.trials, args.workers)
    n = len(spec.configs) * len(spec.seeds)
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else (
        f"{args.workers or os.cpu_count()} local processes")
    print(f"sweep {args.spec}: {len(spec.configs)} configurations x {len(spec.seeds)} seeds = "
          f"{n} points of {spec.trials} trials, on {where}", file=sys.stderr)
    table = run_sweep(spec, out, workers=args.workers, scheduler=args.scheduler)
    files = [table.name]
    if not args.no_plots:
        files += [p.name for p in plot_table(spec, table, out, args.metric)]
    print(f"results in {out}/ ({', '.join(files)})")
    return 0
