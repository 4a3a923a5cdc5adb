"""``formation-ilc``: simulate, compare, check and launch formation learning runs.

Run ``formation-ilc COMMAND --help`` for each command.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

# The lifted check multiplies 1800 x 1800 matrices; on 2 cores a threaded BLAS spins more
# than it gains (measured: 10.5 s threaded, 3.9 s single-threaded). Set before numpy loads.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from formation_ilc.cli.options import (  # noqa: E402
    OneLineParser,
    OptionError,
    int_range,
    make_out_dir,
    out_dir_arg,
    output_file_arg,
    positive_float,
    positive_int,
    scenario_arg,
)
from formation_ilc.cli.simulate import (  # noqa: E402
    _add_compare,
    _add_simulate,
    _fits,
    cmd_compare,
    cmd_simulate,
)
from formation_ilc.cli.studies import (  # noqa: E402
    _add_sweep,
    _add_tune,
    _regular_file,
    cmd_sweep,
    cmd_tune,
)
from formation_ilc.config.scenario import (  # noqa: E402
    Scenario,
    ScenarioError,
    builtin_scenarios,
    load_scenario,
)
from formation_ilc.core.topology import SpanningTreeError  # noqa: E402
from formation_ilc.model.footprint import BODIES  # noqa: E402
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


def _add_check(sub: Any) -> None:
    p = sub.add_parser("check", help="Theorem 2, condition (20) and the lifted heading map",
                       description="Check a scenario before running it: Theorem 2 (a "
                                   "spanning tree), condition (20), and the lifted heading "
                                   "map's convergence and transient. The exit status is "
                                   "the verdict, for scripts (below).",
                       epilog=CHECK_CODES,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    scenario_arg(p)
    p.add_argument("--law", type=int, choices=(9, 22, 23))
    p.add_argument("--memory", choices=("feedforward", "literal"))
    p.add_argument("--trials", type=positive_int, metavar="K",
                   help="horizon for the transient-growth estimate (default: scenario's)")
    p.add_argument("--no-delay", action="store_true",
                   help="check the delay-free configuration (as run with --no-delay)")
    p.add_argument("--base", choices=(*BODIES, "none"), default="p3dx",
                   help="the robots the desired motion must fit: their speed and "
                        "acceleration limits (the base's row of the one limits table the "
                        "bridges, the physics models and the filter read) and their body "
                        "for the safety filter (default p3dx, the paper's Pioneer 3-DX; "
                        "none: check the learning only)")
    p.add_argument("--headings", choices=("auto", "chord", "arc"), default="arc",
                   help="the desired headings the motion is checked with (default arc: "
                        "robots that drive arcs)")
    p.add_argument("--time-scale", type=positive_float, default=None, metavar="S",
                   help="check the scenario stretched in time by S")


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

    first, _, rest = (launch.__doc__ or "").partition("\n\n")
    p = sub.add_parser("launch", help="run the distributed ROS 2 stack on localhost",
                       usage="formation-ilc launch [SCENARIO | RUN.yaml] [options]",
                       description=first, epilog=rest,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    launch.add_arguments(p)
    launch.without_defaults(p)


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
    from formation_ilc.model.safety import motion_fit, motion_peaks, what_fits

    if args.base == "none":
        return []
    moved = sc.with_options(headings=args.headings, time_scale=args.time_scale)
    body = args.base
    # the filter as the run will have it: room for the scenario's noise, tried on it
    noise = moved.uncertainty if moved.uncertainty.noisy else None
    fit = motion_fit(moved, body, noise)
    limits = fit.limits
    print(f"desired motion ({args.headings} headings"
          + (f", time scale {moved.time_scale:g}" if moved.time_scale != 1 else "")
          + f"; {body}: v <= {limits.v_max:g} m/s, omega <= {limits.omega_max:.3g} rad/s, "
            f"a <= {limits.a_max:g} m/s^2, alpha <= {limits.alpha_max:.3g} rad/s^2):")
    for p in motion_peaks(moved):
        print(f"  {p.line(moved.dt)}")
    problems = []
    if fit.limits_line is not None:
        problems.append(f"{body}: {fit.limits_line}")
    dc = fit.clearance
    print(f"  closest robots: {dc.line(moved.dt)}")
    if fit.through is None:
        problems.append(f"{body}: {dc.line(moved.dt)}: the safety filter would hold the "
                        f"robots off their formation; widen the offsets")
        return problems
    through = fit.through
    print(f"  {through.line(moved.dt)}")
    if not through.passes:
        scale, spread = what_fits(moved, fit.spec, fit.noisy)
        fixes = [f"--time-scale {moved.time_scale * scale:g} (slower)" if scale else "",
                 f"the formation's offsets x {spread:g} (wider)" if spread else ""]
        fix = " or ".join(f for f in fixes if f) or "no time scale up to 4 nor spread up to 2"
        problems.append(f"{body}: {through.line(moved.dt)}; it would hold them off their "
                        f"formation in every trial; what fits: {fix}")
    return problems


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
