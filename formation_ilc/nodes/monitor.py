"""Monitor node of the launcher: per-trial metrics from the wire, diagnostics, progress.

Trajectories are labelled with their slot; the leader's ``start`` events say which
iteration a slot runs, and an ``abort`` drops a slot (``formation_ilc.schedule``). Rows are
keyed by iteration; iterations below ``first`` (already in a resumed run's metrics.csv) are
not reported again.

It reads each robot's whole-trial measured trajectory (``trajectory``, the same message its
neighbours learn from) and, when the plant publishes them (``true_state``), its true
trajectories, and computes the metrics row with ``formation_ilc.simulate.trial_errors``
(metrics are defined once, in the core). Without a true state the ``true_`` columns are
nan: a hardware plant has no ground truth.

What it takes (the rest is dropped and counted, with the reason, in ``drops``): trial
events in the leader's order (start k+1 after start k, end of the trial started, done);
trajectories of a trial the leader has started and whose row is not complete, once per
robot; diagnostics whose fields are what the launcher reads
(``formation_ilc.links.check_diagnostics``), of a trial started, never older than the
node's last.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

import numpy as np
from nav_msgs.msg import Path
from rclpy.node import Node
from std_msgs.msg import String

import msgs_schema as ms
from formation_ilc.clock import Rejected
from formation_ilc.links import check_diagnostics
from formation_ilc.metrics import METRIC_COLUMNS, TRUE_COLUMNS
from formation_ilc.nodes.common import DropCounter, RunConfig
from formation_ilc.schedule import TrialEvent
from formation_ilc.simulate import Problem, trial_errors


class MonitorNode(Node):
    """Collects trial k's trajectories; calls ``on_trial(k, row)`` when all are in."""

    def __init__(self, cfg: RunConfig, on_trial: Callable[[int, np.ndarray], None],
                 true_state: bool = True, first: int = 0, **kwargs: Any):
        kwargs.setdefault("namespace", ms.NAMESPACE)
        super().__init__("monitor", **kwargs)
        self.cfg = cfg
        self.pb = Problem.from_scenario(cfg.scenario)
        self.clock = cfg.clock
        self.on_trial = on_trial
        self.true_state = true_state
        self.drops = DropCounter(self)
        n = self.pb.n
        self.eta: dict[int, dict[int, np.ndarray]] = {}
        self.xi: dict[int, dict[int, np.ndarray]] = {}
        self.rows: dict[int, np.ndarray] = {}
        self.diagnostics: dict[str, dict[str, Any]] = {}
        self.events: list[dict[str, Any]] = []
        self.first = first
        self.iteration_of: dict[int, int] = {}   # slot -> iteration (start events)
        self.aborted: set[int] = set()
        self.started = -1   # the last slot the leader started
        self.path_subs = []
        for r in range(n):
            self.path_subs.append(self.create_subscription(
                Path, ms.trajectory_topic(r + 1), lambda m, r=r: self._on_traj(m, r, self.eta),
                ms.TRAJECTORY_QOS))
            if true_state:
                self.path_subs.append(self.create_subscription(
                    Path, ms.true_trajectory_topic(r + 1),
                    lambda m, r=r: self._on_traj(m, r, self.xi), ms.TRAJECTORY_QOS))
        # the schedule waits for the monitor too ("monitor" in the leader's nodes_expected):
        # a writer's match count cannot tell a monitor from a recorder, and a monitor matched
        # after trial 1 would miss trial 0 (trajectories are latched 2 deep)
        self.ready_pub = self.create_publisher(String, ms.READY, ms.LATCHED_QOS)
        self._gate = self.create_timer(0.05, self._check_ready)
        self.create_subscription(String, ms.DIAGNOSTICS, self._on_diag, ms.LATCHED_READER_QOS)
        self.create_subscription(String, ms.TRIAL_EVENTS, self._on_event, ms.SAMPLE_QOS)

    def _check_ready(self) -> None:
        if all(s.get_publisher_count() >= 1 for s in self.path_subs) and \
                self.ready_pub.get_subscription_count() >= 1:
            self._gate.cancel()
            self.ready_pub.publish(ms.json_to_msg({"node": "monitor", "passive": True,
                                                   "trial": self.cfg.scenario.trials,
                                                   "boot": f"{os.getpid()}",
                                                   "run": self.cfg.run_id}))

    def _on_traj(self, msg: Path, r: int, store: dict[int, dict[int, np.ndarray]]) -> None:
        topic = (ms.trajectory_topic if store is self.eta else ms.true_trajectory_topic)(r + 1)
        try:
            eta, stamps, frame = ms.path_to_trajectory(msg, self.pb.eta_d[r, :, 2])
            if frame != ms.WORLD_FRAME:
                raise ms.MalformedMessage(f"trajectory in frame {frame[:50]!r}")
            k, s0 = self.clock.decode(int(stamps[0]))
            if s0 != 0 or any(int(x) != self.clock.stamp_ns(k, s)
                              for s, x in enumerate(stamps)):
                raise ms.MalformedMessage("stamps are not samples 0..T of one trial")
            i = self.iteration_of.get(k)
            if k in self.aborted:
                raise Rejected("stale", f"trajectory of slot {k}, aborted")
            if i is not None and i in self.rows:
                raise Rejected("duplicate", f"trial {i} is complete")
            if k > self.started:
                raise Rejected("future", f"trajectory of slot {k}, slot {self.started} "
                                         f"started")
            if r in store.get(k, {}):
                raise Rejected("duplicate", f"slot {k} again")
        except Rejected as exc:
            self.drops.reject(exc, topic)
            return
        store.setdefault(k, {})[r] = eta
        self._complete(k)

    def _complete(self, k: int) -> None:
        """Report slot k's row once its trajectories and its iteration are known."""
        n = self.pb.n
        i = self.iteration_of.get(k)
        if i is None or k in self.aborted:
            return
        if len(self.eta.get(k, {})) == n and (not self.true_state
                                              or len(self.xi.get(k, {})) == n):
            eta_all = np.stack([self.eta[k][i] for i in range(n)])
            xi_all = (np.stack([self.xi[k][i] for i in range(n)]) if self.true_state
                      else eta_all)
            row = np.empty(len(METRIC_COLUMNS))
            row[0] = i
            trial_errors(eta_all, xi_all, self.pb.eta_d, self.pb.src, self.pb.weight, row[1:])
            if not self.true_state:
                for c in TRUE_COLUMNS:
                    row[METRIC_COLUMNS.index(c)] = np.nan
            self.eta.pop(k, None)
            self.xi.pop(k, None)
            if i < self.first or i in self.rows:
                return
            self.rows[i] = row
            self.on_trial(i, row)

    def _on_diag(self, msg: String) -> None:
        try:
            d = check_diagnostics(ms.msg_to_json(msg, ("node", "trial")))
            name, k = d["node"], d["trial"]
            if k > self.started:
                raise Rejected("future", f"{name[:100]} diagnostics of trial {k}, trial "
                                         f"{self.started} started")
            if k < self.diagnostics.get(name, {}).get("trial", k):
                raise Rejected("stale", f"{name[:100]} diagnostics of trial {k} after "
                                        f"{self.diagnostics[name]['trial']}")
        except Rejected as exc:
            self.drops.reject(exc, ms.DIAGNOSTICS)
            return
        self.diagnostics[name] = d

    def _on_event(self, msg: String) -> None:
        try:
            d = ms.msg_to_json(msg)
            ev = TrialEvent.from_json(d)
            if ev.run and ev.run != self.cfg.run_id:
                raise Rejected("foreign", f"event of run {ev.run}")
            if ev.event == ms.START and ev.slot <= self.started:
                raise Rejected("stale", f"start of slot {ev.slot}, slot {self.started} "
                                        f"started")
            # the next slot; any for a monitor that has just started (a resumed run)
            if ev.event == ms.START and ev.slot > self.started + 1 and self.started >= 0:
                raise Rejected("future", f"start of slot {ev.slot}, slot {self.started} "
                                         f"started")
            if ev.event in (ms.END, ms.ABORT) and ev.slot > self.started:
                raise Rejected("unexpected", f"{ev.event} of slot {ev.slot}, slot "
                                             f"{self.started} started")
        except Rejected as exc:
            self.drops.reject(exc, ms.TRIAL_EVENTS)
            return
        self.events.append(d)
        if ev.event == ms.START:
            self.started = ev.slot
            self.iteration_of[ev.slot] = ev.trial
            self._complete(ev.slot)
        elif ev.event == ms.ABORT:
            self.aborted.add(ev.slot)
            self.eta.pop(ev.slot, None)
            self.xi.pop(ev.slot, None)
