"""``formation-ilc``: simulate, compare, check and launch formation learning runs.

Run ``formation-ilc COMMAND --help`` for each command.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

# The lifted check multiplies 1800 x 1800 matrices; on 2 cores a threaded BLAS spins more
# than it gains (measured: 10.5 s threaded, 3.9 s single-threaded). Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from formation_ilc.cli.options import (  # noqa: E402
    MAX_TRIAL,
    OneLineParser,
    OptionError,
    add_run_options,
    int_range,
    make_out_dir,
    nonneg_float,
    out_dir_arg,
    output_file_arg,
    positive_float,
    positive_int,
)
from formation_ilc.config.scenario import Scenario, ScenarioError, builtin_scenarios, load_scenario  # noqa: E402
from formation_ilc.core.guards import DivergedError, format_bytes, memory_shortfall  # noqa: E402
from formation_ilc.core.topology import SpanningTreeError  # noqa: E402
from formation_ilc.model.footprint import BODIES  # noqa: E402
from formation_ilc.store.memoryfile import MemoryFileError, load_memory, save_memory  # noqa: E402
from formation_ilc.system.exits import DISK_FULL, is_disk_full  # noqa: E402

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
  formation-ilc launch team50 --mode realtime          50 robot processes (formation-ilc team N)

A SCENARIO is a built-in name or a YAML file (see formation_ilc/config/scenarios/*.yaml).
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


CHECK_CODES = """\
exit status (for scripts):
  0  converges: Theorem 2 and condition (20) hold, and the lifted heading map converges
     with at most a mild transient (max_k ||M^k|| < 10)
  2  the graph has no spanning tree (Theorem 2), or bad input
  3  will not converge, or is not guaranteed to: condition (20) fails, or the lifted
     heading map's spectral radius is >= 1
  4  converges only after a large transient (max_k ||M^k|| >= 10)
  5  Theorem 2 and condition (20) hold; the lifted heading map was not built
     (robots x samples > 3600), so the transient is unknown
  6  the learning checks pass (0, 4 or 5 above), but the desired motion leaves the
     base's limits (--base: its peak speed, turn rate or acceleration; the line names the
     robot, the time and the --time-scale that fits), or the formation brings two robots'
     bodies closer than the safety filter keeps them
