"""Per-trial metric rows from trajectories labelled with slots: one bookkeeping for the
launcher's monitor (live, from the wire) and for the analysis of a recording (from a file).

Trajectories carry the *slot* of the trial they belong to (their stamps sit on the slot's
grid); the leader's ``start`` events say which *iteration* a slot runs, and an ``abort``
drops a slot (``formation_ilc.protocol.schedule``). A slot's row is made once all its measured
trajectories are in (and its true ones, with ``true_state``) and its iteration is known;
rows are keyed by iteration. When a slot is aborted after its trajectories were all in,
the row made from it stays: the iteration runs again in a later slot with the same draws
and the same memory, and its repetition is dropped as a duplicate.

``strict`` (the monitor) also refuses events out of the leader's order and trajectories of
a slot not started yet; a recording (``strict=False``) is taken as the file gives it, and
a trajectory that comes before its slot's start waits for it.

**The schedule cross-checks every trial number.** Slots run one after the other, and each
either commits or is aborted: the slot after one that ran iteration i runs i + 1 if it
committed, i again if it was aborted (``expected``). A start that names another iteration
cannot be the leader's schedule: the monitor refuses it (``unexpected``), so no sequence
of events can file one trial's trajectories under another's number; a recording takes a
later start of the same slot that agrees with the schedule in its place (an earlier one
that disagreed, say a forgery in a run without sealed events, is dropped). With the run
key (``key``) only events the leader sealed are taken at all (``schedule.seal``); the
rest are ``foreign``. An abort names the slot the team last committed (``kept``): if an
earlier abort of that slot was taken here (one the leader did not send), the slot stands
again, with the trajectories it had.

The counts of a row (``core.metrics.COUNT_COLUMNS``) come from the nodes' reports, noted
as they arrive (``note_filtered``, ``note_contacts``): a robot reports what its safety
filter changed before it sends its trajectory, the plant its contacts before its last
poses. A row takes what has been noted when its trajectories are in: ``filter_active``
is 0 in a run without a filter, the sum over the robots once every robot's count is in
(else nan); ``contacts`` is the plant's count (nan without bodies, or when not noted).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core.clock import Rejected
from formation_ilc.core.metrics import METRIC_COLUMNS, TRUE_COLUMNS
from formation_ilc.core.names import robot_number
from formation_ilc.model.simulate import Problem, trial_errors
from formation_ilc.protocol.schedule import (
    ABORT,
    DONE,
    END,
    START,
    TrialEvent,
    is_repeat,
    sealed,
    unexplained_gap,
)

__all__ = ["Row", "SlotRows"]

_FILTER = METRIC_COLUMNS.index("filter_active")
_CONTACTS = METRIC_COLUMNS.index("contacts")


@dataclass
class Row:
    """A complete trial: its iteration, metrics row (METRIC_COLUMNS) and trajectories
    (N, T+1, 3); ``xi`` is None without a true state."""

    trial: int
    row: NDArray[np.float64]
    eta: NDArray[np.float64]
    xi: NDArray[np.float64] | None


class SlotRows:
    """The slots of one run and the rows they completed (``rows``: iteration -> row).

    ``first``: iterations below it are not reported (a resumed run has their rows already).
    ``key``: the run key; only events it sealed are taken (None: any).
    """

    def __init__(self, pb: Problem, true_state: bool = True, first: int = 0,
                 strict: bool = True, safety: bool = False, key: bytes | None = None):
        self.pb = pb
        self.key = key
        #: the last slot aborted here, with what it held (a ``kept`` may restore it)
        self.limbo: tuple[int, dict[int, Any], dict[int, Any], dict[int, int] | None,
                          int | None] | None = None
        #: events refused as foreign (another run's, or not sealed by the leader)
        self.foreign = 0
        self.safety = safety
        #: slot -> robot (0-based) -> commands its filter changed; slot -> contacts
        self.filtered: dict[int, dict[int, int]] = {}
        self.contacts: dict[int, int] = {}
        #: iterations whose row took a count after it was made (``note_contacts``)
        self.late_counts: set[int] = set()
        self.true_state = true_state
        self.first = first
        self.strict = strict
        #: the run id (events of another run are foreign); "" takes any
        self.run = ""
        self.iteration_of: dict[int, int] = {}  # slot -> iteration (start events)
        self.aborted: set[int] = set()
        self.started = -1                      # the last slot started
        self.start_seq = -1                    # the seq of its start
        self.done_at: tuple[int, int] | None = None  # (slot, trials) of the done event
        self.rows: dict[int, NDArray[np.float64]] = {}
        #: iteration -> the slot its row was made from
        self.made: dict[int, int] = {}
        self.eta: dict[int, dict[int, NDArray[np.float64]]] = {}
        self.xi: dict[int, dict[int, NDArray[np.float64]]] = {}

    def event(self, ev: TrialEvent) -> list[Row]:
        """Take a trial event; returns the rows it completes. Rejected (strict) if it is
        out of the leader's order."""
        if ev.run and self.run and ev.run != self.run:
            self.foreign += 1
            raise Rejected("foreign", f"event of run {ev.run}")
        if not sealed(ev, self.key):
            self.foreign += 1
            raise Rejected("foreign", f"{ev.event} of slot {ev.slot} (seq {ev.seq}) not "
                                      f"sealed by this run's leader")
        if self.repeat(ev):
            return []
        if self.strict:
            if ev.event == START and ev.slot <= self.started:
                raise Rejected("stale", f"start of slot {ev.slot}, slot {self.started} "
                                        f"started")
            # the next slot; any for one that has just started (a resumed run)
            if ev.event == START and unexplained_gap(self.started, ev.slot, self.aborted):
                raise Rejected("future", f"start of slot {ev.slot}, slot {self.started} "
                                         f"started")
            # an abort of the next slot: its start was lost with a leader that was killed
            if ev.event == END and ev.slot > self.started or \
                    ev.event == ABORT and ev.slot > self.started + 1:
                raise Rejected("unexpected", f"{ev.event} of slot {ev.slot}, slot "
                                             f"{self.started} started")
        if ev.event == START:
            exp = self.expected(ev.slot)
            before = self._last_before(ev.slot)
            if (self.key is not None and exp is not None and ev.trial == exp - 1
                    and before is not None and before not in self.aborted):
                # a start sealed by the run's leader that runs the last slot's iteration
                # again: the leader does that only after aborting that slot, so its abort
                # was lost here (a restarted leader's, sent before this reader matched it;
                # the leader waits for no passive reader's answer)
                self._abort(before)
                exp = self.expected(ev.slot)
            if self.strict and exp is not None and ev.trial != exp:
                raise Rejected("unexpected", f"start of slot {ev.slot} as trial {ev.trial}: "
                                             f"the schedule runs trial {exp} there")
            had = self.iteration_of.get(ev.slot)
            if had is not None and had != ev.trial:
                if self.strict or exp is None or ev.trial != exp \
                        or self._made_from(ev.slot):
                    raise Rejected("unexpected", f"slot {ev.slot} started as trial "
                                                 f"{ev.trial}, it runs trial {had}")
                # a recording: the start that agrees with the schedule replaces one that
                # does not (a forgery in a run without sealed events)
            if ev.slot >= self.started:
                self.started, self.start_seq = ev.slot, ev.seq
            self.iteration_of[ev.slot] = ev.trial
            return self._complete(ev.slot)
        if ev.event == ABORT:
            done = self._kept(ev.kept)
            self._abort(ev.slot)
            return done
        if ev.event == DONE:  # the slot after the last, and the trials learned
            self.done_at = (ev.slot, ev.trial)
        return []

    def _abort(self, slot: int) -> None:
        """``slot`` is aborted: what it held waits in ``limbo`` (a ``kept`` may restore it)."""
        if slot not in self.aborted:
            self.limbo = (slot, self.eta.pop(slot, {}), self.xi.pop(slot, {}),
                          self.filtered.pop(slot, None), self.contacts.pop(slot, None))
        self.aborted.add(slot)
        if slot == self.started:  # a start of it again is a replay, not a repeat
            self.start_seq = -1

    def _last_before(self, slot: int) -> int | None:
        """The last slot started before ``slot`` (None: none known)."""
        before = [q for q in self.iteration_of if q < slot]
        return max(before) if before else None

    def expected(self, slot: int) -> int | None:
        """The iteration the leader's schedule runs in ``slot``, from the last slot started
        before it: that slot's iteration, plus one unless it was aborted (slots only run
        after the one before committed or was aborted); None when no slot before it is
        known."""
        p = self._last_before(slot)
        if p is None:
            return None
        return self.iteration_of[p] + (0 if p in self.aborted else 1)

    def _made_from(self, slot: int) -> bool:
        """Whether a row was made from ``slot``'s trajectories."""
        return slot in self.made.values()

    def _kept(self, slot: int) -> list[Row]:
        """An abort says ``slot`` was committed: if an abort of it was taken here (one the
        leader did not send), it stands again, with what it held; returns the rows made."""
        if slot < 0 or slot not in self.aborted:
            return []
        self.aborted.discard(slot)
        if self.limbo is not None and self.limbo[0] == slot:
            _, eta, xi, filtered, contacts = self.limbo
            self.limbo = None
            self.eta.setdefault(slot, {}).update(eta)
            self.xi.setdefault(slot, {}).update(xi)
            if filtered is not None:
                self.filtered[slot] = filtered
            if contacts is not None:
                self.contacts[slot] = contacts
        if slot == self.started:
            self.start_seq = -1
        return self._complete(slot)

    def repeat(self, ev: TrialEvent) -> bool:
        """Whether ``ev`` is the last start taken, again, with no abort of its slot since:
        the leader repeats a start while its slot does not move
        (``schedule.StartRepeat``); no news, and no refusal. An unsealed copy of it (with
        the run key) is no repeat: ``event`` refuses it as foreign."""
        return sealed(ev, self.key) and is_repeat(ev, self.started, self.start_seq)

    def infer(self, identity: range | None = None) -> list[Row]:
        """For a recording: the iteration of a slot whose start event is not in the file (a
        recorder killed just as it began, a damaged chunk), from the slots around it.
        Slots run one after the other and each either commits or is aborted, so from the
        nearest slot before it with a known iteration (l) to the nearest one after it (u,
        or the run's ``done``) the iteration rises by one for each slot that committed.
        When it rose by one for every slot between whose abort the file does not show,
        they all committed, and slot s ran l's iteration plus the commits from l to s;
        when it rose by one less and s is the only such slot, s was aborted and its
        trajectories are dropped. Otherwise s is left unknown. ``identity``: the slots of
        a batch simulation's recording (its trials), each of which ran the iteration of
        its own number. Returns the rows made."""
        known = dict(self.iteration_of)
        if self.done_at is not None:
            known.setdefault(*self.done_at)
        done: list[Row] = []
        for s in sorted(set(self.eta) | set(self.xi)):
            if s in self.iteration_of or s in self.aborted:
                continue
            if identity is not None:
                if s in identity:
                    self.iteration_of[s] = s
                    done += self._complete(s)
                continue
            lower = [q for q in self.iteration_of if q < s]
            upper = [q for q in known if q > s]
            if not lower or not upper:
                continue
            lo, hi = max(lower), min(upper)
            aborted = sum(1 for q in range(lo, hi) if q in self.aborted)
            rise = known[hi] - self.iteration_of[lo]
            unknown = [q for q in range(lo + 1, hi) if q not in self.aborted]
            if rise == hi - lo - aborted:
                self.iteration_of[s] = self.iteration_of[lo] + sum(
                    1 for q in range(lo, s) if q not in self.aborted)
                done += self._complete(s)
            elif rise == hi - lo - aborted - 1 and unknown == [s]:
                self.aborted.add(s)
                self.eta.pop(s, None)
                self.xi.pop(s, None)
        return done

    def trajectory(self, slot: int, robot: int, true: bool,
                   eta: NDArray[np.float64]) -> list[Row]:
        """Take robot ``robot``'s (0-based) measured (or ``true``) trajectory of ``slot``;
        returns the rows it completes. Rejected if its slot was aborted, its trial is
        complete, it came already, or (strict) it is of a slot after the next one. A
        trajectory of the next slot is kept until its start comes (the trajectories and
        the events are two topics, and a loaded reader may take a robot's trajectory
        before the start it follows: a CI run lost trial 14's that way and stopped as
        stuck); its row is made when the start comes."""
        i = self.iteration_of.get(slot)
        if slot in self.aborted:
            raise Rejected("stale", f"trajectory of slot {slot}, aborted")
        if i is not None and i in self.rows:
            raise Rejected("duplicate", f"trial {i} is complete")
        if self.strict and slot > self.started + 1:
            raise Rejected("future", f"trajectory of slot {slot}, slot {self.started} "
                                     f"started")
        store = self.xi if true else self.eta
        if robot in store.get(slot, {}):
            raise Rejected("duplicate", f"slot {slot} again")
        store.setdefault(slot, {})[robot] = eta
        return self._complete(slot)

    def note_diagnostics(self, d: Mapping[str, Any]) -> None:
        """What a node's diagnostics (checked: ``core.links.check_diagnostics``) say of a
        row's counts: a robot's ``filter`` (the commands its filter changed in a slot), a
        plant's ``contact_report`` (the pairs that touched in a slot)."""
        f = d.get("filter")
        if isinstance(f, Mapping) and "slot" in f and "changed" in f:
            try:
                r = robot_number(str(d.get("node"))) - 1
            except Rejected:
                return
            if 0 <= r < self.pb.n:
                self.note_filtered(int(f["slot"]), r, int(f["changed"]))
        c = d.get("contact_report")
        if isinstance(c, Mapping) and "slot" in c and isinstance(c.get("pairs"), list):
            self.note_contacts(int(c["slot"]), len(c["pairs"]))

    def note_filtered(self, slot: int, robot: int, changed: int) -> None:
        """Robot ``robot`` (0-based) says its filter changed ``changed`` commands in
        ``slot`` (a slot whose row is made already: ignored)."""
        if slot not in self.iteration_of or self.iteration_of[slot] not in self.rows:
            self.filtered.setdefault(slot, {})[robot] = int(changed)

    def note_contacts(self, slot: int, pairs: int) -> None:
        """The plant says ``pairs`` pairs of robots touched in ``slot``. A plant on the wall
        clock (the physics bases) may say it after the slot's trajectories made its row
        (the run's last trial): a row made without it (nan) takes it then, and its
        iteration is in ``late_counts`` (its line in a streamed metrics.csv is to be
        written again). Only ``strict`` (the monitor, which takes contacts from the
        run's body watchers alone: ``core.links.check_for_run``); a recording's analysis
        knows no watchers, and a forged late report in it would be taken."""
        i = self.iteration_of.get(slot)
        if i is None or i not in self.rows:
            self.contacts[slot] = int(pairs)
        elif (self.strict and self.made.get(i) == slot
              and np.isnan(self.rows[i][_CONTACTS])):
            self.rows[i][_CONTACTS] = float(pairs)
            self.late_counts.add(i)

    def measured_only(self) -> list[Row]:
        """Rows of the slots whose measured trajectories are all in, with nan true columns:
        for a recording whose plant published no true state."""
        self.true_state = False
        done: list[Row] = []
        for slot in sorted(self.eta):
            done += self._complete(slot)
        return done

    def unstarted(self) -> list[tuple[int, int, bool]]:
        """(slot, robot, true) of the trajectories held for a slot no start event named:
        at the end of a recording, trajectories of no trial of the run."""
        return [(slot, r, true) for true, store in ((False, self.eta), (True, self.xi))
                for slot, got in sorted(store.items()) if slot not in self.iteration_of
                for r in sorted(got)]

    def _complete(self, slot: int) -> list[Row]:
        n = self.pb.n
        i = self.iteration_of.get(slot)
        if i is None or slot in self.aborted:
            return []
        if len(self.eta.get(slot, {})) < n or (self.true_state
                                               and len(self.xi.get(slot, {})) < n):
            return []
        eta = np.stack([self.eta[slot][r] for r in range(n)])
        xi = np.stack([self.xi[slot][r] for r in range(n)]) if self.true_state else None
        row = np.empty(len(METRIC_COLUMNS))
        row[0] = i
        trial_errors(eta, eta if xi is None else xi, self.pb.eta_d, self.pb.src,
                     self.pb.weight, row[1:])
        if xi is None:
            for c in TRUE_COLUMNS:
                row[METRIC_COLUMNS.index(c)] = np.nan
        got = self.filtered.pop(slot, {})
        row[_FILTER] = (0.0 if not self.safety
                        else float(sum(got.values())) if len(got) == n else np.nan)
        row[_CONTACTS] = float(self.contacts.pop(slot, np.nan))
        self.eta.pop(slot, None)
        self.xi.pop(slot, None)
        if i < self.first or i in self.rows:
            return []
        self.rows[i] = row
        self.made[i] = slot
        return [Row(i, row, eta, xi)]
