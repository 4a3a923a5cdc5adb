"""Monitor node of the launcher: per-trial metrics from the wire, diagnostics, progress.

Trajectories are labelled with their slot; the leader's ``start`` events say which
iteration a slot runs, and an ``abort`` drops a slot (``formation_ilc.protocol.schedule``). Rows are
keyed by iteration; iterations below ``first`` (already in a resumed run's metrics.csv) are
not reported again.

It reads each robot's whole-trial measured trajectory (``trajectory``, the same message its
neighbours learn from) and, when the plant publishes them (``true_state``), its true
trajectories, and computes the metrics row with ``formation_ilc.model.simulate.trial_errors``
(metrics are defined once, in the core). Without a true state the ``true_`` columns are
nan: a hardware plant has no ground truth.

What it takes (the rest is dropped and counted, with the reason, in ``drops``): trial
events the leader sealed with the run key (``protocol.schedule.seal``; any other writer's
are ``foreign``: the graph names the writers, ``foreign_writers``), in the leader's order
(start k+1 after start k, with the iteration the schedule runs there; end of the trial
started; done);
trajectories of a trial the leader has started and whose row is not complete, once per
robot; diagnostics from the writer of the node they name (``protocol.writers``: a report in
another node's name is ``forged``, counted by sender) whose fields are what the launcher
reads (``formation_ilc.core.links.check_diagnostics``), of a trial started, never older than
the node's last.

A report whose writer the graph does not name yet is held until it does (``nodes.writers``):
held past its trial's trajectories, its counts would miss that trial's row. So the monitor
says ready (and the first trial starts) only once the graph names a diagnostics writer of
every node of ``report_writers`` (the roster's), or ``NAMES_WAIT`` seconds after everything
else it waits for is there; and before it takes a trajectory it takes the reports that
wait in rcl (a robot reports before it sends its trajectory, but the executor may run the
trajectory's callback first).
"""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Path
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.core.clock import Rejected
from formation_ilc.core.links import check_diagnostics, check_for_run
from formation_ilc.core.text import printable, printable_tree
from formation_ilc.model.simulate import Problem
from formation_ilc.nodes.common import DropCounter, GuardedNode, RunConfig
from formation_ilc.nodes.writers import REFRESH_TRIAL
from formation_ilc.protocol.schedule import Ready, TrialEvent, sealed
from formation_ilc.protocol.trialrows import Row, SlotRows

#: [s] how long the monitor's ready waits for the graph to name the report writers, once
#: everything else it waits for is there (a node the graph lost the name of for good,
#: dropped on its lease and found again, must not hold the run)
NAMES_WAIT = 20.0