"""

SIMULATE_CODES = """\
exit status: 0 done; 2 bad input (one line on stderr: file or option, and why), or a run
that would need more memory than is available (the estimate is printed); 3 the learning
diverged (errors not finite: metrics.csv keeps the finished trials, memory.npz the last
finite memory); 5 the disk is full (one line naming the file; metrics.csv and memory.npz
keep what was written before); 130 or 143 interrupted (Ctrl-C, SIGTERM): metrics.csv and
memory.npz keep every finished trial, and the command to go on is printed.
"""


def _scenario_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", metavar="SCENARIO",
                   help="built-in scenario name (formation-ilc scenarios) or a YAML file")


def build_parser() -> argparse.ArgumentParser:
    """The ``formation-ilc`` parser: one subparser per row of ``COMMANDS``."""
    ap = OneLineParser(
        prog="formation-ilc",
        description="Distributed iterative learning control of differential-drive robot "
                    "formations: robots repeat a trial, learn from it, and converge on a "
                    "formation that follows a virtual leader, despite initial shifts, "
                    "disturbances, noise and communication delays.",
        epilog=EXAMPLES, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    for c in COMMANDS.values():
        c.add(sub)
    return ap


def _add_scenarios(sub: Any) -> None:
    sub.add_parser("scenarios", help="list the built-in scenarios")


def _add_simulate(sub: Any) -> None:
    p = sub.add_parser("simulate", help="batch-simulate all robots over all trials",
                       description="Batch-simulate a scenario. Writes DIR/metrics.csv (one "
                                   "row per trial as it ends, trial 0 = the first run), "
                                   "DIR/memory.npz (the learned memory: saved at least every "
                                   "2 s, at the end and when interrupted), DIR/summary.json "
                                   "and plots of error vs trial and of chosen trials' "
                                   "trajectories. A run that would need more memory than "
                                   "the machine has is refused before it starts.",
                       epilog=SIMULATE_CODES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    _scenario_arg(p)
    add_run_options(p, shape=True)
    p.add_argument("--no-plots", action="store_true", help="write no figures")
    p.add_argument("--init-memory", type=Path, metavar="MEMORY.npz",
                   help="start from a learned memory (a run's memory.npz, or an older "
                        "memory.npy), e.g. learn noise-free first, then go on with noise or "
                        "on the robots (`launch --init-memory`; the paper's sim-to-real "
                        "workflow, paper-notes 10)")
    p.add_argument("--first-trial", type=int_range(0, MAX_TRIAL), default=0, metavar="K",
                   help="number the trials from K (their random draws are trial K's, ...); "
                        "to go on from a memory.npz, K is its trials_learned (printed when "
                        "a run is interrupted)")
    p.add_argument("--record", type=output_file_arg, metavar="RUN.mcap",
                   help="also write the run as ROS 2 MCAP, on the distributed stack's topics "
                        "(analyse it with `formation-ilc analyze RUN.mcap`)")
    p.add_argument("--keep", metavar="K1,K2,...",
                   help="trials whose trajectories are plotted and saved "
                        "(default: first, about 10%%, 40%% and last)")
    p.add_argument("--plant-model", choices=("euler", "arc"), default="euler",
                   help="euler (default): eq. (1) as the paper steps it; arc: a unicycle that "
                        "drives an arc each sample, as real robots and the physics plant do "
                        "(the scenario's auto headings then read as arc)")
    p.add_argument("--footprint", choices=BODIES, default=None,
                   help="write clearance.csv: each trial's least clearance between the "
                        "robots' footprints (this model's body; < 0: they overlap), and say "
                        "how many trials overlap (default with --safety: its --body)")
    p.add_argument("--safety", action="store_true",
                   help="put every robot's command through the safety filter, as the stack "
                        "does on a plant with bodies (docs/safety.md): predicts what the "
                        "bodies will do; metrics.csv counts the commands it changed "
                        "(filter_active). With --plant-model arc, as the robots drive")
    p.add_argument("--body", choices=BODIES, default="p3dx",
                   help="with --safety: the robots' body, whose footprint and limits the "
                        "filter keeps (default p3dx)")
    p.add_argument("--safety-margin", type=nonneg_float, default=None, metavar="M",
                   help="with --safety: the least gap [m] between two robots' covering discs "
                        "(default 0.1; 0.25 on skid steer)")
    p.add_argument("--safety-learning", choices=("applied", "split", "freeze", "ignore"),
                   default=None,
                   help="with --safety: how the memory learns where the filter changed a "
                        "command (docs/safety.md)")
    p.add_argument("--out", type=out_dir_arg, metavar="DIR",
                   help="output folder (default: runs/SCENARIO-LAW-MEMORY-TIME)")


def _add_compare(sub: Any) -> None:
    p = sub.add_parser("compare", help="laws 9, 22, 23 in both memory readings, same draws",
                       description="Run laws (9), (22) and (23), each with memory "
                                   "'feedforward' and 'literal', on the same random draws, "
                                   "and plot their errors in one figure (like Fig. 7).")
    _scenario_arg(p)
    add_run_options(p, law=False)
    p.add_argument("--out", type=out_dir_arg, metavar="DIR", help="output folder")


def _add_check(sub: Any) -> None:
    p = sub.add_parser("check", help="Theorem 2, condition (20) and the lifted heading map",
                       description="Check a scenario before running it: Theorem 2 (a "
                                   "spanning tree), condition (20), and the lifted heading "
                                   "map's convergence and transient. The exit status is "
                                   "the verdict, for scripts (below).",
                       epilog=CHECK_CODES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    _scenario_arg(p)
    p.add_argument("--law", type=int, choices=(9, 22, 23))
    p.add_argument("--memory", choices=("feedforward", "literal"))
    p.add_argument("--trials", type=positive_int, metavar="K",
                   help="horizon for the transient-growth estimate (default: scenario's)")
    p.add_argument("--no-delay", action="store_true",
                   help="check the delay-free configuration (as run with --no-delay)")
    p.add_argument("--base", choices=(*BODIES, "none"), default="p3dx",
                   help="the robots the desired motion must fit: their speed and "
                        "acceleration limits (a physics model's maker's, else the base "
                        "preset's) and their body for the safety filter (default p3dx, the "
                        "paper's Pioneer 3-DX; none: check the learning only)")
    p.add_argument("--headings", choices=("auto", "chord", "arc"), default="arc",
                   help="the desired headings the motion is checked with (default arc: "
                        "robots that drive arcs)")
    p.add_argument("--time-scale", type=positive_float, default=None, metavar="S",
                   help="check the scenario stretched in time by S")


def _add_tune(sub: Any) -> None:
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


def _add_analyze(sub: Any) -> None:
    p = sub.add_parser("analyze", help="metrics, delays, plots and a report from a recording",
                       description="Analyse a recorded run (formation-ilc launch --record, or "
                                   "simulate --record) from the MCAP file alone. Writes "
                                   "DIR/metrics.csv (the columns of simulate), delays.csv, "
                                   "errors.png, trajectories.png, formation.png, delays.png "
                                   "and report.html (one page to read at a glance). A file "
                                   "cut short by a crash is read up to the cut. A file "
                                   "damaged in the middle is read past the damage; what was "
                                   "lost is reported and the exit status is 1. When a "
                                   "trial of the run is not complete in the files, the "
                                   "run is not whole: the trials are named and the exit "
                                   "status is 3 (1 if also damaged). A run "
                                   "whose recorder was restarted, or that was resumed, "
                                   "left more files next to RUN.mcap (RUN.part1.mcap, "
                                   "RUN.resumed1.mcap, ...): they are read with it, in "
                                   "order, as one run.")
    p.add_argument("recording", type=Path, metavar="RUN.mcap")
    p.add_argument("--out", type=out_dir_arg, metavar="DIR",
                   help="output folder (default: RUN-analysis next to the file)")
    p.add_argument("--no-plots", action="store_true", help="tables only")
    p.add_argument("--only-this-file", action="store_true",
                   help="read RUN.mcap alone, not the parts written after it")
    p.add_argument("--run-dir", type=Path, metavar="DIR",
                   help="the launched run's output folder: its config.json stands in for "
                        "the run configuration when the files have lost every copy of it "
                        "(default: the folder RUN.mcap is in, when it holds one)")


def _add_mcap_repair(sub: Any) -> None:
    p = sub.add_parser("mcap-repair", help="rewrite a recording cut short by a crash",
                       description="A recorder killed mid-run leaves an MCAP file without "
                                   "its summary and footer; everything flushed before the "
                                   "kill still reads back (analyze reads such files as they "
                                   "are). This writes a complete copy that every MCAP tool "
                                   "opens, keeping every message that reads back, and puts "
                                   "back what it can rebuild: the run configuration's "
                                   "message, from a copy in the file's metadata or the run's "
                                   "folder, when the damage took it. A file of which nothing "
                                   "reads back is refused (exit status 2) and nothing is "
                                   "written.")
    p.add_argument("recording", type=Path, metavar="RUN.mcap")
    p.add_argument("-o", "--output", type=output_file_arg, metavar="FIXED.mcap",
                   help="default: RUN.repaired.mcap")
    p.add_argument("--run-dir", type=Path, metavar="DIR",
                   help="the launched run's output folder: its config.json stands in for "
                        "the run configuration when the file has lost every copy of it "
                        "(default: the folder RUN.mcap is in, when it holds one)")



def _add_team(sub: Any) -> None:
    from formation_ilc.config.generate import GRAPH_RULES, PATTERNS

    p = sub.add_parser(
        "team", help="write a scenario for a team of N robots (a pattern and a graph rule)",
        description="Write a scenario file for a team of N robots: the formation from a "
                    "pattern, the graph from a rule, everything else (reference, timing, "
                    "law, uncertainty, delays) from a base scenario. The built-in team50 "
                    "is `formation-ilc team 50`. Then: formation-ilc launch FILE.")
    p.add_argument("robots", type=int_range(1, 1000), metavar="N", help="robots")
    p.add_argument("-o", "--output", type=output_file_arg, metavar="FILE.yaml",
                   help="where to write it (default teamN.yaml in this folder)")
    p.add_argument("--pattern", choices=PATTERNS, default="grid",
                   help="grid: rows of about sqrt(2 N) robots; ring: one circle (default grid)")
    p.add_argument("--graph", choices=GRAPH_RULES, default="relay",
                   help="relay: along the pattern every third robot sees the leader and its "
                        "two neighbours follow it (the paper's leader-relay tree)")
    p.add_argument("--spacing", type=positive_float, default=1.5, metavar="M",
                   help="distance between neighbours [m] (default 1.5)")
    p.add_argument("--columns", type=int_range(1, 1000), metavar="C",
                   help="grid: robots per row (default about sqrt(2 N))")
    p.add_argument("--from", dest="base", default="paper-hexagon6", metavar="SCENARIO",
                   help="the base scenario (default paper-hexagon6)")


def cmd_team(args: argparse.Namespace) -> int:
    from formation_ilc.config.generate import team_yaml

    text = team_yaml(args.robots, pattern=args.pattern, graph=args.graph,
                     spacing=args.spacing, columns=args.columns, base=args.base)
    out = args.output or Path(f"team{args.robots}.yaml")
    try:
        out.write_text(text)
    except OSError as exc:
        raise ScenarioError(f"{out}: cannot write: {exc.strerror}") from None
    sc = load_scenario(out)
    print(f"wrote {out}: {sc.n} robots ({args.pattern}, graph rule {args.graph}, "
          f"{int(sc.graph.leader.astype(bool).sum())} see the leader); run it with: "
          f"formation-ilc launch {out}")
    return 0


def _add_keystore(sub: Any) -> None:
    from formation_ilc.cli import keystore

    keystore.add_parser(sub)


def _add_launch(sub: Any) -> None:
    from formation_ilc.cli import launch

    p = sub.add_parser("launch", help="run the distributed ROS 2 stack on localhost",
                       description=launch.__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    launch.add_arguments(p)
    launch.without_defaults(p)


class Progress:
    """simulate's and compare's progress: trials done, with the last trial's errors
    (``formation_ilc.system.progress``: a bar on a terminal, a line every 10 % or 30 s in a
    log)."""

    def __init__(self, total: int, label: str, first: int = 0):
        from formation_ilc.system.progress import Progress as Bar

        self.first = first
        self.bar = Bar(total, label, "trials", tenths=True)

    def __call__(self, k: int, row: Any) -> None:
        self.bar.to(k - self.first + 1,
                    f"max position {row[1]:.4g} m  max heading {row[2]:.4g} rad")


class TrialLog:
    """A run's metrics rows as they come, in bounded memory: each row goes to metrics.csv at
    once (flushed), the first, last and best rows are kept, and a series for the plots that
    holds every row up to ``cap`` rows, then every 2nd, 4th, ... row (a run of 10^9 trials
    needs no more memory than one of 10^5)."""

    def __init__(self, path: Path | None, cap: int = 100_000):
        from formation_ilc.core.metrics import METRIC_COLUMNS, MetricsWriter

        self.writer = None if path is None else MetricsWriter(path)
        self.cap = cap - cap % 2
        self.stride = 1
        self.seen = 0
        self.series = np.empty((self.cap, len(METRIC_COLUMNS)))
        self.count = 0
        self.first: np.ndarray | None = None
        self.last: np.ndarray | None = None
        self.best: np.ndarray | None = None

    def add(self, row: np.ndarray) -> None:
        row = np.array(row, dtype=float)
        if self.writer is not None:
            self.writer.write(row)
        if self.first is None:
            self.first = row
        self.last = row
        if self.best is None or row[1] < self.best[1]:
            self.best = row
        if self.seen % self.stride == 0:
            if self.count == self.cap:  # full: keep every other row, take every 2nd from now
                half = self.cap // 2
                self.series[:half] = self.series[0:self.cap:2]
                self.count = half
                self.stride *= 2
            if self.seen % self.stride == 0:
                self.series[self.count] = row
                self.count += 1
        self.seen += 1

    def rows(self) -> np.ndarray:
        """The plot series, shape (rows, len(METRIC_COLUMNS)), the last row included."""
        rows = self.series[:self.count]
        if self.last is not None and (not len(rows) or rows[-1, 0] != self.last[0]):
            rows = np.vstack([rows, self.last])
        return rows

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


class MemoryKeeper:
    """The latest learned memory, written to ``path`` (memory.npz, atomically) at most every
    ``interval`` seconds, and at least ``overhead`` of the time apart (measured: 1 to 8 ms a
    write with fsync, 30 KB for paper-hexagon6), and whenever ``save`` is called: at the
    end, on an interruption, on divergence."""

    def __init__(self, path: Path, sc: Scenario, start: np.ndarray | None, first: int,
                 interval: float = 2.0, overhead: float = 0.05):
        self.path = path
        self.sc = sc
        self.memory = None if start is None else np.array(start, dtype=float)
        self.trials = first
        self.saved_trials: int | None = None
        self.interval = interval
        self.overhead = overhead
        self.next_time = time.monotonic() + interval
        self.writes = 0
        self.write_seconds = 0.0

    def update(self, next_trial: int, memory: np.ndarray) -> None:
        if self.memory is None:
            self.memory = np.array(memory, dtype=float)
        else:
            np.copyto(self.memory, memory)
        self.trials = next_trial
        if time.monotonic() >= self.next_time:
            self.save()

    def save(self) -> Path | None:
        """Write the memory now (if there is one and it is newer than the file)."""
        if self.memory is None or self.saved_trials == self.trials:
            return self.path if self.saved_trials is not None else None
        t0 = time.monotonic()
        save_memory(self.path, self.memory, self.sc, trials_learned=self.trials)
        took = time.monotonic() - t0
        self.writes += 1
        self.write_seconds += took
        self.saved_trials = self.trials
        self.next_time = time.monotonic() + max(self.interval, took / self.overhead)
        return self.path


def _sigterm_as_interrupt() -> Any:
    """SIGTERM raises KeyboardInterrupt (marked), so a killed run saves what it learned;
    returns the previous handler."""
    import signal

    def on_term(signum: int, frame: Any) -> None:
        exc = KeyboardInterrupt()
        exc.signal = signum  # type: ignore[attr-defined]
        raise exc

    try:
        return signal.signal(signal.SIGTERM, on_term)
    except ValueError:  # not the main thread (e.g. called from a test's worker thread)
        return None


def _restore_sigterm(previous: Any) -> None:
    import signal

    if previous is not None:
        signal.signal(signal.SIGTERM, previous)


def _out_dir(arg: Path | None, sc: Scenario, tag: str) -> Path:
    if arg is None:
        stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
        arg = Path("runs") / f"{sc.name}-{tag}-{stamp}"
    return make_out_dir(arg)


def _scenario(args: argparse.Namespace, law: bool = True) -> Scenario:
    sc = load_scenario(args.scenario)
    return sc.with_options(
        law=getattr(args, "law", None) if law else None,
        memory=getattr(args, "memory", None) if law else None,
        noise=not getattr(args, "no_noise", False), delay=not getattr(args, "no_delay", False),
        seed=getattr(args, "seed", None), trials=getattr(args, "trials", None))


def _default_keep(k: int) -> list[int]:
    return sorted({0, max(0, k // 10 - 1), max(0, 2 * k // 5 - 1), k - 1})


def _fits(sc: Scenario, need: int, what: str) -> None:
    """Refuse a job whose memory estimate does not fit, naming the scenario and the size."""
    why = memory_shortfall(need)
    if why is not None:
        raise ScenarioError(f"{sc.source}: samples: {what} of {sc.n} robots x {sc.samples} "
                            f"samples {why}; use fewer samples (or robots, or kept trials)")


def _thin(a: np.ndarray, limit: int = 20_000) -> np.ndarray:
    """Every k-th sample of (N, T, ...) so that a plot draws at most ``limit`` per robot."""
    step = max(1, -(-a.shape[1] // limit))
    return a[:, ::step]


def cmd_simulate(args: argparse.Namespace) -> int:
    from formation_ilc.model.simulate import simulate, simulate_bytes

    sc = _scenario(args).with_options(headings=getattr(args, "headings", None),
                                      time_scale=getattr(args, "time_scale", None))
    plant = getattr(args, "plant_model", "euler")
    sc = sc.for_plant(plant)
    k = sc.trials
    first = int(args.first_trial)
    if first + k > MAX_TRIAL:
        raise OptionError(f"--first-trial {first} + --trials {k}: trial numbers must stay "
                          f"below 2^53")
    keep = _keep_trials(args.keep, first, k)
    need = simulate_bytes(sc, k, keep=len(keep), store_metrics=False)
    _fits(sc, need, f"a run keeping {len(keep)} trials' trajectories")
    init = None
    if args.init_memory is not None:
        try:
            init = load_memory(args.init_memory, sc)
        except MemoryFileError as exc:
            raise ScenarioError(str(exc)) from None
    out = _out_dir(args.out, sc, f"law{sc.law.kind}-{sc.law.memory}")
    if need >= 1 << 30:
        print(f"{sc.name}: {sc.n} robots x {sc.samples} samples, {k} trials: about "
              f"{format_bytes(need)} of memory", file=sys.stderr)
    # metrics are written as they come, so a crash or Ctrl-C keeps every finished trial;
    # the memory learned from them is written at most 2 s apart and on any interruption
    log = TrialLog(out / "metrics.csv")
    keeper = MemoryKeeper(out / "memory.npz", sc, init, first)
    bar = Progress(k, f"{sc.name} law ({sc.law.kind}) {sc.law.memory}", first)

    def on_trial(trial: int, row: np.ndarray) -> None:
        log.add(row)
        bar(trial, row)

    recorder = None
    if args.record is not None:
        from formation_ilc.nodes.observer import sim_recorder

        try:
            args.record.parent.mkdir(parents=True, exist_ok=True)
            recorder = sim_recorder(args.record, sc, set(keep), first)
        except OSError as exc:
            log.close()
            raise OptionError(f"--record {args.record}: cannot write: "
                              f"{exc.strerror or exc}") from None
    clear_rows: list[Any] = []
    safety = _safety_spec(args, sc)
    args.footprint = footprint = args.footprint or (args.body if safety is not None else None)
    on_data = _with_clearance(footprint, None if recorder is None else recorder.trial,
                              clear_rows)
    t0 = time.perf_counter()
    previous = _sigterm_as_interrupt()
    try:
        res = simulate(sc, keep=keep, progress=on_trial, initial_memory=init,
                       first_trial=first, on_trial_data=on_data, plant=plant,
                       stop_on_divergence=True, on_memory=keeper.update, store_metrics=False,
                       safety=safety)
        keeper.save()
    except DivergedError as exc:
        saved = keeper.save()
        done = "no trial finished" if log.last is None else (
            f"metrics.csv keeps trials {first}..{int(log.last[0])}")
        mem = (f"memory.npz the memory trial {exc.trial} started from" if saved
               else "no memory was learned")
        print(f"error: {sc.source}: {exc}; {done}, {mem} (in {out}/); smaller gains? see "
              f"`formation-ilc check {args.scenario}`", file=sys.stderr)
        return 3
    except KeyboardInterrupt as exc:
        return _interrupted(args, out, log, keeper, first, k, 128 + getattr(exc, "signal", 2))
    finally:
        _restore_sigterm(previous)
        log.close()
        if recorder is not None:
            recorder.close()
    return _simulate_outputs(args, sc, res, log, keeper, out, first,
                             time.perf_counter() - t0, clear_rows)


def _safety_spec(args: argparse.Namespace, sc: Any) -> Any:
    """``simulate --safety``: the filter of ``--body`` with its own limits, or None."""
    if not getattr(args, "safety", False):
        return None
    from formation_ilc.config.safety import SafetySettings, default_learning, default_margin
    from formation_ilc.model.safety import body_limits, desired_clearance, spec_of

    args.safety_learning = args.safety_learning or default_learning(args.body)
    if args.safety_margin is None:
        args.safety_margin = default_margin(args.body)
    spec = spec_of(SafetySettings(args.body, body_limits(args.body), args.safety_margin,
                                  args.safety_learning), sc.dt)
    dc = desired_clearance(sc, spec)
    if not dc.fits:
        raise OptionError(f"--safety: {dc.line(sc.dt)} ({args.body} bodies + "
                          f"{args.safety_margin:g} m margin); widen the formation's offsets "
                          f"or lower --safety-margin")
    return spec


def _with_clearance(body: str | None, on_data: Any, rows: list[Any]) -> Any:
    """``simulate --footprint BODY``: the per-trial callback that also appends each trial's
    least clearance between the robots' footprints to ``rows``."""
    if body is None:
        return on_data
    from formation_ilc.model.footprint import footprint_of, trial_clearance

    fp = footprint_of(body)

    def with_clearance(k: int, xi: np.ndarray, *rest: Any) -> None:
        rows.append(trial_clearance(k, xi, fp))
        if on_data is not None:
            on_data(k, xi, *rest)

    return with_clearance


