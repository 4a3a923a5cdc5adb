"""A node's diagnostics as standard statuses: OK, WARN or ERROR by documented thresholds,
and its fields as key/value pairs, without loss (free of ROS; msgs_schema packs them into
``diagnostic_msgs/DiagnosticArray``).

Each node's report (the dict it always made: ``node``, ``trial``, counters, histograms) is
one status named after the node; its fields are flattened to pairs, nested keys joined by
``.`` and every value JSON text (``unflatten`` gives the report back). The plant adds one
status per robot (``robot_sim: robot_2``, hardware ``robot_2``) with that robot's missed
samples, so a robot that cannot speak for itself (stopped, crashed) still turns WARN.

Thresholds (docs/ros-tools.md lists them for users):

* missed samples in the trial (a robot's own count since start, the plant's per robot in
  the trial, a bridge's): any is WARN; more than ``MISSED_ERROR`` of the trial's samples
  is ERROR.
* dropped messages: ``malformed`` or ``foreign`` (junk, another run on the domain) are WARN;
  the other reasons (stale, duplicate, out of order, future, unexpected) are how the
  protocol rejects re-sends and restarts, counted and OK.
* late links (realtime: a robot commanded without every link; the link emulator delivered
  after its deadline): WARN.
* measured delay percentiles (the plant's command latency after the tick, realtime): p99
  above ``LATENCY_WARN`` dT is WARN, above dT ERROR (a command missed its sample).
* command clipping and return time-outs of a bridge: WARN.
* the leader's watchdog finding (a phase past its bound): WARN.
* contact between robots, or a robot tipped (a plant with bodies): ERROR; contacts in the
  trial's report: WARN (the run acted on them).
* commands the safety filter changed (a robot's ``filter``): OK, it is doing its work;
  a sample outside the filter's guarantee (``infeasible``: a pair already past braking
  apart, or no command in the limits kept every barrier): WARN; so are samples it braked
  or flagged on another robot's pose more than a sample old (``late``: the filter widens
  its distance by the age, so a late machine or network holds robots apart, and learning
  stalls).
* clocks (a robot's or a bridge's ``clock``, ``protocol.timesync``): an estimate not
  converged 20 s after the first exchange, a clock that stepped, a peer silent for 10 s:
  WARN.
"""

from __future__ import annotations

import json
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from formation_ilc.core.clock import Malformed
from formation_ilc.core.names import (
    BASES_NODE,
    BRIDGE_PREFIX,
    LEADER_NODE,
    LINKS_NODE,
    LIVEVIEW_NODE,
    MONITOR_NODE,
    PHYSICS_NODE,
    RECORDER_NODE,
    ROBOT_PREFIX,
    SIM_NODE,
)

__all__ = ["OK", "WARN", "ERROR", "Status", "flatten", "unflatten", "assess", "statuses",
           "TASKS", "task_name", "plain_value", "hardware_of",
           "MISSED_ERROR", "LATENCY_WARN", "WARN_DROPS", "DIAG_STATUS_MAX", "DIAG_VALUES_MAX",
           "read_statuses", "node_report", "filter_warnings", "FILTER_WINDOW"]

OK, WARN, ERROR = 0, 1, 2
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR"}
#: the share of a trial's samples missed above which a status is ERROR
MISSED_ERROR = 0.10
#: [dT] the p99 command latency above which the plant's status is WARN
LATENCY_WARN = 0.5
#: drop reasons that turn a status to WARN
WARN_DROPS = ("malformed", "foreign")
_SEP = "."
#: the most statuses and key/value pairs a diagnostics message may carry to be read
DIAG_STATUS_MAX = 1024
DIAG_VALUES_MAX = 100_000


@dataclass
class Status:
    """One status: level, name, summary, hardware and the fields (a report, nested)."""

    level: int
    name: str
    message: str
    hardware_id: str = ""
    values: dict[str, Any] = field(default_factory=dict)


