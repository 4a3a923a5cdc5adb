"""Run the distributed ROS 2 stack on this machine: one OS process per node.

Starts the virtual leader, the plant (the kinematic simulator, unless --plant external),
the link emulator (with --links emulated), and one process per robot (or, with
--container N, N robot nodes per process), all on localhost discovery and on a
ROS_DOMAIN_ID of their own, in one namespace (--namespace). Prints per-trial progress,
writes DIR/metrics.csv (the columns of `formation-ilc simulate`), DIR/delays.csv (per-link
delay histograms: measured by the robots with eq. 11, injected by the emulated links, and
the model's), DIR/diagnostics.json, DIR/summary.json, DIR/errors.png and one log per
process in DIR/logs/. Stops every process on Ctrl-C, or when a node fails for good, and
then exits non-zero naming it.

Run files: `formation-ilc run-file SCENARIO [options] -o run.yaml` writes every option of
a run to one commented YAML file, `formation-ilc launch run.yaml` runs it (an option given
beside it overrides its key), and DIR/run.yaml keeps what ran, every key with its value.

Faults: a node process that dies during the run is started again with the same
parameters (at most --max-restarts times each); the robots and the leader keep their state
in DIR/state/ (written atomically at every trial), the interrupted trial is aborted and run
again, and no learned trial is lost. No node outlives the launcher, whatever signal ends
it; `launch --resume DIR` continues an interrupted run. Before anything starts, the
launcher refuses to join a ROS domain and namespace where another formation already runs
(docs/reliability.md).

Liveness and honest outcomes: the leader's watchdog names a phase that waits past its bound
on this console, re-runs, then stops the run (status 4, with the resume command); a run
whose recording lacks a trial fails (status 3); a full disk stops it (status 5, the file
named, with the resume command); a resume is decided from validated state files before
anything changes. Statuses: 0 whole, 1 a node failed, 2 refused, 3 recording incomplete,
4 stuck, 5 disk full, 6 robots touched past what --on-contact allows, 130 interrupted.

Safety (docs/safety.md): on every plant with bodies (physics, pioneer, base) each robot's
command goes through the safety filter (robots kept apart, commands inside the base's
limits, the memory learning through it); --no-safety turns it off, --safety turns it on
with the simulator. Contacts are printed at once, counted in metrics.csv and acted on
(--on-contact).

Node entry points (also `ros2 run formation_ilc <exe>` on a full ROS 2 install):
  formation-ilc-virtual-leader  virtual leader: --ros-args -p scenario:=NAME [-p trials:=K]
  formation-ilc-robot-sim       kinematic simulator, the plant (config from the config topic)
  formation-ilc-physics-sim     the PyBullet physics plant (docs/physics.md)
  formation-ilc-link-emulator   link emulator, for emulated links (config from the config topic)
  formation-ilc-robot           one robot: --ros-args -p robot_id:=I; container: --robots 1 2 3
  formation-ilc-bridge          any base's driver behind the plant contract (a Pioneer 3-DX,
                                a TurtleBot, ...): --ros-args -p robot_id:=I -p driver:=rosaria
                                (docs/real-robots.md)
The old names (formation-ilc-sim, -physics, -links, -leader, -record) still work for one
release, with a deprecation line.

--live [PORT]: serve the running formation to Foxglove on ws://127.0.0.1:PORT (its own
process, formation-ilc-liveview; docs/ros-tools.md).

--plant pioneer: one bridge per robot instead of the simulator (with --fake-drivers one
fake RosAria driver per robot too), wall-clock trials, direct links; --plant base: the same
bridges in front of any differential-drive base (--base PRESET, limits checked against the
scenario before anything starts; --physics-bases: physics robots behind them); --plant
physics: the PyBullet plant, refused where the batch simulator predicts that the robots'
bodies touch (--allow-contact); --init-memory FILE:
every robot starts from its row of a memory learned by `formation-ilc simulate`.

--secure DIR: every node in its SROS2 enclave of the keystore DIR (`formation-ilc keystore
create DIR SCENARIO`), DDS-Security enforced; refused before anything starts if the
keystore or the loaded Fast DDS cannot run it (docs/security.md).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from formation_ilc.cli.console import (
    StartupProgress,
    Watch,
    legend_line,
    live_line,
    progress_line,
)
from formation_ilc.cli.launchargs import add_arguments, launch_parser, without_defaults
from formation_ilc.cli.supervisor import (
    Stack,
    Supervisor,
    disk_full_line,
    node_env,
    resume_hint,
    trial_ranges,
)
from formation_ilc.plan.specs import NodeSpec, NoRun, RunPlan, finished
from formation_ilc.protocol.watchdog import Bounds
from formation_ilc.system.discovery import SERVER_ENV
from formation_ilc.system.exits import DISK_FULL, STUCK, is_disk_full

__all__ = ["add_arguments", "run", "execute", "Stack", "launch_parser", "without_defaults",
           "StartupProgress", "Watch"]


# --------------------------------------------------------------------------- running
def _compile_notes(args: argparse.Namespace) -> Any:
    """Robots with bodies: the plan runs the batch simulator to predict contacts, which
    compiles it on a fresh install; that is said on the console while it lasts."""
    import contextlib

    from formation_ilc.config.plants import plant

    try:
        bodies = plant(str(getattr(args, "plant", None) or "sim")).bodies
    except ValueError:
        bodies = False  # the plan refuses it, in its words
    if not bodies:
        return contextlib.nullcontext()
    from formation_ilc.core._jit import cache_dir
    from formation_ilc.system.compiling import compile_notes

    return compile_notes("the batch simulator (it predicts contacts before the run)",
                         where=cache_dir())


def run(args: argparse.Namespace) -> int:
    """Run the stack; return the exit status (0 ok, 1 a node failed, 2 refused, 130
    interrupted): the plan, built once from the options, then its execution (with
    --hosts netns inside the robots' network namespaces)."""
    from formation_ilc.cli.runfile import plan_of

    try:
        with _compile_notes(args):
            plan = plan_of(args)
    except NoRun as stop:
        return stop.report()
    if not plan.ground:  # a host of a run file's hosts: without the leader
        from formation_ilc.cli.hostlaunch import run_member_host
        from formation_ilc.system.private import private

        with private(_run_files(plan)):  # its members' files too (a recorder among them)
            return run_member_host(plan)
    if plan.hosts is not None:
        from formation_ilc.cli.hosts import run_on_hosts

        status = run_on_hosts(plan, execute)
    else:
        status = execute(plan)
    from formation_ilc.nodes.host import LauncherHost

    if LauncherHost.teardown_hung:
        # the results are written; the interpreter's exit would block on the same lock
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


def _run_files(plan: RunPlan) -> list[Path]:
    """Where a run's files go: its folder, and its recording (which holds the key that
    seals the leader's events: ``system.private`` keeps them the user's alone while the
    run lives)."""
    return [plan.out, *([plan.record] if plan.record else [])]


def execute(plan: RunPlan, place: Callable[[NodeSpec], list[str]] | None = None) -> int:
    """Run ``plan``: its processes under a supervisor, the trials followed by a monitor
    node, then the report; the exit status. ``place``: a process's command line (default
    its own)."""
    if plan.record is not None:  # the recorder makes no folder: it is the launcher's
        try:
            plan.record.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            print(f"error: argument --record: {plan.record.parent}: cannot create the "
                  f"folder: {exc.strerror or exc}", file=sys.stderr)
            return 2
    if plan.run_json is not None:
        _save_run(plan.out, plan.run_json, plan)
    _save_config(plan)
    plan.write_peers_profile()  # before the secure one, which builds on it
    if plan.secure is not None:
        plan.secure.write_profile()
    env = node_env(plan)
    server = None
    if plan.discovery == "server":  # every process a client, the monitor too
        from formation_ilc.system.discovery import DiscoveryServer, ServerError

        # (with --hosts netns this runs in the hub's namespace: the server listens on the
        # hub's address on the bridge, which every robot's namespace reaches)
        server = DiscoveryServer(plan.out / "logs" / "discovery_server.log", plan.server_host)
        try:
            env[SERVER_ENV] = server.start()
        except ServerError as exc:
            print(f"error: --discovery server: {exc}", file=sys.stderr)
            return 2
        print(f"discovery: through Fast DDS's discovery server on {env[SERVER_ENV]} "
              f"({plan.participants} participants)", flush=True)
    try:
        return _run_started(plan, env, place)
    finally:
        if server is not None:
            server.stop()
            os.environ.pop(SERVER_ENV, None)


def _run_started(plan: RunPlan, env: dict[str, str],
                 place: Callable[[NodeSpec], list[str]] | None) -> int:
    """``run_plan`` once the environment is ready: the session, its report."""
    from formation_ilc.cli.report import write_report
    from formation_ilc.system.private import private
    from formation_ilc.system.shm import clean_leftovers, fastdds_files

    # Fast DDS files that nodes killed earlier left behind (held by no process)
    stale = clean_leftovers(min_age=2.0)
    if stale:
        print(f"removed {len(stale)} Fast DDS shared-memory files of dead processes")
    shm_before = fastdds_files()
    # our own monitor node joins the same domain: set before rclpy initialises
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    for name in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "FASTRTPS_DEFAULT_PROFILES_FILE"):
        if name in env:
            os.environ[name] = env[name]
    # the discovery server the nodes use, or none (node_env drops a caller's on localhost)
    if SERVER_ENV in env:
        os.environ[SERVER_ENV] = env[SERVER_ENV]
    else:
        os.environ.pop(SERVER_ENV, None)
    for note in plan.notes:
        print(note, flush=True)
    print(plan.banner(), flush=True)
    print(legend_line(plan), flush=True)
    if plan.live is not None:
        print(live_line(*plan.live), flush=True)
    session = _Session(plan, env, place)
    if session.hosts is not None:
        from formation_ilc.cli.hostlaunch import STARTING, over_graph, write_ground

        # the other hosts stop what they run for an earlier run here before this one
        # looks for another formation on its domain (over the graph: once it joined it)
        if not over_graph(plan):
            write_ground(plan, STARTING)
    # the run's files, the recording with its events' key among them, are the user's
    # alone while it lives (system.private)
    try:
        with private(_run_files(plan)):
            status = session.run()
    finally:
        # the shared-memory files of nodes killed during the run, and older leftovers
        clean_leftovers(fastdds_files() - shm_before)
        clean_leftovers(min_age=2.0)
    if status == 0 and plan.record_root is not None:
        status = check_recording(plan.record_root, plan.scenario.trials, plan.resumed_at,
                                 plan.out / "metrics.csv")
    if session.hosts is not None:  # the other hosts' launchers stop their members
        from formation_ilc.cli.hostlaunch import over_graph, print_hosts, write_ground

        if not over_graph(plan):  # (over the graph: said before the launcher left it)
            write_ground(plan, status)
        print_hosts(session.hosts)
    status = write_report(plan, session.rows(), session.diagnostics,
                          session.supervisor.restarts, time.monotonic() - session.t_start,
                          status, startup=session.startup(),
                          ending_contact=session.ending_contact)
    if session.hosts is not None:
        session.hosts.save(plan.out / "summary.json")
    return status