def _clearance_outputs(body: str, rows: list[Any], out: Path, dt: float,
                       summary: dict[str, Any]) -> str:
    """clearance.csv and the summary's footprint entry; the line to print."""
    with (out / "clearance.csv").open("w") as fh:
        fh.write("trial,least_clearance,robot_i,robot_j,time,overlapping_samples\n")
        for c in rows:
            fh.write(f"{c.trial},{c.value:.6f},{c.robots[0]},{c.robots[1]},"
                     f"{c.sample * dt:.6g},{c.overlapping}\n")
    hits = [c for c in rows if c.value < 0]
    summary["footprint"] = {"model": body, "overlapping_trials": len(hits),
                            "least_clearance": min(c.value for c in rows)}
    return (f"  footprints ({body}): {len(hits)} of {len(rows)} trials overlap"
            + (f", first {hits[0].line(dt)}" if hits else ""))


def _keep_trials(text: str | None, first: int, k: int) -> list[int]:
    """The trials whose trajectories are kept (--keep), in first..first + k - 1."""
    if not text:
        return [first + t for t in _default_keep(k)]
    try:
        keep = sorted({int(x) for x in text.split(",") if x.strip()})
    except ValueError:
        raise OptionError(f"--keep: expected trial numbers like 0,99,1999, got "
                          f"{text[:60]!r}") from None
    bad = [x for x in keep if not first <= x < first + k]
    if bad:
        raise OptionError(f"--keep: trial {bad[0]} is outside {first}..{first + k - 1}")
    return keep