def flatten(d: Mapping[str, Any], prefix: str = "") -> list[tuple[str, str]]:
    """Key/value text pairs of a nested report: keys joined by '.', values JSON (an empty
    mapping is kept as ``{}``)."""
    out: list[tuple[str, str]] = []
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping) and v:
            out += flatten(v, key + _SEP)
        else:
            out.append((key, json.dumps(v, separators=(",", ":"))))
    return out


#: the task each node's own status stands for (``node: task`` on the standard stream, as
#: diagnostic_updater names a status)
TASKS = {LEADER_NODE: "schedule", SIM_NODE: "plant", PHYSICS_NODE: "plant",
         LINKS_NODE: "links", RECORDER_NODE: "recording", BASES_NODE: "bases",
         MONITOR_NODE: "monitor", LIVEVIEW_NODE: "live view"}


def task_name(node: str) -> str:
    """The standard status name of ``node``'s own report: ``robot_2: learner``,
    ``bridge_1: bridge``, ``virtual_leader: schedule``."""
    for prefix, task in ((ROBOT_PREFIX, "learner"), (BRIDGE_PREFIX, "bridge")):
        if node.startswith(prefix) and node[len(prefix):].isdigit():
            return f"{node}: {task}"
    return f"{node}: {TASKS.get(node, 'report')}"


def hardware_of(node: str, host: str) -> str:
    """The hardware a node's status is about: its robot (``robot_i`` for robot i's learner
    and bridge), else the host it runs on."""
    for prefix in (ROBOT_PREFIX, BRIDGE_PREFIX):
        digits = node[len(prefix):]
        if node.startswith(prefix) and digits.isdigit():
            return f"{ROBOT_PREFIX}{digits}"
    return host


def plain_value(text: str) -> str:
    """A key/value pair's value as ROS tools show it: a JSON string without its quotes, any
    other value (number, true, list) as its JSON text."""
    try:
        v = json.loads(text)
    except ValueError:
        return text
    return v if isinstance(v, str) else text


def unflatten(pairs: Iterable[tuple[str, str]]) -> dict[str, Any]:
    """The report of ``flatten``'s pairs; ValueError for a value that is not JSON or two
    pairs that disagree on a key's nesting."""
    out: dict[str, Any] = {}
    for key, text in pairs:
        value = json.loads(text)
        *path, last = key.split(_SEP)
        node = out
        for part in path:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"key {key!r} nests under a value")
        if isinstance(node.get(last), dict) and node[last]:
            raise ValueError(f"key {key!r} is also a mapping")
        node[last] = value
    return out


def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else 0.0


def _missed(count: float, samples: int | None, who: str) -> tuple[int, str] | None:
    if count <= 0:
        return None
    if samples and count > MISSED_ERROR * samples:
        return ERROR, f"{who}{count:g} samples missed (> {MISSED_ERROR:.0%} of {samples})"
    return WARN, f"{who}{count:g} samples missed"