def check_recording(root: Path, trials: int, resumed_at: int | None = None,
                    metrics: Path | None = None) -> int:
    """0 when every trial of the run is complete in its recording (every part of it, read
    as ``analyze`` reads it); else say which trials are missing and why, and return 3: a
    run whose recording lost a trial has not succeeded.

    A resumed run (``resumed_at`` trials learned before this launch) whose only missing
    trials were learned before it, in a launch whose recorder stopped before it wrote them
    (a trial that ended just before its launcher was killed), is whole all the same when
    ``metrics`` has every trial's row and every row the recording has equals it: that is
    said in a note, and the status is 0."""
    from formation_ilc.recordings.recording import (
        RecordingError,
        load_recording,
        recording_parts,
    )

    parts = [p for p in recording_parts(root) if p.exists()]
    try:
        rec = load_recording(parts, keep=lambda k, n: False) if parts else None
    except (RecordingError, OSError, ValueError) as exc:
        print(f"error: the recording cannot be read back: {exc}", file=sys.stderr)
        return INCOMPLETE
    missing = list(range(trials)) if rec is None else rec.missing
    if not missing:
        return 0
    names = ", ".join(p.name for p in parts) or f"{root.name} (never written)"
    if rec is not None and resumed_at and metrics is not None:
        note = _learned_before(rec, missing, trials, resumed_at, metrics, names)
        if note is not None:
            print(f"note: {note}", flush=True)
            return 0
    damaged = rec is not None and any(r.damaged for _, r in rec.parts)
    why = ("the files are damaged" if damaged else
           "no recorder had them: it was restarted or killed while they ran")
    shown = ", ".join(map(str, missing[:20])) + (", ..." if len(missing) > 20 else "")
    print(f"error: the run finished, but its recording lacks {len(missing)} of its {trials} "
          f"trials ({shown}) in {names}: {why}; metrics.csv has them all "
          f"(formation-ilc analyze {root} says the same)", file=sys.stderr)
    return INCOMPLETE