def _interrupted(args: argparse.Namespace, out: Path, log: TrialLog, keeper: MemoryKeeper,
                 first: int, k: int, status: int) -> int:
    """Save what an interrupted simulation learned, say where it is and how to go on."""
    saved = keeper.save()
    print("", file=sys.stderr)
    if log.last is None:
        print(f"interrupted before the first trial ended; nothing learned (in {out}/)",
              file=sys.stderr)
        return status
    last = int(log.last[0])
    learned = keeper.saved_trials if keeper.saved_trials is not None else first
    print(f"interrupted after trial {last}: {out}/metrics.csv holds trials {first}..{last}, "
          f"{saved} the memory for trial {learned} (learned from the trials before it)",
          file=sys.stderr)
    left = first + k - learned
    if left > 0 and saved is not None:
        print(f"go on with: formation-ilc simulate {args.scenario} --init-memory {saved} "
              f"--first-trial {learned} --trials {left} --out {out}-cont "
              f"(and the same options)", file=sys.stderr)
    return status


def _simulate_outputs(args: argparse.Namespace, sc: Scenario, res: Any, log: TrialLog,
                      keeper: MemoryKeeper, out: Path, first: int, elapsed: float,
                      clear_rows: list[Any]) -> int:
    """A finished simulation's trajectories.npz, summary.json, plots and printed lines."""
    from formation_ilc.model.checks import condition20

    k = sc.trials
    arrays: dict[str, Any] = {"eta_d": sc.desired.eta}
    for t, r in res.records.items():
        arrays.update({f"eta_{t}": r.eta, f"xi_{t}": r.xi, f"u_{t}": r.u})
    np.savez_compressed(out / "trajectories.npz", **arrays)
    assert log.first is not None and log.last is not None and log.best is not None
    rows = log.rows()
    pos0, head0 = float(log.first[1]), float(log.first[2])
    pos1, head1 = float(log.last[1]), float(log.last[2])
    summary = {
        "scenario": sc.name, "source": sc.source, "law": sc.law.kind, "memory": sc.law.memory,
        "seed": sc.seed, "trials": k, "noise": sc.uncertainty.noisy,
        "delay": sc.uncertainty.delay.kind, "robots": sc.n, "samples": sc.samples, "dt": sc.dt,
        "condition20": condition20(sc.graph, np.asarray(sc.law.gain), sc.dt),
        "first": {"max_position_error": pos0, "max_heading_error": head0},
        "last": {"max_position_error": pos1, "max_heading_error": head1},
        "best": {"max_position_error": float(log.best[1]), "trial": int(log.best[0])},
        "position_error_reduction": pos0 / pos1 if pos1 > 0 else None,
        "seconds": elapsed, "ms_per_trial": 1000 * elapsed / k,
        "memory_writes": keeper.writes,
    }
    if getattr(args, "safety", False):
        summary["safety"] = {"body": args.body, "margin": args.safety_margin,
                             "learning": args.safety_learning}
    files = ["metrics.csv", "summary.json", "trajectories.npz", "memory.npz"]
    clear_line = None
    if clear_rows:
        clear_line = _clearance_outputs(args.footprint, clear_rows, out, sc.dt, summary)
        files.append("clearance.csv")
    if not args.no_plots:
        from formation_ilc.recordings.plots import plot_errors, plot_trajectories

        title = (f"{sc.name}: law ({sc.law.kind}), {sc.law.memory} memory, "
                 f"{'noisy' if sc.uncertainty.noisy else 'noise-free'}, "
                 f"delay {sc.uncertainty.delay.kind}")
        plot_errors(rows[:, 0], rows[:, 1], rows[:, 2], out / "errors.png", title)
        edges = [(i, j) for i in range(sc.n) for j in sc.graph.neighbours(i)]
        plot_trajectories(_thin(sc.desired.eta), {t: _thin(r.eta) for t, r in
                                                  res.records.items()},
                          out / "trajectories.png", title, edges=edges or _ring(sc.n))
        files += ["errors.png", "trajectories.png"]
    summary["files"] = files
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print(f"{sc.name}: {k} trials in {elapsed:.2f} s ({summary['ms_per_trial']:.3f} ms/trial)")
    last = first + k - 1
    print(f"  max position error: trial {first} {pos0:.4g} m -> trial {last} {pos1:.4g} m")
    print(f"  max heading error:  trial {first} {head0:.4g} rad -> trial {last} "
          f"{head1:.4g} rad")
    if clear_line is not None:
        print(clear_line)
    print(f"  results in {out}/ ({', '.join(files)})")
    return 0


