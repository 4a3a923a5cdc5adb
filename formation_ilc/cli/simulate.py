"""``formation-ilc simulate`` and ``compare``: the batch simulator's runs, their progress,
their rows and memory kept as they come, and their outputs."""

from __future__ import annotations

import argparse
import json
import sys
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from formation_ilc.cli.options import (
    MAX_TRIAL,
    OptionError,
    add_run_options,
    argument_of,
    int_range,
    make_out_dir,
    nonneg_float,
    out_dir_arg,
    output_file_arg,
    scenario_arg,
)
from formation_ilc.config.option_table import option
from formation_ilc.config.scenario import Scenario, ScenarioError, load_scenario
from formation_ilc.core._jit import cache_dir
from formation_ilc.core.guards import DivergedError, format_bytes, memory_shortfall
from formation_ilc.core.metrics import RobotCurves
from formation_ilc.model.footprint import BODIES
from formation_ilc.store.memoryfile import MemoryFileError, load_memory, save_memory
from formation_ilc.system.compiling import compile_notes

SIMULATE_CODES = """\
exit status: 0 done; 2 bad input (one line on stderr: file or option, and why), or a run
that would need more memory than is available (the estimate is printed); 3 the learning
diverged (errors not finite: metrics.csv keeps the finished trials, memory.npz the last
finite memory); 5 the disk is full (one line naming the file; metrics.csv and memory.npz
keep what was written before); 130 or 143 interrupted (Ctrl-C, SIGTERM): metrics.csv and
memory.npz keep every finished trial, and the command to go on is printed.
"""


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
    scenario_arg(p)
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
    for name in ("safety_margin", "safety_learning", "safety_motion"):
        # the launch's options of the filter, as the option table declares them
        names, kw = argument_of(option(name))
        p.add_argument(*names, **{**kw, "help": f"with --safety: {kw['help']}"})
    p.add_argument("--safety-age", type=nonneg_float, default=0.0, metavar="S",
                   help="with --safety: how old [s] the other robots' poses are when a robot "
                        "filters (default 0: lockstep, and the simulator in real time); "
                        "robots behind bridges (pioneer, base), each base on its own clock, "
                        "hear each other up to a sample late: the memory is then learned "
                        "through the filter they will run")
    p.add_argument("--out", type=out_dir_arg, metavar="DIR",
                   help="output folder (default: runs/SCENARIO-LAW-MEMORY-TIME)")


def _add_compare(sub: Any) -> None:
    p = sub.add_parser("compare", help="laws 9, 22, 23 in both memory readings, same draws",
                       description="Run laws (9), (22) and (23), each with memory "
                                   "'feedforward' and 'literal', on the same random draws, "
                                   "and plot their errors in one figure (like Fig. 7).")
    scenario_arg(p)
    add_run_options(p, law=False)
    p.add_argument("--out", type=out_dir_arg, metavar="DIR", help="output folder")


class Progress:
    """simulate's and compare's progress: the share of trials done, with the last trial's
    number (from 0, as in metrics.csv, the table and the plots) and errors
    (``formation_ilc.system.progress``: a bar on a terminal, a line every 10 % or 10 s in a
    log)."""

    def __init__(self, total: int, label: str, first: int = 0):
        from formation_ilc.system.progress import Progress as Bar

        self.first = first
        self.span = f"{first}..{first + total - 1}"
        self.bar = Bar(total, label, "trials", tenths=True, count=False)

    def __call__(self, k: int, row: Any) -> None:
        self.bar.to(k - self.first + 1, f"trial {k} of {self.span}: max position "
                                        f"{row[1]:.4g} m  max heading {row[2]:.4g} rad")


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
    init = _initial_memory(args, sc)
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

    recorder = _recorder(args, sc, keep, first, log)
    clear_rows: list[Any] = []
    safety = _safety_spec(args, sc)
    args.footprint = footprint = args.footprint or (args.body if safety is not None else None)
    on_data = _with_clearance(footprint, None if recorder is None else recorder.trial,
                              clear_rows)
    curves = RobotCurves(sc.desired.eta, first, k)  # errors.png's per-robot curves
    on_data = _with_curves(curves, on_data)
    t0 = time.perf_counter()
    previous = _sigterm_as_interrupt()
    try:
        with compile_notes(where=cache_dir()):
            res = simulate(sc, keep=keep, progress=on_trial, initial_memory=init,
                           first_trial=first, on_trial_data=on_data, plant=plant,
                           stop_on_divergence=True, on_memory=keeper.update,
                           store_metrics=False, safety=safety,
                           safety_age=args.safety_age if safety is not None else 0.0)
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
                             time.perf_counter() - t0, clear_rows, curves)


def _initial_memory(args: argparse.Namespace, sc: Any) -> Any:
    """--init-memory's memory for ``sc`` (None: u_0 = 0); ScenarioError if it does not fit."""
    if args.init_memory is None:
        return None
    try:
        return load_memory(args.init_memory, sc)
    except MemoryFileError as exc:
        raise ScenarioError(str(exc)) from None


def _recorder(args: argparse.Namespace, sc: Any, keep: Any, first: int, log: Any) -> Any:
    """--record's recorder of the run (None without); OptionError, the log closed, when
    the file cannot be written."""
    if args.record is None:
        return None
    from formation_ilc.nodes.observer import sim_recorder

    try:
        args.record.parent.mkdir(parents=True, exist_ok=True)
        return sim_recorder(args.record, sc, set(keep), first)
    except OSError as exc:
        log.close()
        raise OptionError(f"--record {args.record}: cannot write: "
                          f"{exc.strerror or exc}") from None


def _with_curves(curves: Any, on_data: Any) -> Any:
    """The per-trial callback that also gives each trial's outputs to ``curves``."""
    def with_curves(k: int, xi: np.ndarray, eta: np.ndarray, *rest: Any) -> None:
        curves.take(k, eta)
        if on_data is not None:
            on_data(k, xi, eta, *rest)

    return with_curves


def _safety_spec(args: argparse.Namespace, sc: Any) -> Any:
    """``simulate --safety``: the filter of ``--body`` with its own limits, or None."""
    if not getattr(args, "safety", False):
        return None
    from formation_ilc.config.safety import (
        SafetySettings,
        default_learning,
        default_margin,
        default_motion,
    )
    from formation_ilc.model.safety import body_limits, desired_clearance, spec_of

    args.safety_learning = (args.safety_learning
                            or default_learning(args.body, sc.uncertainty.pose_noise))
    if args.safety_margin is None:
        args.safety_margin = default_margin(args.body)
    args.safety_motion = getattr(args, "safety_motion", None) or default_motion(sc.n)
    spec = spec_of(SafetySettings(args.body, body_limits(args.body), args.safety_margin,
                                  args.safety_learning, motion=args.safety_motion),
                   sc.dt, sc.uncertainty)
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
                      clear_rows: list[Any], curves: Any = None) -> int:
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
                             "learning": args.safety_learning,
                             "motion": args.safety_motion}
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
        print(f"  writing {out / 'errors.png'}, {out / 'trajectories.png'} ...",
              file=sys.stderr, flush=True)
        plot_errors(rows[:, 0], rows[:, 1], rows[:, 2], out / "errors.png", title,
                    per_robot=None if curves is None else curves.arrays())
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
                with compile_notes(where=cache_dir()):
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