class MonitorNode(GuardedNode):
    """Collects trial k's trajectories; calls ``on_trial(k, row)`` when all are in.
    ``contacts_from``: the nodes that watch the run's bodies and report contacts (the
    physics plant, the physics bases; empty: no contact report is this run's).
    ``report_writers``: the nodes whose diagnostics writers the graph must name before the
    monitor says ready (the roster's ``report_writers``; empty: no wait).
    ``trajectory_writers``: a trajectory topic (relative) -> the nodes that alone write it
    (the roster's ``trajectory_writers``): a trajectory from any other writer is refused
    and counted as ``forged``; a topic not in it is taken from any writer."""

    def __init__(self, cfg: RunConfig, on_trial: Callable[[int, np.ndarray], None], *,
                 true_state: bool = True, first: int = 0,
                 on_contact: Callable[[str, dict[str, Any]], None] | None = None,
                 on_clock: Callable[[str, str, str], None] | None = None,
                 key: bytes | None = None, contacts_from: tuple[str, ...] = (),
                 report_writers: tuple[str, ...] = (),
                 trajectory_writers: dict[str, tuple[str, ...]] | None = None, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__(ms.MONITOR_NODE, **kwargs)
        self.cfg = cfg
        self.contacts_from = contacts_from
        self.report_writers = tuple(w for w in report_writers if w != ms.MONITOR_NODE)
        #: when the rest of the ready gate held first (the names' wait starts), or None
        self._names_from: float | None = None
        self.pb = Problem.from_scenario(cfg.scenario)
        self.clock = cfg.clock
        self.on_trial = on_trial
        self.true_state = true_state
        self.drops = DropCounter(self)
        n = self.pb.n
        # the rows, by iteration (with the counts the robots' filters and the plant report)
        # only the leader's sealed events count (``key``: the run's, from the launcher)
        self.slots = SlotRows(self.pb, true_state, first, safety=cfg.safety is not None,
                              key=key)
        self.slots.run = cfg.run_id
        self.on_contact = on_contact
        self.contacts_seen: set[tuple[str, int, int, int]] = set()
        #: a node's clock words (the last of each) and the events of them already said
        self.on_clock = on_clock
        self.clock_words: dict[str, dict[str, Any]] = {}
        self.clock_seen: set[tuple[str, str]] = set()
        self.rows = self.slots.rows
        self.diagnostics: dict[str, dict[str, Any]] = {}
        self.events: list[dict[str, Any]] = []
        #: writers of the trial events besides the leader, by node (from the graph)
        self.foreign_seen: set[str] = set()
        self._writers_at = -1e9
        self.path_subs: list[Any] = []
        owners = trajectory_writers or {}
        for r in range(n):
            for true in (False, True) if true_state else (False,):
                topic = (ms.true_trajectory_topic if true else ms.trajectory_topic)(r + 1)
                # raw: a trajectory longer than a trial is refused before it is
                # deserialized; from its writers only where the roster names them (a
                # forged trajectory taken first would be a row of metrics.csv)
                if owners.get(topic):
                    sub = self.checked_subscription(
                        Path, topic, lambda m, gid, r=r, true=true: self._on_traj(m, r, true),
                        ms.TRAJECTORY_READER_QOS, raw=True, owners=owners[topic],
                        poll=REFRESH_TRIAL)
                else:
                    sub = self.create_subscription(
                        Path, topic, lambda m, r=r, true=true: self._on_traj(m, r, true),
                        ms.TRAJECTORY_READER_QOS, raw=True)
                self.path_subs.append(sub)
        # the schedule waits for the monitor too ("monitor" in the leader's nodes_expected):
        # a writer's match count cannot tell a monitor from a recorder, and a monitor matched
        # after trial 1 would miss trial 0 (trajectories are latched 2 deep)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self.boot = f"{os.getpid()}"
        self.said_ready = False
        #: the last ready of each node (the launcher names whom a stuck run waits for)
        self.readies: dict[str, Ready] = {}
        # every report and ready from the node it names (protocol.writers), a report then
        # checked field by field (core.links)
        self.diag_sub = self.checked_subscription(DiagnosticArray, ms.DIAGNOSTICS,
                                                  self._on_diag_from, ms.LATCHED_READER_QOS,
                                                  shared=True)
        self.checked_readies(self._on_ready)
        self._gate = self.create_timer(0.05, self._check_ready)
        self.events_sub = self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event,
                                                   ms.SAMPLE_QOS)

    def _check_ready(self) -> None:
        if not (all(s.get_publisher_count() >= 1 for s in self.path_subs)
                and self.ready_pub.get_subscription_count() >= 1):
            return
        now = time.monotonic()
        if self._names_from is None:
            self._names_from = now
        unnamed = self.unnamed_report_writers()
        if unnamed:
            if now - self._names_from < NAMES_WAIT:
                return
            self.get_logger().warning(
                f"ready without the graph naming the diagnostics writer of "
                f"{', '.join(unnamed[:8])} after {NAMES_WAIT:g} s: a first report of theirs "
                f"is held until it does")
        self._gate.cancel()
        self.said_ready = True
        self.ready_pub.publish(self._ready_msg())

    def unnamed_report_writers(self) -> list[str]:
        """The nodes of ``report_writers`` of which the graph names no diagnostics writer
        yet (asked again at most every ``protocol.writers.REFRESH`` seconds)."""
        if not self.report_writers:
            return []
        self.diag_sub.learn_writers()
        return self.writers.not_named(self.diag_sub.topic_name, self.report_writers)

    def _ready_msg(self) -> String:
        return ms.json_to_msg({"node": ms.MONITOR_NODE, "passive": True,
                               "trial": self.cfg.scenario.trials, "boot": self.boot,
                               "run": self.cfg.run_id})

    def _on_ready(self, msg: String) -> None:
        """Readies of every node: who is there (``readies``, for the launcher's watchdog);
        a ``down`` naming this live monitor is refuted by saying ready again (the leader
        would otherwise wait for a monitor that has said all it will say)."""
        try:
            r = Ready.from_json(ms.msg_to_json(msg))
        except Rejected as exc:
            self.drops.reject(exc, ms.READY)
            return
        # the launcher names whom a run waits for: a node's name reaches the console
        r = dataclasses.replace(r, node=printable(r.node, 200))
        if r.run and r.run != self.cfg.run_id:
            return
        if r.down and r.node == ms.MONITOR_NODE and r.boot == self.boot and self.said_ready:
            self.drops.drop("unexpected", ms.READY, f"'down' of this live monitor ({r.boot})")
            self.ready_pub.publish(self._ready_msg())
            return
        if r.node in self.readies or len(self.readies) < 256:  # a flood of names: bounded
            self.readies[r.node] = r

    def _foreign_writers(self) -> None:
        """Note the writers of the trial events other than the leader, by node, as the
        graph names them when an unsealed event comes (DDS names no writer per sample:
        ``protocol.schedule``), at most once a second."""
        now = time.monotonic()
        if now - self._writers_at < 1.0 or len(self.foreign_seen) >= 16:
            return
        self._writers_at = now
        ns = self.get_namespace()
        for i in self.get_publishers_info_by_topic(self.events_sub.topic_name):
            if not (i.node_name == ms.LEADER_NODE and i.node_namespace == ns):
                self.foreign_seen.add(f"{i.node_namespace.rstrip('/')}/{i.node_name}")

    def report(self) -> dict[str, Any]:
        """The monitor's own report for diagnostics.json: the trial events it refused as
        foreign, and the other writers of the topic it saw."""
        return {"node": ms.MONITOR_NODE,
                "foreign_events": int(self.drops.by_topic[f"foreign:{ms.TRIAL_EVENTS}"]),
                "foreign_writers": sorted(self.foreign_seen),
                "forged": self.writers.report()}

    def forged_reports(self) -> dict[str, Any]:
        """Every node's ``forged`` counts as its last report says, and the monitor's own."""
        out = {n: d.get("forged") for n, d in self.diagnostics.items() if d.get("forged")}
        out[ms.MONITOR_NODE] = self.writers.report()
        return out

    def leader_present(self) -> bool:
        """Whether a writer of the trial events (the leader) has been discovered."""
        return bool(self.events_sub.get_publisher_count() >= 1)

    def _on_traj(self, data: bytes | Path, r: int, true: bool) -> None:
        # a robot reports its slot's counts before it sends its trajectory: the reports
        # that wait are taken first, whatever order the executor runs the callbacks in
        self.diag_sub.take_waiting()
        topic = (ms.true_trajectory_topic if true else ms.trajectory_topic)(r + 1)
        try:
            k, eta, _ = ms.trial_trajectory(data, self.clock, self.pb.eta_d[r, :, 2])
            done = self.slots.trajectory(k, r, true, eta)
        except Rejected as exc:
            self.drops.reject(exc, topic)
            return
        self._report(done)

    def _report(self, done: list[Row]) -> None:
        for d in done:
            self.on_trial(d.trial, d.row)

    def _on_diag_from(self, msg: DiagnosticArray, gid: bytes) -> None:
        """A report, taken only from the writer (``gid``) of the node it names (else
        ``forged``, counted by sender); then checked field by field (``_take_report``)."""
        report = self._report_of(msg)
        if report is not None and self.from_named_writer(ms.DIAGNOSTICS, gid,
                                                         report.get("node")):
            self._take_report(report)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        """A report, its writer not asked (the handler the tests feed directly)."""
        report = self._report_of(msg)
        if report is not None:
            self._take_report(report)

    def _report_of(self, msg: DiagnosticArray) -> dict[str, Any] | None:
        """The report's JSON, or None (dropped and counted) when it does not decode."""
        try:
            return ms.msg_to_report(msg, ("node", "trial"))
        except Rejected as exc:
            self.drops.reject(exc, ms.DIAGNOSTICS)
            return None

    def _take_report(self, report: dict[str, Any]) -> None:
        """A report (from the writer of the node it names): checked field by field."""
        try:
            d = check_diagnostics(report)
            check_for_run(d, self.cfg.scenario.trials, self.contacts_from)
            # every text in it may reach the console (contact lines, clock words, names)
            d = printable_tree(d)
            name, k = d["node"], d["trial"]
            if "waiting" in d:  # a node not ready yet, for the leader's watchdog: no report
                return
            if name == "virtual_leader":
                # the leader's own word (its watchdog's findings too, before trial 0 and
                # after it un-commits a trial): the launcher prints it
                self.diagnostics[name] = d
                return
            if k > self.slots.started:
                raise Rejected("future", f"{name[:100]} diagnostics of trial {k}, slot "
                                         f"{self.slots.started} started")
            if k < self.diagnostics.get(name, {}).get("trial", k):
                raise Rejected("stale", f"{name[:100]} diagnostics of trial {k} after "
                                        f"{self.diagnostics[name]['trial']}")
        except Rejected as exc:
            self.drops.reject(exc, ms.DIAGNOSTICS)
            return
        self.slots.note_diagnostics(d)
        if "clock_word" in d:  # where a node's clock estimates are, between its reports
            self.clock_words[name] = d
            for level, text in d["clock_word"].get("events", []):
                if (name, text) not in self.clock_seen:  # said once
                    self.clock_seen.add((name, text))
                    if self.on_clock is not None:
                        self.on_clock(name, level, text)
            return
        if "contact" in d and isinstance(d["contact"], dict):
            c = d["contact"]
            # every event once (a plant numbers them: ``n``; an older plant said one a slot)
            key = (name, int(d["trial"]), int(c.get("slot", -1)), int(c.get("n", 0) or 0))
            if key not in self.contacts_seen:  # said at once, once
                self.contacts_seen.add(key)
                if self.on_contact is not None:
                    self.on_contact(name, {**c, "trial": int(d["trial"])})
            return  # a mid-trial word, not the node's report
        self.diagnostics[name] = d

    def _on_event(self, msg: String) -> None:
        try:
            d = ms.msg_to_json(msg)
            ev = TrialEvent.from_json(d)
            if ev.run and ev.run != self.cfg.run_id:
                raise Rejected("foreign", f"event of run {ev.run}")
            if not sealed(ev, self.slots.key):
                self._foreign_writers()
                raise Rejected("foreign", f"{ev.event} of slot {ev.slot} (seq {ev.seq}) not "
                                          f"sealed by this run's leader")
            if self.slots.repeat(ev):
                return  # not progress: the launcher's backstop counts the events
            ev.agree(self.clock)
            done = self.slots.event(ev)
        except Rejected as exc:
            self.drops.reject(exc, ms.TRIAL_EVENTS)
            return
        self.events.append(d)
        self._report(done)