def _ring(n: int) -> list[tuple[int, int]]:
    return [(i, (i + 1) % n) for i in range(n)] if n > 1 else []


def cmd_compare(args: argparse.Namespace) -> int:
    from formation_ilc.model.simulate import simulate, simulate_bytes
    from formation_ilc.recordings.plots import plot_compare

    base = _scenario(args, law=False)
    _fits(base, simulate_bytes(base, store_metrics=False), "a run")
    out = _out_dir(args.out, base, "compare")
    curves = {}
    rows = []
    for law in (9, 22, 23):
        for mem in ("feedforward", "literal"):
            if law == 22 and mem == "literal":
                continue  # law (22) has no current term: both readings are the same law
            sc = base.with_options(law=law, memory=mem)
            log = TrialLog(out / f"metrics_law{law}_{mem}.csv")
            bar = Progress(sc.trials, f"law ({law}) {mem}")

            def on_trial(trial: int, row: np.ndarray, log: TrialLog = log,
                         bar: Progress = bar) -> None:
                log.add(row)
                bar(trial, row)

            try:
                simulate(sc, progress=on_trial, store_metrics=False)
            finally:
                log.close()
            assert log.first is not None and log.last is not None
            m = log.rows()
            label = f"({law}) {mem}"
            curves[label] = (m[:, 0], m[:, 1], m[:, 2])
            peak = max(float(np.max(m[:, 1])), float(log.first[1]))
            rows.append((label, log.first[1], log.last[1], peak, log.last[2]))
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