def assess(d: Mapping[str, Any], dt: float | None = None, samples: int | None = None
           ) -> tuple[int, str]:
    """The level of a node's report and why (the worst finding), by the thresholds above;
    ``dt`` [s] and ``samples`` (per trial) make the relative ones."""
    found: list[tuple[int, str]] = []
    missed = d.get("missed")
    if isinstance(missed, Mapping):
        total = sum(_num(v) for v in missed.values())
        worst = max((_num(v) for v in missed.values()), default=0.0)
        hit = _missed(worst, samples, "")
        if hit is not None:
            who = ", ".join(f"{k} {_num(v):g}" for k, v in missed.items() if _num(v) > 0)
            found.append((hit[0], f"{total:g} samples missed ({who})"))
    else:
        hit = _missed(_num(missed), None, "")
        if hit is not None:
            found.append(hit)
    dropped = d.get("dropped")
    for reason in WARN_DROPS:
        n = _num(dropped.get(reason)) if isinstance(dropped, Mapping) else 0.0
        if n > 0:
            found.append((WARN, f"{n:g} {reason} messages dropped"))
    late = d.get("late")
    late_n = sum(_num(v) for v in late.values()) if isinstance(late, Mapping) else 0.0
    if late_n > 0:
        found.append((WARN, f"{late_n:g} late links"))
    timing = d.get("timing")
    if isinstance(timing, Mapping) and dt and "commands" in timing:
        p99 = _num(timing.get("p99_ms")) / 1e3
        if p99 > dt:
            found.append((ERROR, f"command latency p99 {p99 * 1e3:.0f} ms > dT"))
        elif p99 > LATENCY_WARN * dt:
            found.append((WARN, f"command latency p99 {p99 * 1e3:.0f} ms > "
                                f"{LATENCY_WARN:g} dT"))
    for key, what in (("clipped", "commands clipped"), ("return_timeouts", "return time-outs")):
        if _num(d.get(key)) > 0:
            found.append((WARN, f"{_num(d.get(key)):g} {what}"))
    wd = d.get("watchdog")
    if isinstance(wd, Mapping) and _num(wd.get("count")) > 0:
        found.append((WARN, f"watchdog: {str(wd.get('what', ''))[:200]}"))
    contact = d.get("contact")
    if isinstance(contact, Mapping):
        found.append((ERROR, f"contact: {str(contact.get('line', ''))[:200]}"))
    report = d.get("contact_report")
    if isinstance(report, Mapping) and isinstance(report.get("pairs"), list) \
            and report["pairs"]:
        found.append((WARN, f"{len(report['pairs'])} pairs of robots touched in the trial"))
    filt = d.get("filter")
    if isinstance(filt, Mapping) and _num(filt.get("infeasible")) > 0:
        found.append((WARN, f"safety filter: {_num(filt.get('infeasible')):g} samples outside "
                            f"its guarantee (a pair already past braking apart, or no "
                            f"command in the limits kept every barrier)"))
    if isinstance(filt, Mapping) and _num(filt.get("late")) > 0:
        found.append((WARN, f"safety filter: {_num(filt.get('late')):g} samples braked or "
                            f"flagged on poses more than a sample old (up to "
                            f"{_num(filt.get('late_ms')):g} ms): it widens its distance by "
                            f"the other robot's speed x age, so a late machine or network "
                            f"holds robots apart and slows their learning"))
    clock = d.get("clock")
    warn = clock.get("warn") if isinstance(clock, Mapping) else None
    if isinstance(warn, list) and warn:
        found.append((WARN, f"clock: {'; '.join(str(w)[:100] for w in warn[:4])}"))
    if not found:
        return OK, "ok"
    level = max(lv for lv, _ in found)
    return level, "; ".join(m for lv, m in found if lv == level)


def statuses(d: Mapping[str, Any], dt: float | None = None, samples: int | None = None,
             hardware_id: str = "") -> list[Status]:
    """The statuses of one node's report: the node's own, and the plant's one per robot."""
    name = str(d.get("node", "?"))
    level, message = assess(d, dt, samples)
    out = [Status(level, name, message, hardware_id, dict(d))]
    missed = d.get("missed")
    if isinstance(missed, Mapping):
        for robot, count in missed.items():
            hit = _missed(_num(count), samples, "")
            lv, msg = hit if hit is not None else (OK, "ok")
            out.append(Status(lv, f"{name}: {robot}", msg, str(robot),
                              {"robot": robot, "trial": d.get("trial"), "missed": count}))
    return out


#: one status as a message carries it: (level, name, message, hardware_id, [(key, value)])
StatusFields = tuple[int, str, str, str, Collection[tuple[str, str]]]