#: exit status of a run that finished but whose recording lacks trials
INCOMPLETE = 3
#: how long the launcher still takes messages after a node failed for good [s]
DRAIN_S = 0.3


def _learned_before(rec: Any, missing: list[int], trials: int, resumed_at: int,
                    metrics: Path, names: str) -> str | None:
    """Why a resumed run is whole although its recording lacks ``missing``, or None: each
    was learned before the resume (the interrupted launch's monitor wrote its row, its
    recorder stopped before it wrote the trajectories), metrics.csv has every trial, and
    every row the recording has is metrics.csv's to the last bit."""
    from formation_ilc.core.metrics import format_row, read_metrics

    if any(k >= resumed_at for k in missing):
        return None
    try:
        rows = {int(r[0]): format_row(r) for r in read_metrics(metrics)}
    except (OSError, ValueError):
        return None
    if set(range(trials)) - set(rows):
        return None
    recorded = {int(r[0]): format_row(r) for r in rec.metrics}
    if any(rows[k] != row for k, row in recorded.items()):
        return None
    cut = [p.name for p, r in rec.parts if r.cut_short]
    return (f"the recording ({names}) lacks {trial_ranges(missing)}: learned before this "
            f"launch resumed the run (at {resumed_at} trials), by a launch that was stopped "
            f"before its recorder wrote the trajectories"
            + (f" ({', '.join(cut)} end{'s' * (len(cut) == 1)} cut short)" if cut else "")
            + f"; metrics.csv has every trial's row, from that launch's monitor, and the "
              f"recording's {len(recorded)} others equal metrics.csv to the last bit")