#: check's exit status per verdict (CHECK_CODES)
CHECK_OK, CHECK_NO_TREE, CHECK_DIVERGES, CHECK_TRANSIENT, CHECK_UNKNOWN = 0, 2, 3, 4, 5
CHECK_LIMITS = 6


def check_status(rep: Any) -> int:
    """The exit status of ``formation-ilc check`` for a CheckReport (CHECK_CODES)."""
    if not rep.spanning_tree:
        return CHECK_NO_TREE
    h = rep.heading
    if rep.cond20 >= 1 or (h is not None and h.spectral_radius >= 1):
        return CHECK_DIVERGES
    if h is None:
        return CHECK_UNKNOWN
    if h.norm >= 1 and h.growth >= 10:
        return CHECK_TRANSIENT
    return CHECK_OK


def cmd_check(args: argparse.Namespace) -> int:
    from formation_ilc.model.checks import check_bytes, check_scenario

    sc = load_scenario(args.scenario).with_options(law=args.law, memory=args.memory,
                                                   trials=args.trials,
                                                   delay=not args.no_delay)
    _fits(sc, check_bytes(sc), "the check")
    rep = check_scenario(sc)
    for line in rep.lines(sc):
        print(line)
    status = check_status(rep)
    if status == CHECK_NO_TREE:
        print("error: no gain can satisfy condition (20) on this graph (Theorem 2)",
              file=sys.stderr)
    problems = _motion_check(args, sc)
    if problems and status in (CHECK_OK, CHECK_TRANSIENT, CHECK_UNKNOWN):
        for line in problems:
            print(f"error: {line}", file=sys.stderr)
        return CHECK_LIMITS
    return status


