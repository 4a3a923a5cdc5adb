"""The report writer of a launch: what a finished (or stopped) run leaves behind.

From a ``RunPlan`` and what the run gathered (metrics rows, the nodes' last diagnostics,
restarts), it writes DIR/diagnostics.json, DIR/delays.csv (per-link delay histograms:
measured by the robots with eq. 11, injected by the emulated links, and the model's) and
DIR/summary.json whatever the outcome; after a run that succeeded also DIR/errors.png and
the printed report (per-trial errors, timing, delays, dropped messages). No ROS here.
"""

from __future__ import annotations

import json
import math
import re
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from formation_ilc.cli.supervisor import disk_full_line
from formation_ilc.config.scenario import Scenario
from formation_ilc.core.links import (
    delay_rows,
    link_clocks,
    link_histograms,
    write_delays,
)
from formation_ilc.core.names import BASES_NODE, MONITOR_NODE, SIM_NODE
from formation_ilc.core.text import printable
from formation_ilc.plan.specs import RunPlan
from formation_ilc.protocol.health import filter_warnings
from formation_ilc.protocol.writers import forged_line
from formation_ilc.system.exits import DISK_FULL, is_disk_full

__all__ = ["write_report", "summary_of", "print_report", "log_warnings"]

#: a bridge's diagnostics that go into summary.json
BRIDGE_KEYS = ("initial_shifts", "returns", "return_timeouts", "missed", "clipped",
               "clipped_accel", "tilt_max_deg", "limits", "watchdog_zero", "stale_odometry")
#: the physics plant's diagnostics that go into summary.json
PHYSICS_KEYS = ("model", "pose_source", "substeps", "contacts_by_trial", "tilt_by_trial",
                "odometry_drift_by_trial", "limited")
#: the physics bases' diagnostics (``--physics-bases``) that go into summary.json
BASES_KEYS = ("contacts_by_trial", "return_contacts_by_trial", "tilt_by_trial",
              "contact_events", "odometry_drift", "commands_max")