def _save_run(out: Path, options: Any, plan: RunPlan) -> None:
    """DIR/run.yaml, the resolved run file (every key with the value the run went with,
    the run's id; ``cli.runfile.stored_run_text``): the one stored description of the run,
    which ``--resume`` and the tools read. Paths into the run's folder are relative to it
    (a copied folder resumes into itself). (Launches before run files wrote run.json,
    which ``--resume`` still reads.)"""
    from formation_ilc.cli.runfile import RUN_YAML, stored_run_text
    from formation_ilc.store.atomic import atomic_write_text

    d = dict(options)
    if isinstance(d.get("scenario"), str) and Path(d["scenario"]).is_file():
        d["scenario"] = str(Path(d["scenario"]).resolve())
    atomic_write_text(out / RUN_YAML, stored_run_text(
        plan, d,
        title="what this run ran, every key with the value it went with: formation-ilc "
              "launch --resume\nTHIS_FOLDER goes on with it; formation-ilc launch run.yaml "
              "--out NEW runs it again as a new run"))


def _save_config(plan: RunPlan) -> None:
    """DIR/config.json: the run configuration (scenario text, options, run id), written
    atomically at each launch of the run."""
    import json

    from formation_ilc.store.atomic import atomic_write_text
    from formation_ilc.store.runfile import CONFIG_FILE

    atomic_write_text(plan.out / CONFIG_FILE, json.dumps(
        plan.config.to_json() | {"namespace": plan.namespace}) + "\n")


def _rewrite_metrics(path: Path, kept: list[Any]) -> None:
    """metrics.csv with only the rows ``kept``, written atomically."""
    import csv

    from formation_ilc.core.metrics import METRIC_COLUMNS, format_row
    from formation_ilc.store.atomic import atomic_open

    with atomic_open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(METRIC_COLUMNS)
        for r in kept:
            w.writerow(format_row(np.asarray(r, dtype=float)))