def _motion_check(args: argparse.Namespace, sc: Scenario) -> list[str]:
    """``check``'s look at the desired motion: every robot's peaks, printed; what does
    not fit ``--base`` (its limits, its body under the safety filter), returned."""
    from formation_ilc.config.bases import fit_limits
    from formation_ilc.config.safety import SafetySettings
    from formation_ilc.model.safety import body_limits, desired_clearance, motion_peaks, spec_of

    if args.base == "none":
        return []
    moved = sc.with_options(headings=args.headings, time_scale=args.time_scale)
    body = args.base
    limits = body_limits(body)
    print(f"desired motion ({args.headings} headings"
          + (f", time scale {moved.time_scale:g}" if moved.time_scale != 1 else "")
          + f"; {body}: v <= {limits.v_max:g} m/s, omega <= {limits.omega_max:.3g} rad/s, "
            f"a <= {limits.a_max:g} m/s^2, alpha <= {limits.alpha_max:.3g} rad/s^2):")
    for p in motion_peaks(moved):
        print(f"  {p.line(moved.dt)}")
    problems = []
    line = fit_limits(moved, [limits] * moved.n)
    if line is not None:
        problems.append(f"{body}: {line}")
    dc = desired_clearance(moved, spec_of(SafetySettings(body, limits), moved.dt))
    print(f"  closest robots: {dc.line(moved.dt)}")
    if not dc.fits:
        problems.append(f"{body}: {dc.line(moved.dt)}: the safety filter would hold the "
                        f"robots off their formation; widen the offsets")
    return problems


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


def cmd_scenarios(args: argparse.Namespace) -> int:
    for name in builtin_scenarios():
        sc = load_scenario(name)
        print(f"{name:20s} {sc.n} robots, {sc.samples} samples of {sc.dt} s, "
              f"{sc.trials} trials: {sc.description.strip().splitlines()[0]}")
    return 0