def read_statuses(rows: Collection[StatusFields]) -> list[Status]:
    """Every status of a diagnostics message (``rows`` as the message carries them) with its
    fields back; Malformed if one's values are not the pairs ``flatten`` writes, or there
    are too many (counted before a pair is read). ``msgs_schema.msg_to_statuses`` reads a
    message object with it, ``recordings`` the bytes (``wire.read_diagnostics``)."""
    if len(rows) > DIAG_STATUS_MAX:
        raise Malformed(f"{len(rows)} statuses in one diagnostics message")
    out = []
    for level, name, message, hardware_id, pairs in rows:
        if len(pairs) > DIAG_VALUES_MAX:
            raise Malformed(f"{len(pairs)} values in one status")
        try:
            values = unflatten(pairs)
        except (ValueError, RecursionError) as exc:
            raise Malformed(f"status {name[:100]!r}: {exc}"[:200]) from None
        out.append(Status(level, name, message, hardware_id, values))
    return out


def node_report(found: Sequence[Status], required: Sequence[str] = ()) -> dict[str, Any]:
    """The node's own report among a message's statuses (the status that names its
    ``node``); Malformed if there is none or it lacks a key of ``required``."""
    for st in found:
        if "node" in st.values:
            missing = [k for k in required if k not in st.values]
            if missing:
                raise Malformed(f"diagnostics lack {missing}")
            return st.values
    raise Malformed("diagnostics without a node's report")


#: trials compared at each end of a run by ``filter_warnings``
FILTER_WINDOW = 10


def filter_warnings(changed: Sequence[float], totals: Mapping[str, Any],
                    commands_per_trial: int) -> list[str]:
    """The console's warnings on a run's safety filter, the causes of a stall a person
    should see without reading ``/diagnostics``: ``changed`` the commands it changed in
    each trial (``metrics.csv``'s filter_active), ``totals`` every robot's ``filter_total``
    (its counts over the run; None for one that never reported), ``commands_per_trial``
    robots x samples.

    * it kept acting: over the last FILTER_WINDOW trials (half the run, if shorter) it
      changed more than half as many commands a trial as over the first, and more than
      one in 200: learning through a filter that keeps acting is held back;
    * samples outside its guarantee (``infeasible``), on poses more than a sample old
      (``late``), or without another robot's told command (``untold``), by robot."""
    out = []
    k = len(changed)
    w = min(FILTER_WINDOW, k // 2)
    if w >= 1:
        first = sum(changed[:w]) / w
        last = sum(changed[-w:]) / w
        if last > 0.5 * first and last > commands_per_trial / 200:
            limits = sum(int(t.get("limits", 0) or 0) for t in totals.values()
                         if isinstance(t, Mapping))
            barrier = sum(int(t.get("barrier", 0) or 0) for t in totals.values()
                          if isinstance(t, Mapping))
            if limits > 4 * barrier:
                cause = (f"mostly the bases' limits clipping the learned command ({limits} "
                       f"changes of the run; a barrier moved {barrier}): a learned command "
                       f"rougher than the base can follow, as the law learns the poses' "
                       f"noise (docs/safety.md, \"Noise, and the limits\")")
            else:
                cause = ("the robots are held near its bounds and learn slowly; "
                       "`formation-ilc check` says whether the desired motion itself fits "
                       "(noisy poses, speeds, spacing: docs/safety.md)")
            out.append(f"warning: the safety filter kept acting: {last:.0f} commands a "
                       f"trial over the last {w} trials against {first:.0f} over the first "
                       f"(of {commands_per_trial}): {cause}")
    why = {"infeasible": "outside its guarantee (a pair already past braking apart as it "
                         "counts)",
           "late": "acted on another robot's pose more than a sample old (a loaded machine "
                   "or a slow network holds robots apart)",
           "untold": "filtered against a robot whose told command was not in (its speed "
                     "estimated from its poses)",
           "box_missed": "found a robot off the position its told commands allow (a pose "
                         "outside its estimate's bounds: slip, a push, a pose source noisier "
                         "than the run says)"}
    for key, text in why.items():
        by = {r: int(t.get(key, 0) or 0) for r, t in sorted(totals.items())
              if isinstance(t, Mapping)}
        by = {r: c for r, c in by.items() if c > 0}
        if by:
            each = ", ".join(f"{r} {c}" for r, c in by.items())
            out.append(f"warning: samples the safety filter {text}: {each}")
    return out
