"""``formation-ilc``: simulate, compare, check and launch formation learning runs.

Run ``formation-ilc COMMAND --help`` for each command.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import Any

# The lifted check multiplies 1800 x 1800 matrices; on 2 cores a threaded BLAS spins more
# than it gains (measured: 10.5 s threaded, 3.9 s single-threaded). Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from .memoryfile import MemoryFileError, load_memory, save_memory  # noqa: E402
from .scenario import Scenario, ScenarioError, builtin_scenarios, load_scenario  # noqa: E402
from .topology import SpanningTreeError  # noqa: E402

EXAMPLES = """\
examples:
  formation-ilc scenarios                              list the built-in scenarios
  formation-ilc check paper-hexagon6                   Theorem 2, condition (20), lifted map
  formation-ilc simulate paper-hexagon6 --trials 2000  the paper's study, law (9)
  formation-ilc simulate paper-hexagon6 --law 22 --no-noise --out runs/hex22
  formation-ilc compare paper-hexagon6 --trials 500    laws 9, 22, 23 in both memory readings
  formation-ilc tune paper-hexagon6 --out runs/tuned   gains that learn in tens of trials
  formation-ilc sweep study.yaml --out runs/study      gains x graphs x laws x seeds
  formation-ilc launch paper-triangle3 --trials 20     real ROS 2 processes, one per robot
  formation-ilc launch paper-triangle3 --record run.mcap && formation-ilc analyze run.mcap