def cmd_analyze(args: argparse.Namespace) -> int:
    from formation_ilc.cli.analyze import analyze
    from formation_ilc.recordings.recording import recording_parts, root_of

    files = [args.recording] if args.only_this_file else recording_parts(args.recording)
    for f in files:
        _regular_file(f)
    if files[0] != args.recording:
        print(f"note: {args.recording} does not exist; the run's files are "
              f"{', '.join(f.name for f in files)}", file=sys.stderr)
    root = root_of(args.recording)
    if root != args.recording and not args.only_this_file:
        print(f"note: {args.recording.name} is one part of the run recorded in "
              f"{root.name}: `formation-ilc analyze {root}` reads every part",
              file=sys.stderr)
    out = make_out_dir(args.out or args.recording.with_name(args.recording.stem + "-analysis"))
    try:
        return analyze(files, out, plots=not args.no_plots,
                       fallback=_run_dir_config(args.run_dir, args.recording))
    except ValueError as exc:  # not a recording, or not one of ours
        raise ScenarioError(" ".join(str(exc).split())) from None


def _run_dir_config(run_dir: Path | None, recording: Path) -> dict[str, Any] | None:
    """The run configuration of a launched run's folder (``--run-dir``, else the folder the
    recording is in, when it holds one), or None; OptionError for one that cannot be
    read."""
    from formation_ilc.store.runfile import CONFIG_FILE, RunFileError, load_config

    folder = run_dir if run_dir is not None else recording.parent
    try:
        conf = load_config(folder / CONFIG_FILE)
    except RunFileError as exc:
        raise OptionError(f"argument --run-dir: {exc}") from None
    if conf is None and run_dir is not None:
        raise OptionError(f"argument --run-dir: {run_dir}: no {CONFIG_FILE} there (not the "
                          f"output folder of a `formation-ilc launch` run)")
    return conf


def cmd_mcap_repair(args: argparse.Namespace) -> int:
    from formation_ilc.recordings.mcap_io import ReadReport, RepairError
    from formation_ilc.recordings.recording import repair_run

    _regular_file(args.recording)
    dst = args.output or args.recording.with_suffix(".repaired.mcap")
    rep = ReadReport()
    try:
        n, rebuilt = repair_run(args.recording, dst, rep,
                                fallback=_run_dir_config(args.run_dir, args.recording))
    except RepairError as exc:
        print(f"error: {args.recording}: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        raise ScenarioError(" ".join(str(exc).split())) from None
    for line in rep.lines():
        print(f"note: {args.recording}: {line}")
    for line in rebuilt:
        print(f"note: {dst}: {line}")
    print(f"{dst}: {n} messages kept")
    return 0


def cmd_keystore(args: argparse.Namespace) -> int:
    from formation_ilc.cli import keystore

    return keystore.run(args)


def _add_run_file(sub: Any) -> None:
    from formation_ilc.cli import runfile

    runfile.add_parser(sub)


def cmd_run_file(args: argparse.Namespace) -> int:
    from formation_ilc.cli import runfile

    return runfile.run(args)


def cmd_launch(args: argparse.Namespace) -> int:
    from formation_ilc.cli import launch

    return int(launch.run(args))


@dataclass(frozen=True)
class Command:
    """One subcommand of ``formation-ilc``: ``add(subparsers)`` registers its parser (named
    ``name``), ``run(args)`` runs it and returns the exit status; ``interrupted`` is what
    Ctrl-C says."""

    name: str
    add: Callable[[Any], None]
    run: Callable[[argparse.Namespace], int]
    interrupted: str = "interrupted; finished trials are in metrics.csv"


#: every subcommand, in the order ``--help`` lists them: one registration each
COMMANDS: dict[str, Command] = {c.name: c for c in (
    Command("scenarios", _add_scenarios, cmd_scenarios),
    Command("simulate", _add_simulate, cmd_simulate),
    Command("compare", _add_compare, cmd_compare),
    Command("check", _add_check, cmd_check),
    Command("tune", _add_tune, cmd_tune),
    Command("sweep", _add_sweep, cmd_sweep,
            interrupted="interrupted; every finished point is kept in DIR/points: run the "
                        "same command again to go on"),
    Command("analyze", _add_analyze, cmd_analyze),
    Command("mcap-repair", _add_mcap_repair, cmd_mcap_repair),
    Command("keystore", _add_keystore, cmd_keystore),
    Command("run-file", _add_run_file, cmd_run_file),
    Command("launch", _add_launch, cmd_launch),
    Command("team", _add_team, cmd_team),
)}


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.command is None:
        ap.print_help()
        return 1
    command = COMMANDS[args.command]
    try:
        return command.run(args)
    except (ScenarioError, SpanningTreeError, OptionError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        print(f"error: {args.command}: out of memory (the estimate made before the run was too "
              f"low: please report it)", file=sys.stderr)
        return 1
    except OSError as exc:  # a full disk, a folder removed under a run, ...
        where = f"{exc.filename}: " if exc.filename else ""
        if is_disk_full(exc):
            # what was written before is kept (rows and memory are written as they come)
            print(f"error: the disk is full: {args.command} could not write "
                  f"{exc.filename or 'its outputs'}; what was written before is kept; free "
                  f"some space, then run it again", file=sys.stderr)
            return DISK_FULL
        print(f"error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"\n{command.interrupted}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
