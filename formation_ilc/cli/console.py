"""The launcher's console: its start-up lines, its liveness backstop, a trial's line.

``cli.launch`` runs a run and says how it goes with these: ``StartupProgress`` (the nodes
found and ready while the run starts), ``Watch`` (a run that stopped moving, named from the
leader's events), the lines of the live view, the legend and each trial.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Collection, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from formation_ilc.cli.supervisor import metrics_rows, resume_hint, trial_ranges
from formation_ilc.plan.specs import RunPlan

__all__ = ["StartupProgress", "Watch", "live_line", "legend_line", "progress_line"]


class StartupProgress:
    """What the console shows while a run starts: from the processes' start to the
    leader's first ``start``, a line at least every ``every`` seconds (sooner when a count
    moved), with how many of the nodes the leader waits for are found in the ROS graph
    and how many have said ready; after ``name_after`` seconds, also whom it still waits
    for. Then one line that the first trial starts. The times it saw (``found_at``: every
    node found, ``ready_at``: every node ready, ``started_at``: the first start; seconds
    from ``t0``) go into summary.json."""

    def __init__(self, expected: Sequence[str], t0: float, every: float = 1.0,
                 name_after: float = 5.0):
        self.expected = list(expected)
        self.t0 = t0
        self.every = every
        self.name_after = name_after
        self.last_line = -math.inf  # the first call prints
        self.last_counts: tuple[int, int] = (-1, -1)
        self.found_at: float | None = None
        self.ready_at: float | None = None
        self.started_at: float | None = None

    @property
    def active(self) -> bool:
        return self.started_at is None

    def update(self, now: float, found: Collection[str], ready: Collection[str],
               started: bool) -> str | None:
        """The line to print now, or None. ``found``: node names found in the graph;
        ``ready``: nodes that have said ready; ``started``: the leader started a trial."""
        if not self.active:
            return None
        t = now - self.t0
        n = len(self.expected)
        n_found = sum(1 for e in self.expected if e in found)
        n_ready = sum(1 for e in self.expected if e in ready)
        if n_found == n and self.found_at is None:
            self.found_at = t
        if n_ready == n and self.ready_at is None:
            self.ready_at = t
        if started:
            self.started_at = t
            return f"start-up done [{t:.1f} s]: {n} nodes ready, the first trial starts"
        counts = (n_found, n_ready)
        if counts == self.last_counts and now - self.last_line < self.every:
            return None
        if counts != self.last_counts and now - self.last_line < 0.25 * self.every:
            return None  # several changes at once: one line
        self.last_counts, self.last_line = counts, now
        line = f"start-up [{t:.1f} s]: {n_found} of {n} nodes found, {n_ready} ready"
        if n_ready == n:
            line += "; waiting for the leader to start the first trial"
        elif t >= self.name_after:
            waiting = [e for e in self.expected if e not in ready]
            line += f"; waiting for {', '.join(waiting[:6])}" + (
                f" and {len(waiting) - 6} more" if len(waiting) > 6 else "")
        return line

    def summary(self) -> dict[str, float | None]:
        return {"all_found_s": self.found_at, "all_ready_s": self.ready_at,
                "first_start_s": self.started_at}


class Watch:
    """The launcher's side of liveness: it prints the leader's watchdog findings on the
    console (they arrive in the leader's diagnostics), and, as a backstop for a leader
    that cannot report (it never started, hung, or went silent), gives up when nothing at
    all has moved (no trial event, row, or report) for the longest bound times
    (RETRIES + 3): by then the leader's own watchdog has reported, retried and stopped
    (``formation_ilc.protocol.watchdog``). Until the leader's events writer shows up, the
    bound is twice the unscaled start-up bound (starting processes is as slow as the
    machine, whatever the scale). Once the leader is done, a trial row still missing after
    the ready bound will not come (a trajectory was lost on its way here): the run stops
    naming it rather than wait for the backstop."""

    def __init__(self, bounds: Any, out: Path, nodes: int, trials: int):
        from formation_ilc.protocol.watchdog import RETRIES, STARTUP_PER_NODE_S, STARTUP_S

        self.limit = max(bounds.startup, bounds.ready, bounds.sample) * (RETRIES + 3)
        self.first = 2 * (STARTUP_S + STARTUP_PER_NODE_S * nodes)
        self.after_done = bounds.ready
        self.trials = trials
        self.out = out
        self.seen = 0
        self.mark: tuple[int, int, int] = (-1, -1, -1)
        self.since = time.monotonic()
        self.leader = False
        self.done_at: float | None = None
        #: what a finding of the leader's comes from, said before it (a host that is not
        #: there: ``cli.hostlaunch.HostWatch.cause``), or None
        self.cause: Callable[[], str | None] | None = None

    def tick(self, monitor: Any, now: float) -> str | None:
        """Print a new finding of the leader's; why the run is given up, or None."""
        from formation_ilc.core.names import LEADER_NODE

        report = monitor.diagnostics.get(LEADER_NODE, {}).get("watchdog") or {}
        count = report.get("count", 0)
        if count > self.seen:
            self.seen = count
            text = "".join(c if c.isprintable() else "?" for c in str(report.get("what")))
            first = self.cause() if self.cause is not None else None
            if first:
                print(f"error: {first}", flush=True)
            print(f"{LEADER_NODE}: {text[:1000]}", flush=True)
        if not self.leader and monitor.leader_present():
            self.leader, self.since = True, now  # its own watchdog runs from here
        if monitor.slots.done_at is not None:
            self.done_at = now if self.done_at is None else self.done_at
            missing = sorted(set(range(monitor.slots.first, self.trials)) - set(monitor.rows))
            if missing and now - self.done_at > self.after_done:
                return (f"the leader is done, but the metrics of {trial_ranges(missing)} "
                        f"never came: a robot's trajectory was lost on its way to the "
                        f"launcher; {len(metrics_rows(self.out))} trials are in "
                        f"metrics.csv; the learning itself is complete (state/)")
        mark = (len(monitor.events), len(monitor.rows), count)
        if mark != self.mark:
            self.mark, self.since = mark, now
            return None
        limit = self.limit if self.leader else self.first
        if now - self.since <= limit:
            return None
        who = ("no word from the leader's watchdog" if self.leader
               else "the leader has not started")
        return (f"no progress for {limit:.0f} s and {who} (last events: "
                f"{[e.get('event') for e in monitor.events[-3:]]}); "
                f"{len(metrics_rows(self.out))} trials are in metrics.csv; to go on: "
                f"{resume_hint(self.out)}")


def live_line(host: str, port: int) -> str:
    """Where the live view serves (``--live``): the address a viewer opens."""
    if host in ("0.0.0.0", "::", ""):
        import socket

        return (f"live view: ws://{socket.gethostname()}:{port} (serving on every address "
                f"of this machine; open it in Foxglove: docs/ros-tools.md)")
    shown = f"[{host}]" if ":" in host else host
    return f"live view: ws://{shown}:{port} (open it in Foxglove: docs/ros-tools.md)"


def legend_line(plan: RunPlan) -> str:
    """The line under the header that says how to read each trial's line."""
    text = ("each trial: its number (from 0, as in metrics.csv, the table and the plots) and "
            "its largest error over robots and time; ")
    if plan.true_state:
        return text + ("'measured': of the poses the robots are given (what they learn "
                       "from, noise and delays included); 'true': of where the plant really "
                       "has them")
    return text + "of the poses the robots are given (what they learn from)"


def progress_line(k: int, plan: RunPlan, row: np.ndarray) -> str:
    """A trial's line on the console: its measured errors; where the plant knows the
    ground truth (the simulator, the physics plant) the true errors beside them; what
    the safety filter changed and the contacts, when the run has them."""
    from formation_ilc.core.metrics import METRIC_COLUMNS

    col = {c: row[i] for i, c in enumerate(METRIC_COLUMNS)}
    line = f"trial {k} of 0..{plan.scenario.trials - 1}  max position "
    if plan.true_state:
        line += (f"{col['true_max_position_error']:.4g} m true, "
                 f"{col['max_position_error']:.4g} m measured  max heading "
                 f"{col['true_max_heading_error']:.4g} rad true, "
                 f"{col['max_heading_error']:.4g} measured")
    else:
        line += (f"{col['max_position_error']:.4g} m  max heading "
                 f"{col['max_heading_error']:.4g} rad")
    if plan.config.safety is not None:
        f = col["filter_active"]
        line += "  filtered " + ("?" if np.isnan(f) else f"{int(f)}")
    if plan.physics is not None and not np.isnan(col["contacts"]):
        line += f"  contacts {int(col['contacts'])}"
    return line