A SCENARIO is a built-in name or a YAML file (see formation_ilc/scenarios/*.yaml).
"""


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


def _paras(text: str) -> str:
    """Paragraphs (separated by blank lines) wrapped to 88 columns, for raw help text."""
    import textwrap

    return "\n\n".join(textwrap.fill(" ".join(par.split()), 88) for par in text.split("\n\n"))


def _scenario_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO",
                   help="built-in scenario name (formation-ilc scenarios) or a YAML file")


def _run_options(p: argparse.ArgumentParser, law: bool = True) -> None:
    p.add_argument("--trials", type=int, metavar="K",
                   help="number of trials (default: the scenario's 'trials')")
    if law:
        p.add_argument("--law", type=int, choices=(9, 22, 23),
                       help="9: predictive + delay-compensated current term (the paper's); "
                            "22: predictive only; 23: current term ignores the delay")
        p.add_argument("--memory", choices=("feedforward", "literal"),
                       help="what the learning memory holds (paper-notes 12): feedforward "
                            "(default; the current term is feedback on top) or literal "
                            "(the applied input, current term included)")
    p.add_argument("--seed", type=int, help="random seed (default: the scenario's)")
    p.add_argument("--no-noise", action="store_true",
                   help="no initial shifts, disturbances or measurement noise")
    p.add_argument("--no-delay", action="store_true", help="no communication delays")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="formation-ilc",
        description="Distributed iterative learning control of differential-drive robot "
                    "formations: robots repeat a trial, learn from it, and converge on a "
                    "formation that follows a virtual leader, despite initial shifts, "
                    "disturbances, noise and communication delays.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")

    sub.add_parser("scenarios", help="list the built-in scenarios")

    p = sub.add_parser("simulate", help="batch-simulate all robots over all trials",
                       description="Batch-simulate a scenario. Writes DIR/metrics.csv (one "
                                   "row per trial, trial 0 = the first run), "
                                   "DIR/summary.json and plots of error vs trial and of "
                                   "chosen trials' trajectories.")
    _scenario_arg(p)
    _run_options(p)
    p.add_argument("--no-plots", action="store_true", help="write no figures")
    p.add_argument("--init-memory", type=Path, metavar="MEMORY.npz",
                   help="start from a learned memory (a run's memory.npz, or an older "
                        "memory.npy), e.g. learn noise-free first, then go on with noise or "
                        "on the robots (`launch --init-memory`; the paper's sim-to-real "
                        "workflow, paper-notes 10)")
    p.add_argument("--first-trial", type=int, default=0, metavar="K",
                   help="number the trials from K (their random draws are trial K's, ...)")
    p.add_argument("--record", type=Path, metavar="RUN.mcap",
                   help="also write the run as ROS 2 MCAP, on the distributed stack's topics "
                        "(analyse it with `formation-ilc analyze RUN.mcap`)")
    p.add_argument("--keep", metavar="K1,K2,...",
                   help="trials whose trajectories are plotted and saved "
                        "(default: first, about 10%%, 40%% and last)")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder (default: runs/SCENARIO-LAW-MEMORY-TIME)")

    p = sub.add_parser("compare", help="laws 9, 22, 23 in both memory readings, same draws",
                       description="Run laws (9), (22) and (23), each with memory "
                                   "'feedforward' and 'literal', on the same random draws, "
                                   "and plot their errors in one figure (like Fig. 7).")
    _scenario_arg(p)
    _run_options(p, law=False)
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder")

    p = sub.add_parser("check", help="Theorem 2, condition (20) and the lifted heading map",
                       description="Check a scenario before running it. Exit status 2 if "
                                   "the graph has no spanning tree (Theorem 2).")
    _scenario_arg(p)
    p.add_argument("--law", type=int, choices=(9, 22, 23))
    p.add_argument("--memory", choices=("feedforward", "literal"))
    p.add_argument("--trials", type=int, metavar="K",
                   help="horizon for the transient-growth estimate (default: scenario's)")
    p.add_argument("--no-delay", action="store_true",
                   help="check the delay-free configuration (as run with --no-delay)")

    p = sub.add_parser(
        "tune", help="choose learning gains: fewest trials, under condition (20) and a "
                     "bounded heading map",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_paras(
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
    _scenario_arg(p)
    p.add_argument("--law", type=int, choices=(9, 22, 23), help="law to tune (default: the "
                   "scenario's)")
    p.add_argument("--memory", choices=("feedforward", "literal"),
                   help="memory reading to tune (default: the scenario's)")
    p.add_argument("--position-level", type=float, default=1.0, metavar="M",
                   help="target max position error [m] (default 1)")
    p.add_argument("--heading-level", type=float, default=0.1, metavar="RAD",
                   help="target max heading error [rad] (default 0.1)")
    p.add_argument("--seeds", type=int, default=5, metavar="S",
                   help="verify over seeds 1..S (default 5)")
    p.add_argument("--verify-trials", type=int, default=300, metavar="K",
                   help="trials of each verification run (default 300; the scenario's own "
                        "gains run max(K, its trials))")
    p.add_argument("--screen-trials", type=int, default=60, metavar="K",
                   help="trials of each screening run (default 60): tune finds gains that "
                        "reach the levels within K trials")
    p.add_argument("--floor-window", type=int, default=100, metavar="N",
                   help="floor = median of the last N trials (default 100)")
    p.add_argument("--floor-factor", type=float, default=1.5, metavar="F",
                   help="tuned floors may be at most F times the scenario's own (default 1.5)")
    p.add_argument("--max-growth", type=float, metavar="G",
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
    p.add_argument("--workers", type=int, metavar="N", help="local processes (default: all "
                   "cores)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run the simulations on a Dask cluster (tcp://HOST:PORT)")
    p.add_argument("--out", type=Path, metavar="DIR", help="output folder (default: "
                   "runs/SCENARIO-tune-TIME)")

    p = sub.add_parser(
        "sweep", help="run a parameter study from a spec file, resumable, locally or on Dask",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=_paras(
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
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder (default: runs/SPEC-sweep)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="local processes (default: every core; 1 = in this process)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="Dask scheduler address, e.g. tcp://127.0.0.1:8786 (pip install -e "
                        "'.[cluster]'); workers get the scenario text, no shared disk needed")
    p.add_argument("--metric", default="trials_to_position",
                   help="column the plots show (default trials_to_position)")
    p.add_argument("--no-plots", action="store_true", help="table only")

    p = sub.add_parser("analyze", help="metrics, delays, plots and a report from a recording",
                       description="Analyse a recorded run (formation-ilc launch --record, or "
                                   "simulate --record) from the MCAP file alone. Writes "
                                   "DIR/metrics.csv (the columns of simulate), delays.csv, "
                                   "errors.png, trajectories.png, formation.png, delays.png "
                                   "and report.html (one page to read at a glance). A file "
                                   "cut short by a crash is read up to the cut. A file "
                                   "damaged in the middle is read past the damage; what was "
                                   "lost is reported and the exit status is 1.")
    p.add_argument("recording", type=Path, metavar="RUN.mcap")
    p.add_argument("--out", type=Path, metavar="DIR",
                   help="output folder (default: RUN-analysis next to the file)")
    p.add_argument("--no-plots", action="store_true", help="tables only")

    p = sub.add_parser("mcap-repair", help="rewrite a recording cut short by a crash",
                       description="A recorder killed mid-run leaves an MCAP file without "
                                   "its summary and footer; everything flushed before the "
                                   "kill still reads back (analyze reads such files as they "
                                   "are). This writes a complete copy that every MCAP tool "
                                   "opens, keeping every message that reads back.")
    p.add_argument("recording", type=Path, metavar="RUN.mcap")
    p.add_argument("-o", "--output", type=Path, metavar="FIXED.mcap",
                   help="default: RUN.repaired.mcap")

    try:
        from . import launch  # type: ignore[attr-defined,unused-ignore]
    except ImportError:  # the distributed stack is not installed with this build
        launch = None  # type: ignore[assignment]
    if launch is not None:
        p = sub.add_parser("launch", help="run the distributed ROS 2 stack on localhost",
                           description=launch.__doc__,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        launch.add_arguments(p)
    return ap


class Progress:
    """One line, rewritten on a terminal; a line every 10 % otherwise."""

    def __init__(self, total: int, label: str):
        self.total = total
        self.label = label
        self.t0 = time.perf_counter()
        self.tty = sys.stderr.isatty()
        self.last = -1.0

    def __call__(self, k: int, row: Any) -> None:
        done = k + 1
        now = time.perf_counter()
        frac = done / self.total
        if self.tty:
            if now - self.last < 0.1 and done != self.total:
                return
        elif int(frac * 10) == int(self.last) and done != self.total:
            return
        self.last = now if self.tty else int(frac * 10)
        msg = (f"{self.label}: trial {done}/{self.total}  max position {row[1]:.4g} m  "
               f"max heading {row[2]:.4g} rad  [{now - self.t0:.1f} s]")
        if self.tty:
            end = "\n" if done == self.total else ""
            print("\r" + msg.ljust(100), end=end, file=sys.stderr, flush=True)
        else:
            print(msg, file=sys.stderr, flush=True)


def _out_dir(arg: Path | None, sc: Scenario, tag: str) -> Path:
    if arg is None:
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        arg = Path("runs") / f"{sc.name}-{tag}-{stamp}"
    arg.mkdir(parents=True, exist_ok=True)
    return arg


def _scenario(args: argparse.Namespace, law: bool = True) -> Scenario:
    sc = load_scenario(args.scenario)
    return sc.with_options(
        law=getattr(args, "law", None) if law else None,
        memory=getattr(args, "memory", None) if law else None,
        noise=not getattr(args, "no_noise", False), delay=not getattr(args, "no_delay", False),
        seed=getattr(args, "seed", None), trials=getattr(args, "trials", None))


def _default_keep(k: int) -> list[int]:
    return sorted({0, max(0, k // 10 - 1), max(0, 2 * k // 5 - 1), k - 1})


def cmd_simulate(args: argparse.Namespace) -> int:
    from .checks import condition20
    from .metrics import MetricsWriter
    from .simulate import simulate

    sc = _scenario(args)
    k = sc.trials
    if k < 1:
        raise ScenarioError("--trials must be at least 1")
    first = int(args.first_trial)
    if first < 0:
        raise ScenarioError("--first-trial must be >= 0")
    if args.keep:
        try:
            keep = sorted({int(x) for x in args.keep.split(",") if x.strip()})
        except ValueError:
            raise ScenarioError(f"--keep: expected trial numbers like 0,99,1999, got "
                                f"{args.keep!r}") from None
        bad = [x for x in keep if not first <= x < first + k]
        if bad:
            raise ScenarioError(f"--keep: trial {bad[0]} is outside {first}..{first + k - 1}")
    else:
        keep = [first + t for t in _default_keep(k)]
    init = None
    if args.init_memory is not None:
        try:
            init = load_memory(args.init_memory, sc)
        except MemoryFileError as exc:
            raise ScenarioError(str(exc)) from None
    out = _out_dir(args.out, sc, f"law{sc.law.kind}-{sc.law.memory}")
    # metrics are written as they come, so a crash or Ctrl-C keeps every finished trial
    writer = MetricsWriter(out / "metrics.csv")
    bar = Progress(k, f"{sc.name} law ({sc.law.kind}) {sc.law.memory}")

    def on_trial(trial: int, row: np.ndarray) -> None:
        writer.write(row)
        bar(trial - first, row)

    recorder = None
    if args.record is not None:
        from .recording import SimRecorder

        args.record.parent.mkdir(parents=True, exist_ok=True)
        recorder = SimRecorder(args.record, sc, sample_trials=set(keep))
    t0 = time.perf_counter()
    try:
        res = simulate(sc, keep=keep, progress=on_trial, initial_memory=init,
                       first_trial=first,
                       on_trial_data=None if recorder is None else recorder.trial)
    finally:
        writer.close()
        if recorder is not None:
            recorder.close()
    elapsed = time.perf_counter() - t0
    arrays: dict[str, Any] = {"eta_d": sc.desired.eta}
    for t, r in res.records.items():
        arrays.update({f"eta_{t}": r.eta, f"xi_{t}": r.xi, f"u_{t}": r.u})
    np.savez_compressed(out / "trajectories.npz", **arrays)
    if res.memory is not None:
        save_memory(out / "memory.npz", res.memory, sc, trials_learned=first + k)
    pos, head = res.column("max_position_error"), res.column("max_heading_error")
    summary = {
        "scenario": sc.name, "source": sc.source, "law": sc.law.kind, "memory": sc.law.memory,
        "seed": sc.seed, "trials": k, "noise": sc.uncertainty.noisy,
        "delay": sc.uncertainty.delay.kind, "robots": sc.n, "samples": sc.samples, "dt": sc.dt,
        "condition20": condition20(sc.graph, np.asarray(sc.law.gain), sc.dt),
        "first": {"max_position_error": pos[0], "max_heading_error": head[0]},
        "last": {"max_position_error": pos[-1], "max_heading_error": head[-1]},
        "best": {"max_position_error": float(pos.min()), "trial": int(pos.argmin())},
        "position_error_reduction": float(pos[0] / pos[-1]) if pos[-1] > 0 else None,
        "seconds": elapsed, "ms_per_trial": 1000 * elapsed / k,
    }
    files = ["metrics.csv", "summary.json", "trajectories.npz", "memory.npz"]
    if not args.no_plots:
        from .plots import plot_errors, plot_trajectories

        title = (f"{sc.name}: law ({sc.law.kind}), {sc.law.memory} memory, "
                 f"{'noisy' if sc.uncertainty.noisy else 'noise-free'}, "
                 f"delay {sc.uncertainty.delay.kind}")
        plot_errors(res.metrics[:, 0], pos, head, out / "errors.png", title)
        edges = [(i, j) for i in range(sc.n) for j in sc.graph.neighbours(i)]
        plot_trajectories(sc.desired.eta, {t: r.eta for t, r in res.records.items()},
                          out / "trajectories.png", title, edges=edges or _ring(sc.n))
        files += ["errors.png", "trajectories.png"]
    summary["files"] = files
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"{sc.name}: {k} trials in {elapsed:.2f} s ({summary['ms_per_trial']:.3f} ms/trial)")
    last = first + k - 1
    print(f"  max position error: trial {first} {pos[0]:.4g} m -> trial {last} {pos[-1]:.4g} m")
    print(f"  max heading error:  trial {first} {head[0]:.4g} rad -> trial {last} "
          f"{head[-1]:.4g} rad")
    print(f"  results in {out}/ ({', '.join(files)})")
    return 0


def _ring(n: int) -> list[tuple[int, int]]:
    return [(i, (i + 1) % n) for i in range(n)] if n > 1 else []


def cmd_compare(args: argparse.Namespace) -> int:
    from .metrics import write_metrics
    from .plots import plot_compare
    from .simulate import simulate

    base = _scenario(args, law=False)
    out = _out_dir(args.out, base, "compare")
    curves = {}
    rows = []
    for law in (9, 22, 23):
        for mem in ("feedforward", "literal"):
            if law == 22 and mem == "literal":
                continue  # law (22) has no current term: both readings are the same law
            sc = base.with_options(law=law, memory=mem)
            res = simulate(sc, progress=Progress(sc.trials, f"law ({law}) {mem}"))
            pos, head = res.column("max_position_error"), res.column("max_heading_error")
            label = f"({law}) {mem}"
            curves[label] = (res.metrics[:, 0], pos, head)
            write_metrics(out / f"metrics_law{law}_{mem}.csv", res.metrics)
            rows.append((label, pos[0], pos[-1], float(pos.max()), head[-1]))
    title = (f"{base.name}: {base.trials} trials, "
             f"{'noisy' if base.uncertainty.noisy else 'noise-free'}, "
             f"delay {base.uncertainty.delay.kind}")
    fig = plot_compare(curves, out / "compare.png", title)
    print(f"{'law / memory':26s} {'first [m]':>10s} {'last [m]':>10s} {'peak [m]':>10s} "
          f"{'last heading [rad]':>19s}")
    for label, first, last, peak, lh in rows:
        print(f"{label:26s} {first:10.4g} {last:10.4g} {peak:10.4g} {lh:19.4g}")
    print(f"figure: {fig}")
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from .checks import check_scenario

    sc = load_scenario(args.scenario).with_options(law=args.law, memory=args.memory,
                                                   trials=args.trials,
                                                   delay=not args.no_delay)
    rep = check_scenario(sc)
    for line in rep.lines(sc):
        print(line)
    if not rep.spanning_tree:
        print("error: no gain can satisfy condition (20) on this graph (Theorem 2)",
              file=sys.stderr)
        return 2
    return 0


def cmd_tune(args: argparse.Namespace) -> int:
    from dataclasses import replace as dc_replace

    from .scenario import scenario_from_text
    from .study import scenario_text_with
    from .tune import TuneOptions, report_lines, result_json, tune, tuned_text

    sc = load_scenario(args.scenario)
    over: dict[str, Any] = {}
    if args.law is not None:
        over["law.kind"] = args.law
    if args.memory is not None:
        over["law.memory"] = args.memory
    if over:
        sc = scenario_from_text(scenario_text_with(sc.text, over), sc.source)
    for name in ("position_level", "heading_level", "floor_factor", "max_growth"):
        if getattr(args, name) is not None and not getattr(args, name) > 0:
            raise ScenarioError(f"--{name.replace('_', '-')} must be > 0")
    for name in ("seeds", "verify_trials", "screen_trials", "floor_window"):
        if getattr(args, name) < 1:
            raise ScenarioError(f"--{name.replace('_', '-')} must be >= 1")
    if args.floor_window > args.verify_trials:
        raise ScenarioError("--floor-window must be <= --verify-trials")
    grids: dict[str, Any] = {}
    for name in ("gain_grid", "prime_grid"):
        val = getattr(args, name)
        if val is None:
            continue
        try:
            grids[name] = tuple(float(x) for x in val.split(",") if x.strip())
        except ValueError:
            raise ScenarioError(f"--{name.replace('_', '-')}: expected numbers like "
                                f"0.08,0.16, got {val!r}") from None
        if not grids[name] or min(grids[name]) <= 0:
            raise ScenarioError(f"--{name.replace('_', '-')}: values must be > 0")
    opt = TuneOptions(**grids, position_level=args.position_level, heading_level=args.heading_level,
                      seeds=tuple(range(1, args.seeds + 1)), screen_trials=args.screen_trials,
                      verify_trials=args.verify_trials, floor_window=args.floor_window,
                      floor_factor=args.floor_factor, max_growth=args.max_growth,
                      per_robot=not args.uniform)
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


def cmd_sweep(args: argparse.Namespace) -> int:
    from .sweep import load_spec, plot_table, run_sweep

    spec = load_spec(args.spec)
    out = args.out or Path("runs") / f"{args.spec.stem}-sweep"
    if args.workers is not None and args.workers < 1:
        raise ScenarioError("--workers must be >= 1")
    n = len(spec.configs) * len(spec.seeds)
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else (
        f"{args.workers or os.cpu_count()} local processes")
    print(f"sweep {args.spec}: {len(spec.configs)} configurations x {len(spec.seeds)} seeds = "
          f"{n} points of {spec.trials} trials, on {where}", file=sys.stderr)
    table = run_sweep(spec, out, workers=args.workers, scheduler=args.scheduler)
    files = [table.name]
    if not args.no_plots:
        from .study import CHECK_COLUMNS, SIM_COLUMNS

        if args.metric not in SIM_COLUMNS + CHECK_COLUMNS:
            raise ScenarioError(f"--metric: no column {args.metric!r} (columns: "
                                f"{', '.join(SIM_COLUMNS + CHECK_COLUMNS)})")
        files += [p.name for p in plot_table(spec, table, out, args.metric)]
    print(f"results in {out}/ ({', '.join(files)})")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.command is None:
        ap.print_help()
        return 1
    try:
        if args.command == "scenarios":
            for name in builtin_scenarios():
                sc = load_scenario(name)
                print(f"{name:20s} {sc.n} robots, {sc.samples} samples of {sc.dt} s, "
                      f"{sc.trials} trials: {sc.description.strip().splitlines()[0]}")
            return 0
        if args.command == "simulate":
            return cmd_simulate(args)
        if args.command == "compare":
            return cmd_compare(args)
        if args.command == "check":
            return cmd_check(args)
        if args.command == "tune":
            return cmd_tune(args)
        if args.command == "sweep":
            return cmd_sweep(args)
        if args.command == "analyze":
            from .analyze import analyze

            if not args.recording.is_file():
                raise ScenarioError(f"{args.recording}: no such file")
            out = args.out or args.recording.with_name(args.recording.stem + "-analysis")
            return analyze(args.recording, out, plots=not args.no_plots)
        if args.command == "mcap-repair":
            from .mcap_io import ReadReport, repair

            if not args.recording.is_file():
                raise ScenarioError(f"{args.recording}: no such file")
            dst = args.output or args.recording.with_suffix(".repaired.mcap")
            rep = ReadReport()
            n = repair(args.recording, dst, rep)
            for line in rep.lines():
                print(f"note: {args.recording}: {line}")
            print(f"{dst}: {n} messages kept")
            return 0
        if args.command == "launch":
            from . import launch  # type: ignore[attr-defined,unused-ignore]

            return int(launch.run(args))
    except (ScenarioError, SpanningTreeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if args.command == "sweep":
            print("\ninterrupted; every finished point is kept in DIR/points: run the same "
                  "command again to go on", file=sys.stderr)
        else:
            print("\ninterrupted; finished trials are in metrics.csv", file=sys.stderr)
        return 130
    ap.error(f"unknown command {args.command}")
    return 2


if __name__ == "__main__":
    sys.exit(main())