def summary_of(plan: RunPlan, rows: int, diagnostics: Mapping[str, Mapping[str, Any]],
               restarts: Mapping[str, int], seconds: float,
               startup: Mapping[str, float | None] | None = None,
               ending_contact: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """summary.json of a run of ``plan`` that finished ``rows`` trials in ``seconds``;
    ``startup``: when the launcher found every node, saw every ready, saw the first start
    (seconds from its start); ``ending_contact``: the contact or tilt that ended the run
    (its plant's words: trial, slot, phase, line, action, pairs, tilt)."""
    sc, cfg = plan.scenario, plan.config
    # the plant node's timing and missed samples (the simulator, the physics plant)
    sim_diag = diagnostics.get(plan.team.plants[0] if plan.row.true_state else SIM_NODE, {})
    summary: dict[str, Any] = {
        "scenario": sc.name, "robots": sc.n, "trials_done": rows, "trials": sc.trials,
        "mode": cfg.mode, "links": cfg.links, "plant": list(plan.team.plants),
        "true_state": plan.true_state, "namespace": plan.namespace,
        "container": plan.container, "domain_id": plan.domain, "seconds": seconds,
        "run_id": cfg.run_id, "resumed_at": plan.resumed_at, "restarts": dict(restarts),
        "timing": sim_diag.get("timing", {}), "missed": sim_diag.get("missed", {}),
        "dropped": {n: d.get("dropped", {}) for n, d in diagnostics.items()},
        "startup": dict(startup or {})}
    monitor = diagnostics.get(MONITOR_NODE, {})
    forged = forged_line({n: d.get("forged") or {} for n, d in diagnostics.items()})
    if forged:  # messages refused for their writer, by every node (protocol.writers)
        summary["forged"] = {n: d["forged"] for n, d in diagnostics.items() if d.get("forged")}
        summary["forged_line"] = forged
    count = int(monitor.get("foreign_events", 0) or 0)
    if count:  # schedule events of another writer (the monitor sees them all)
        summary["foreign_events"] = {"count": count,
                                     "writers": list(monitor.get("foreign_writers", []))}
    if plan.bridged:
        summary["bridges"] = {b: {key: diagnostics.get(b, {}).get(key) for key in BRIDGE_KEYS}
                              for b in plan.team.plants}
    if plan.row.physics:
        summary["physics"] = {key: sim_diag.get(key) for key in PHYSICS_KEYS}
    elif BASES_NODE in diagnostics or BASES_NODE in plan.team.support:
        # the physics bases of a rehearsal: their contacts and tilts, by trial and return
        bases = diagnostics.get(BASES_NODE, {})
        summary["physics"] = {key: bases.get(key) for key in BASES_KEYS}
    if ending_contact is not None:
        summary["ended_by_contact"] = dict(ending_contact)
    if plan.init_memory is not None:
        summary["init_memory"] = str(plan.init_memory)
    if cfg.clock_exchanges:
        summary["clocks"] = clocks_summary(plan, diagnostics)
    if cfg.safety is not None:
        # the filter's settings, and what it changed over the run, by robot
        summary["safety"] = {**cfg.safety.to_json(), "filter_total": {
            r: diagnostics.get(r, {}).get("filter_total") for r in plan.team.robots}}
    return summary


def clocks_summary(plan: RunPlan, diagnostics: Mapping[str, Mapping[str, Any]]
                   ) -> dict[str, Any]:
    """summary.json's ``clocks``: the settings, the emulated truth (each robot's clock: a
    run can be scored), each link's last estimate and one-way delays, each bridge's
    estimate of the leader's clock and the samples it took on it, and the warnings."""
    cfg = plan.config
    truth = cfg.clocks.truth(cfg.scenario.seed, cfg.scenario.n)
    bridges = {}
    for b in plan.team.plants if plan.bridged else ():
        clock = diagnostics.get(b, {}).get("clock") or {}
        bridges[b] = {**((clock.get("peers") or {}).get("leader") or {}),
                      "sampled_on": clock.get("sampled_on", {}),
                      **({"sample_lag_ms": clock["sample_lag_ms"]}
                         if "sample_lag_ms" in clock else {})}
    return {"settings": cfg.clocks.to_json(),
            "truth": None if truth is None else {
                n: c.to_json() for n, c in truth.items() if n.startswith("robot_")},
            "links": link_clocks(diagnostics), "bridges": bridges,
            "warn": {n: d["clock"]["warn"] for n, d in diagnostics.items()
                     if isinstance(d.get("clock"), Mapping) and d["clock"].get("warn")}}


def write_report(plan: RunPlan, rows: Sequence[Sequence[float]],
                 diagnostics: Mapping[str, Mapping[str, Any]], restarts: Mapping[str, int],
                 seconds: float, status: int,
                 startup: Mapping[str, float | None] | None = None,
                 ending_contact: Mapping[str, Any] | None = None) -> int:
    """Write the run's outputs into ``plan.out``; after a successful run (``status`` 0)
    also the figure and the printed report. Returns ``status``."""
    out = plan.out
    measured, injected = link_histograms(diagnostics)
    emulated = plan.config.links == "emulated"
    clocks = link_clocks(diagnostics)
    dtab = delay_rows(measured, injected if emulated else None,
                      plan.scenario.uncertainty.delay.pmf() if emulated else None, clocks)
    summary = summary_of(plan, len(rows), diagnostics, restarts, seconds, startup,
                         ending_contact)
    try:
        (out / "diagnostics.json").write_text(json.dumps(diagnostics, indent=2) + "\n")
        write_delays(out / "delays.csv", dtab)
        (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        if status == 0:  # else the run's own error line has said it all
            print(f"error: {disk_full_line('the launcher', exc.filename, out)}",
                  file=sys.stderr)
            status = DISK_FULL
    for line in log_warnings(out / "logs"):  # what the nodes said besides their reports
        print(line)
    if status:
        return status
    files = ["metrics.csv", "delays.csv", "diagnostics.json", "summary.json"]
    m = np.array(rows)
    sc = plan.scenario
    print_report(sc, m, dtab, summary)
    if plan.plots and len(rows):
        # a second or two (matplotlib, which on a fresh install first builds its caches)
        print(f"writing {out / 'errors.png'} ...", flush=True)
        from formation_ilc.recordings.plots import plot_errors

        plot_errors(m[:, 0], m[:, 1], m[:, 2], out / "errors.png",
                    f"{sc.name}: distributed stack, {sc.n} robot nodes, {plan.config.mode}")
        files.append("errors.png")
    wrong = contact_warning(plan.predicted_clear, m)
    if wrong is not None:
        print(wrong)
    print(f"results in {out}/ ({', '.join(files)}; logs/)")
    root = plan.record_root or plan.record
    if root is not None:
        print(f"recording: {root} (formation-ilc analyze {root})")
    return 0


#: a ROS log line of a warning or an error: its level, its node (logger) and its text
_LOGGED = re.compile(r"^\[(WARN|ERROR)\] \[[0-9.]+\] \[([^\]]+)\]: (.*)$")
#: the part of a node's log read for warnings (its end: a long run's log is large)
LOG_TAIL = 4 << 20


def log_warnings(log_dir: Path, limit: int = 8) -> list[str]:
    """The nodes' warnings summarised, for the end of a run: a heading, then one line per
    process whose log (``log_dir/NAME.log``) holds ``[WARN]`` or ``[ERROR]`` lines: how
    many, and the one said most often (numbers masked, so that one warning repeated with
    other values counts as one), the processes with the most first, at most ``limit``.
    Empty when no node warned."""
    rows: list[tuple[int, str]] = []
    for log in sorted(log_dir.glob("*.log")) if log_dir.is_dir() else ():
        try:
            with log.open("rb") as fh:
                fh.seek(max(0, log.stat().st_size - LOG_TAIL))
                text = fh.read().decode(errors="replace")
        except OSError:
            continue
        said: Counter[tuple[str, str]] = Counter()
        first: dict[tuple[str, str], str] = {}
        for line in text.splitlines():
            m = _LOGGED.match(line.strip())
            if m is not None:
                key = (m.group(1), re.sub(r"\d+(\.\d+)?", "N", m.group(3)))
                said[key] += 1
                first.setdefault(key, m.group(3))
        if said:
            (level, _), n = top = said.most_common(1)[0]
            total = sum(said.values())
            rows.append((total, f"  {log.stem}: {total} line(s); most often ({n}x, {level}): "
                                f"{printable(first[top[0]], 160)}"))
    if not rows:
        return []
    rows.sort(key=lambda r: -r[0])
    more = f" (and {len(rows) - limit} more)" if len(rows) > limit else ""
    return [f"node warnings{more}, in {log_dir}/NAME.log:", *(r for _, r in rows[:limit])]


def contact_warning(predicted_clear: bool, m: np.ndarray) -> str | None:
    """The line that says the contact prediction was wrong: it predicted none, and the
    metrics rows ``m`` (METRIC_COLUMNS) count contacts; else None."""
    touched = [int(r[0]) for r in m if len(r) > 8 and r[8] > 0] if len(m) else []
    if not (predicted_clear and touched):
        return None
    return (f"warning: the batch simulator predicted no contact, but robots touched in "
            f"trial(s) {', '.join(map(str, touched[:10]))}: the bodies did what its "
            f"kinematic model does not (slip, lag, noise); docs/safety.md")


def print_report(sc: Scenario, m: np.ndarray, dtab: list[list[Any]], summary: dict[str, Any]
                 ) -> None:
    """Per-trial errors (at most about 20 rows), then timing, bridges, delays, drops."""
    k = len(m)
    show = range(k) if k <= 20 else sorted({0, 1, 2, k // 4, k // 2, 3 * k // 4, k - 1})
    # where the plant knows the truth, true and measured side by side; the safety filter's
    # changed commands and the contacts where the run counted them
    truth = k > 0 and bool(np.isfinite(m[:, 3]).any())
    filt = k > 0 and bool(summary.get("safety"))
    contacts = k > 0 and bool(np.isfinite(m[:, 8]).any())
    head = f"{'trial':>6s} {'max pos [m]':>12s}"
    head += f" {'true pos [m]':>13s}" if truth else ""
    head += f" {'max head [rad]':>15s} {'rms pos [m]':>12s}"
    head += f" {'filtered':>9s}" if filt else ""
    head += f" {'contacts':>9s}" if contacts else ""
    print(head)
    for i in show:
        line = f"{int(m[i, 0]):6d} {m[i, 1]:12.4g}"
        line += f" {m[i, 3]:13.4g}" if truth else ""
        line += f" {m[i, 2]:15.4g} {m[i, 5]:12.4g}"
        line += f" {m[i, 7]:9.0f}" if filt else ""
        line += f" {m[i, 8]:9.0f}" if contacts else ""
        print(line)
    _print_timing(sc, summary)
    for b, d in (summary.get("bridges") or {}).items():
        shifts = d.get("initial_shifts") or {}
        worst = max((math.hypot(s[0], s[1]) for s in shifts.values()), default=float("nan"))
        print(f"{b}: {len(shifts)} starts, largest initial shift {worst:.3f} m, return "
              f"timeouts {d.get('return_timeouts')}, missed samples {d.get('missed')}, "
              f"clipped commands {d.get('clipped')}")
    if not summary.get("true_state", True):
        print("true state: the plant publishes none; the true_ columns of metrics.csv are nan")
    if dtab:
        _print_delays(dtab, direct=summary.get("links") == "direct")
    if summary.get("clocks"):
        _print_clocks(summary["clocks"])
    safety = summary.get("safety")
    if safety and k:
        for line in filter_warnings([float(x) for x in m[:, 7]],
                                    safety.get("filter_total") or {}, sc.n * sc.samples):
            print(line)
    drops = {n: sum(d.values()) for n, d in summary["dropped"].items() if sum(d.values())}
    if drops:
        print(f"dropped messages: {drops}")
    if summary.get("forged_line"):
        print(summary["forged_line"])
    foreign = summary.get("foreign_events")
    if foreign:
        print(f"foreign trial events: {foreign['count']} not sealed by this run's leader, "
              f"refused by every node (other writers of the topic: "
              f"{', '.join(foreign['writers']) or 'gone before they were seen'})")


def _print_timing(sc: Scenario, summary: dict[str, Any]) -> None:
    tim = summary.get("timing") or {}
    nan = float("nan")
    if tim and summary.get("mode") == "realtime":
        print(f"realtime: {tim.get('missed_total', 0)} missed of "
              f"{tim.get('commands', 0) + tim.get('missed_total', 0)} robot-samples; command "
              f"arrival after the tick p50 {tim.get('p50_ms', nan):.2f} ms, "
              f"p99 {tim.get('p99_ms', nan):.2f} ms (dT {1000 * sc.dt:.0f} ms)")
    elif tim:
        print(f"lockstep: {tim.get('samples_per_s', nan):.0f} samples/s, per-sample "
              f"latency p50 {tim.get('p50_ms', nan):.2f} ms, "
              f"p99 {tim.get('p99_ms', nan):.2f} ms")


def _print_delays(dtab: list[list[Any]], direct: bool) -> None:
    """The delay histogram of all links together (measured; injected and model too with
    emulated links), as fractions."""
    agg: dict[int, list[float]] = {}
    for _link, tau, meas, inj, _, p, *_ms in dtab:
        a = agg.setdefault(tau, [0, 0, 0 if direct else p])
        a[0] += meas
        a[1] += 0 if direct else inj
    tot = sum(a[0] for a in agg.values()) or 1
    if direct:
        print("delays measured by the robots (eq. 11, all links): tau  measured")
    else:
        print("delays (all links): tau  measured  injected  model")
    for tau, (meas, inj, p) in sorted(agg.items()):
        rest = "" if direct else f" {inj / tot:9.3f} {p:6.3f}"
        print(f"  {tau:4d} {meas / tot:9.3f}{rest}")


def _ms(v: Any, fmt: str = "+.2f") -> str:
    return format(v, fmt) if isinstance(v, (int, float)) else "?"


def _print_clocks(clocks: Mapping[str, Any]) -> None:
    """One line per link: the receiver's estimate of the sender's clock (and the truth in
    an emulated run), the link's one-way delay as the clocks read it, corrected, true;
    one per bridge: its estimate of the leader's clock and what it sampled on."""
    est = clocks.get("settings", {}).get("sync", True)
    print("clocks (the receiver's estimate of the sender's clock; one-way delays since it "
          "converged):" if est else "clocks (estimator off, --no-clock-sync: one-way "
                                    "delays as the clocks read them):")
    for link, c in sorted((clocks.get("links") or {}).items()):
        d = c.get("delay") or {}
        line = f"  {link}:"
        if est and "offset_ms" in c:
            line += (f" offset {_ms(c['offset_ms'], '+.3f')} ms +- "
                     f"{_ms(c.get('uncertainty_ms'), '.3f')}")
            if "true_offset_ms" in c:
                line += f" (true {_ms(c['true_offset_ms'], '+.3f')})"
            line += f", drift {_ms(c.get('drift_ppm'), '+.1f')} ppm;"
        line += f" delay measured {_ms(d.get('measured_ms'))} ms"
        if "corrected_ms" in d:
            line += f", corrected {_ms(d['corrected_ms'])} ms"
        if "injected_ms" in d:
            line += f", true {_ms(d['injected_ms'])} ms"
        if "error_max_ms" in d:
            line += f" (largest error {_ms(d['error_max_ms'], '.3f')} ms)"
        print(line + f" [{d.get('n', 0)} answers]")
    for b, c in sorted((clocks.get("bridges") or {}).items()):
        print(f"  {b}: leader's clock offset {_ms(c.get('offset_ms'), '+.3f')} ms +- "
              f"{_ms(c.get('uncertainty_ms'), '.3f')}"
              + (f" (true {_ms(c['true_offset_ms'], '+.3f')})" if "true_offset_ms" in c
                 else "")
              + f", samples taken on: {c.get('sampled_on') or {}}"
              + (f"; true time of its samples after the leader's instants: p50 "
                 f"{_ms(c['sample_lag_ms'].get('p50'))} ms, "
                 f"{_ms(c['sample_lag_ms'].get('min'))} .. "
                 f"{_ms(c['sample_lag_ms'].get('max'))} ms" if "sample_lag_ms" in c else ""))
    for node, warn in sorted((clocks.get("warn") or {}).items()):
        print(f"  WARN {node}: {'; '.join(warn)}")