def _late_counts(path: Path, rows: dict[int, Any], late: set[int]) -> None:
    """metrics.csv with the counts its rows took after they were written (``late``: their
    trials; ``rows``: the monitor's, by trial): each trial's row as the monitor has it now,
    every other line as it was (a contact's own row, which ended the run in a return)."""
    from formation_ilc.core.metrics import METRIC_COLUMNS, read_metrics

    col = METRIC_COLUMNS.index("contacts")
    kept = []
    for r in read_metrics(path):
        k = int(r[0])
        if k in late and k in rows and np.isnan(r[col]) and np.isfinite(r[1]):
            r = rows[k]
        kept.append(r)
    _rewrite_metrics(path, kept)


class _Refused(Exception):
    """The run was refused before any node started (the message is printed)."""


class Diverged(Exception):
    """A trial's errors are not finite."""

    def __init__(self, trial: int):
        super().__init__(trial)
        self.trial = trial


class _Session:
    """One execution of a plan: the metrics file, the supervisor, and the ROS host with the
    monitor node (``formation_ilc.nodes.host``)."""

    def __init__(self, plan: RunPlan, env: dict[str, str],
                 place: Callable[[NodeSpec], list[str]] | None):
        from formation_ilc.core.metrics import COUNT_COLUMNS, METRIC_COLUMNS, TRUE_COLUMNS

        self.plan = plan
        self.done = plan.resumed_at or 0  # iterations every robot has learned (resumed)
        self.kept, self.writer = self._metrics()
        self.t_start = time.monotonic()
        # without a true state the true_ columns are nan by design
        self.finite_cols = [i for i, c in enumerate(METRIC_COLUMNS)
                            if i > 0 and c not in COUNT_COLUMNS
                            and (plan.true_state or c not in TRUE_COLUMNS)]
        self.supervisor = Supervisor(plan, env, place, on_down=self._down)
        self.progress: StartupProgress | None = None
        self.host: Any = None
        self.diagnostics: dict[str, dict[str, Any]] = {}
        #: the first trial whose errors were not finite (the loop stops the run)
        self.diverged: int | None = None
        #: the contact (or tilt) that ends the run, as the plant said it (None: none)
        self.ending_contact: dict[str, Any] | None = None
        #: a stop signal came while the executor ran a callback (the loop acts on it)
        self.stop_signal: int | None = None
        self.spinning = False
        #: with a run file's hosts: the other hosts as the ground station sees them
        self.hosts: Any = None
        if plan.host is not None:
            from formation_ilc.cli.hostlaunch import HostWatch

            self.hosts = HostWatch(plan)

    def _metrics(self) -> tuple[list[Any], Any]:
        """metrics.csv, opened for the run: a resumed run's learned trials kept."""
        from formation_ilc.core.metrics import MetricsWriter, read_metrics

        out, done = self.plan.out, self.done
        if not done:
            return [], MetricsWriter(out / "metrics.csv")
        path = out / "metrics.csv"
        # the plan read it already (a damaged file refuses the resume): keep the learned
        # trials' rows, rewritten atomically (a crash leaves the old file or the new one)
        kept = [r for r in read_metrics(path) if int(r[0]) < done] if path.exists() else []
        _rewrite_metrics(path, kept)
        lost = sorted(set(range(done)) - {int(r[0]) for r in kept})
        print(f"resuming {out}: {done} of {self.plan.scenario.trials} trials learned; run "
              f"{self.plan.config.run_id}"
              + (f" (metrics.csv lacks the rows of learned trial(s) "
                 f"{', '.join(map(str, lost))}: the launcher stopped before it wrote them)"
                 if lost else ""), flush=True)
        return kept, MetricsWriter(path, append=True)

    def startup(self) -> dict[str, float | None]:
        """When every node was found and ready, and the first trial started [s from the
        session's start]."""
        return self.progress.summary() if self.progress is not None else {}

    def rows(self) -> list[Any]:
        """Every finished trial's metrics row, by iteration (a resumed run's first)."""
        monitor = self.host.monitor if self.host is not None else None
        got = monitor.rows if monitor is not None else {}
        return list(self.kept) + [got[k] for k in sorted(got)]

    def on_trial(self, k: int, row: np.ndarray) -> None:
        """A trial's row, from the monitor's callback: written; a row that is not finite
        stops the run from the loop (an exception raised in a callback is rclpy's to log,
        with a stack)."""
        self.writer.write(row)
        now = time.monotonic()
        if not np.isfinite(row[self.finite_cols]).all():
            if self.diverged is None:
                self.diverged = k
            return
        print(progress_line(k, self.plan, row) + f"  [{now - self.t_start:.1f} s]",
              flush=True)
        self._say_forged()

    def _say_forged(self) -> None:
        """Once a trial, when it changed: the messages refused for their writer."""
        from formation_ilc.protocol.writers import forged_line

        monitor = self.host.monitor if self.host is not None else None
        line = forged_line(monitor.forged_reports()) if monitor is not None else ""
        if line and line != getattr(self, "_forged_said", ""):
            self._forged_said = line
            print(line, flush=True)

    def on_contact(self, node: str, c: dict[str, Any]) -> None:
        """A plant's contact, said the moment it happened (the plant acts on it)."""
        action = {"stop": "the robots are stopped and the trial runs again",
                  "abort": "the run ends", "give_up": "the run ends (retries spent)",
                  "continue": "going on"}.get(str(c.get("action")), "")
        if c.get("acts") is False and c.get("action") != "continue":
            action = "the robots already stand"
        print(f"contact: {str(c.get('line', ''))[:300]}: {action} ({node})", flush=True)
        if (c.get("action") in ("abort", "give_up") and c.get("acts") is not False
                and self.ending_contact is None):
            # the contact that ends the run: a field of summary.json, and its trial a row
            # of metrics.csv (no errors: the robots stood; the pairs that touched)
            from formation_ilc.core.metrics import METRIC_COLUMNS

            self.ending_contact = {"node": node, **{k: c.get(k) for k in (
                "trial", "slot", "sample", "phase", "line", "action", "pairs", "tilt")}}
            row = np.full(len(METRIC_COLUMNS), np.nan)
            row[0] = float(c.get("trial", -1))
            row[METRIC_COLUMNS.index("contacts")] = float(len(c.get("pairs") or []))
            with contextlib.suppress(OSError, ValueError):  # the run ends either way
                self.writer.write(row)

    def on_clock(self, node: str, level: str, text: str) -> None:
        """A node's clock event (a step, an estimate that does not converge), said once."""
        print(f"{level.upper()}: {text[:500]}", flush=True)

    def _down(self, name: str, pid: int) -> None:
        """Tell the leader at once that a node died and is started again: a passive one,
        so that no trial starts without it (the recorder: no trial unrecorded); any, so
        that its successor's new participant takes its name at once (its predecessor's
        stays in the graph until its lease runs out: ``protocol.writers``)."""
        self.host.down(name, pid)

    def run(self) -> int:
        """Start the nodes, follow the trials to the end; the exit status (the outputs
        are the caller's)."""
        from formation_ilc.nodes.host import LauncherHost

        def on_term(signum: int, frame: Any) -> None:
            # inside the executor an exception would end up in rclpy's log as a FATAL
            # stack: the loop stops the run right after the callback instead
            self.stop_signal = signum
            if not self.spinning:
                raise KeyboardInterrupt

        signal.signal(signal.SIGTERM, on_term)
        signal.signal(signal.SIGINT, on_term)
        self.host = LauncherHost(self.plan, self.on_trial, first=self.done,
                                 on_contact=self.on_contact, on_clock=self.on_clock)
        # 1 until the run is followed to its end: an error that escapes prints no success
        status = 1
        try:
            self.host.start()
            status = self._follow()
        except _Refused:
            status = 2
        except Diverged as exc:
            print(f"error: trial {exc.trial}: the errors are no longer finite (the "
                  f"learning diverged; check the gains with `formation-ilc check`): "
                  f"stopping; the finished trials are in metrics.csv", file=sys.stderr)
            status = 1
        except KeyboardInterrupt:
            go_on = (f"to go on: {resume_hint(self.plan.out)}" if self.hosts is None else
                     "a run over several machines does not resume yet (its robots' learned "
                     "state is on their machines): start a new one with --out NEW")
            print(f"\ninterrupted: stopping every node; finished trials are in metrics.csv; "
                  f"{go_on}", file=sys.stderr)
            status = 130
        except OSError as exc:
            if not is_disk_full(exc):
                raise
            print(f"error: {disk_full_line('the launcher', exc.filename, self.plan.out)}",
                  file=sys.stderr)
            status = DISK_FULL
        finally:
            if status == 0:
                print(f"every trial is in: stopping the {len(self.plan.nodes)} processes "
                      f"[{time.monotonic() - self.t_start:.1f} s]", flush=True)
            self._deactivate()
            self.supervisor.stop()
            self.writer.close()
            if self.hosts is not None:  # the other hosts' launchers stop their members
                from formation_ilc.cli.hostlaunch import describe, over_graph

                if over_graph(self.plan) and self.host.monitor is not None:
                    describe(self.plan, self.host, status)
                    self.host.described(3.0)
            self.diagnostics = self.host.close()
            monitor = self.host.monitor
            if monitor is not None and monitor.slots.late_counts:
                # a count said after its row went out (the physics bases' contacts of the
                # last trial): metrics.csv written again with it
                _late_counts(self.plan.out / "metrics.csv", monitor.rows,
                             monitor.slots.late_counts)
        return status

    def _deactivate(self) -> None:
        """Managed bridges: deactivated (their bases stop) before their processes end."""
        tr = self.host.transitions if self.host is not None else None
        if tr is None:
            return
        silent = tr.deactivate(self.host.spin_once)
        if silent:
            print(f"warning: {', '.join(silent)} did not answer the deactivate request; "
                  f"stopping the processes stops them too", file=sys.stderr)

    def _follow(self) -> int:
        """The monitor joins, the nodes start, and the run is followed until every trial
        and report is in (or the wait for them is over), or a node fails for good."""
        self._start_nodes()
        plan, host = self.plan, self.host
        # on a terminal a line a second; in a log a line when the counts move, else one in 10 s
        self.progress = StartupProgress(
            plan.team.expected, self.t_start, every=1.0 if sys.stdout.isatty() else 10.0)
        self._graph_at, self._found = 0.0, set[str]()
        self._final_deadline: float | None = None
        bounds = Bounds.for_run(plan.scenario.dt, len(plan.team.expected), plan.config.mode,
                                plan.config.timeout, plan.watchdog_scale,
                                secure=plan.secure is not None)
        watch = Watch(bounds, plan.out, len(plan.team.expected), plan.scenario.trials)
        # a process that spins but that no node discovered, after this long: restarted
        self._unseen_after = max(30.0, bounds.startup / 2)
        self._trial_progress = None
        if plan.config.mode == "wallclock":  # a trial in real time: said while it runs
            from formation_ilc.cli.trialprogress import TrialProgress

            self._trial_progress = TrialProgress(plan.scenario.samples * plan.scenario.dt,
                                                 plan.scenario.trials,
                                                 every=5.0 if sys.stdout.isatty() else 10.0)
        hosts = self.hosts
        if hosts is not None:  # a stuck run's first line: the host that is not there
            watch.cause = lambda: hosts.cause(self._found, time.monotonic())
        while True:
            self.spinning = True
            try:
                host.spin_once(0.05)
            finally:
                self.spinning = False
            self._say_progress()
            status = self._verdict(watch)
            if status is not None:
                return status

    def _start_nodes(self) -> None:
        """The processes start gated (imports are most of their start) while the monitor
        looks for another formation here; they join the domain only once there is none."""
        plan, host, hosts = self.plan, self.host, self.hosts
        if hosts is not None:  # the other hosts stop what they run for an earlier run
            from formation_ilc.cli.hostlaunch import STARTING, describe, over_graph

            if over_graph(plan):
                describe(plan, host, STARTING)
        self.supervisor.start(gated=True)
        forked = self.supervisor.stack.forked()
        how = ("" if not forked else " (forked from one import)" if forked == len(plan.nodes)
               else f" ({forked} forked from one import)")
        print(f"started {len(plan.nodes)} processes{how}; looking for another formation on "
              f"ROS_DOMAIN_ID={plan.domain} in {plan.namespace} ...", flush=True)
        self._refuse_foreign(1.5)
        self.supervisor.open_gate()
        print(f"none: the processes join; the leader waits for {len(plan.team.expected)} "
              f"nodes [{time.monotonic() - self.t_start:.1f} s]", flush=True)
        if hosts is not None:  # the other hosts' launchers start their members now
            describe(plan, host)

    def _say_progress(self) -> None:
        """The console's lines of the moment: bridges' transitions, the start-up (the nodes
        found on the graph, asked twice a second, and ready), the other hosts, a trial in
        real time."""
        from formation_ilc.protocol.schedule import START

        plan, host, hosts, progress = self.plan, self.host, self.hosts, self.progress
        monitor = host.monitor
        assert progress is not None
        if host.transitions is not None and not host.transitions.active:
            for line in host.transitions.step():
                print(line, flush=True)
        now = time.monotonic()
        if (progress.active or hosts is not None) and now - self._graph_at >= 0.5:
            self._graph_at = now
            self._found = {name for name, ns in monitor.get_node_names_and_namespaces()
                           if ns == plan.namespace}
            for line in (hosts.update(now, self._found, monitor.readies)
                         if hosts is not None else ()):
                print(line, flush=True)
        found = self._found
        if progress.active:
            ready = set(monitor.readies)
            # a process that spins but that no node discovered: named, started again
            self.supervisor.unseen(found | ready, self._unseen_after)
            line = progress.update(now, found | ready, ready,
                                   any(e.get("event") == START for e in monitor.events))
            silent = hosts.silent(found | ready) if hosts is not None else []
            if line and silent and not line.startswith("start-up done"):
                line += f"; not heard from host{'s' * (len(silent) > 1)} {', '.join(silent)}"
            if line:
                print(line, flush=True)
        if self._trial_progress is not None and not progress.active:
            line = self._trial_progress.update(time.time_ns(), monitor.events, monitor.rows)
            if line:
                print(line, flush=True)

    def _verdict(self, watch: Watch) -> int | None:
        """The run's status once it is over (every trial and the last reports in, stuck, a
        node failed for good), else None; a signal or a divergence raises."""
        plan, host, monitor = self.plan, self.host, self.host.monitor
        if self.stop_signal is not None:
            raise KeyboardInterrupt
        if self.diverged is not None:
            raise Diverged(self.diverged)
        stuck = watch.tick(monitor, time.monotonic())
        if stuck is not None:
            first = watch.cause() if watch.cause is not None else None
            if first:
                print(f"error: {first}", file=sys.stderr)
            print(f"error: {stuck}", file=sys.stderr)
            return STUCK
        if len(monitor.rows) == plan.scenario.trials - self.done:
            # the last diagnostics come right after the last trajectories (bridges
            # drive their robots back after the last trial too)
            if self._final_deadline is None:
                self._final_deadline = time.monotonic() + plan.final_wait
            if (finished(plan, monitor.diagnostics, monitor.events)
                    or time.monotonic() > self._final_deadline):
                return 0
        failure = self.supervisor.watch()
        if failure is None:
            return None
        first = watch.cause() if watch.cause is not None else None
        if first:  # the cause first: a host that is not there
            print(f"error: {first}", file=sys.stderr, flush=True)
        # a node that ends the run on purpose (a contact) has its last report
        # acknowledged before it exits: take what is already here, which the exit
        # overtook, so that summary.json and metrics.csv have it
        drain = time.monotonic() + DRAIN_S
        while time.monotonic() < drain:
            host.spin_once(0.05)
        return self.supervisor.report(failure)

    def _refuse_foreign(self, wait: float) -> None:
        """_Refused, said why, when another formation runs on this domain and namespace
        (an external plant's nodes are ours)."""
        plan = self.plan
        allowed = {m.name for m in plan.roster.by_role("plant") if m.entry is None}
        others = self.host.foreign(wait, allowed)
        if others:
            print(f"error: another formation runs on ROS_DOMAIN_ID={plan.domain} in namespace "
                  f"{plan.namespace} ({', '.join(sorted(others)[:6])}"
                  f"{', ...' if len(others) > 6 else ''}): refusing to start a second one "
                  f"there (it would corrupt both); use --namespace or --domain-id",
                  file=sys.stderr)
            raise _Refused
