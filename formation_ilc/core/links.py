"""Links between robots: their names, what a link delivers at a tick, and a robot's inbox.

A robot i listens to its in-neighbours j (a_ij > 0) and, when a_i0 > 0, to the virtual
leader. Two kinds of link carry those poses (``RunConfig.links``):

* ``emulated``: the link emulator applies the scenario's delay model in simulated time. At
  tick t it delivers, on each link, the sender's output labelled ``delivered_label(t, tau)``
  (nothing while that is negative), as the batch simulator does. The receiver knows a tick
  is complete when every link has reported it, so a run is reproducible.
* ``direct``: real links (DDS). The receiver keeps what arrives; at its sample t it uses, on
  each link, the newest pose with a label St <= Rt (its own clock). In lockstep it waits for
  St = Rt on every link.

Either way the robot measures each delay from the labels by eq. (11), and a link with
nothing usable contributes nothing at that sample (eq. 10).
"""

from __future__ import annotations

import csv
from collections import deque
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit
from formation_ilc.core.clock import Malformed, Rejected, SampleClock
from formation_ilc.core.names import LEADER, robot_name, robot_number  # re-exported: their owner

__all__ = ["LEADER", "LINK_MODES", "robot_name", "robot_number", "link_name",
           "delivered_label", "Delivery", "LinkInbox", "DELAY_COLUMNS", "link_histograms",
           "delay_rows", "write_delays", "check_diagnostics", "check_for_run",
           "CONTACT_ACTIONS", "CONTACT_PHASES", "link_clocks", "ONE_WAY"]

#: sender name of the virtual leader's reference
LINK_MODES = ("emulated", "direct")


def link_name(sender: str, receiver: str) -> str:
    """``sender->receiver``: how delay histograms, diagnostics and delays.csv name a link."""
    return f"{sender}->{receiver}"


Samples = int | NDArray[np.int64]


#: the delay of a sample the link loses: ``delivered_label`` is negative for any tick, so
#: nothing is delivered and the link drops out of the current term for that sample (the
#: trial-end exchange still carries the whole trajectory to the predictive term)
LOST = 1 << 40


@njit(cache=True)
def delivered_label(t: Samples, tau: Samples) -> Samples:
    """Sample label an emulated link delivers at tick t when its delay is tau samples
    (negative: nothing is delivered at this tick); element-wise for arrays."""
    return t - tau


@dataclass(frozen=True)
class Delivery:
    """A pose a link delivers for use at one sample: sender, label St [ns], output (3,)."""

    sender: str
    label_ns: int
    eta: NDArray[np.float64]


@dataclass
class LinkInbox:
    """What one link has delivered to a robot, in either link mode.

    direct : poses by label, kept while they may still be the newest usable one.
    emulated : per tick, the pose delivered at that tick or None (nothing delivered).
    """

    sender: str
    clock: SampleClock
    direct: bool
    newest_ns: int = -1
    #: emulated: deliveries that came after the receiver had commanded their sample
    unused: int = 0
    poses: deque[tuple[int, NDArray[np.float64]]] = field(default_factory=deque)
    ticks: dict[int, Delivery | None] = field(default_factory=dict)

    def offer(self, label_ns: int, eta: NDArray[np.float64], trial: int) -> None:
        """Direct link: a pose labelled ``label_ns`` arrived while the receiver is in
        ``trial``. Rejected: a label of an earlier trial (stale), two trials ahead
        (future), or not newer than the newest on this link (duplicate, out_of_order)."""
        k, _ = self.clock.decode(label_ns)
        if k < trial:
            raise Rejected("stale", f"label of trial {k} in trial {trial}")
        if k > trial + 1:
            raise Rejected("future", f"label of trial {k} in trial {trial}")
        if label_ns == self.newest_ns:
            raise Rejected("duplicate", f"label {label_ns} ns again")
        if label_ns < self.newest_ns:
            raise Rejected("out_of_order", f"label {label_ns} ns after {self.newest_ns} ns")
        self.newest_ns = label_ns
        self.poses.append((label_ns, eta))

    def offer_tick(self, tick_ns: int, delivery: Delivery | None, trial: int) -> None:
        """Emulated link: what the link delivered at the tick labelled ``tick_ns``."""
        k, _ = self.clock.decode(tick_ns)
        if k < trial:
            raise Rejected("stale", f"tick of trial {k} in trial {trial}")
        if k > trial + 1:
            raise Rejected("future", f"tick of trial {k} in trial {trial}")
        if tick_ns in self.ticks:
            raise Rejected("duplicate", f"tick {tick_ns} ns again")
        if delivery is not None and delivery.label_ns > tick_ns:
            raise Rejected("future", f"pose labelled {delivery.label_ns} ns delivered at "
                                     f"tick {tick_ns} ns")
        self.ticks[tick_ns] = delivery

    def has(self, rt_ns: int) -> bool:
        """Everything the link will deliver for use at Rt is in: direct, a pose labelled
        Rt (delay 0); emulated, the tick Rt."""
        if self.direct:
            return self.newest_ns >= rt_ns
        return rt_ns in self.ticks

    def take(self, rt_ns: int) -> Delivery | None:
        """What the link delivers for use at Rt (None: nothing usable), forgetting what can
        no longer be used. Direct: the newest pose with St <= Rt of Rt's trial."""
        if not self.direct:
            self.forget(rt_ns - 1)
            return self.ticks.pop(rt_ns, None)
        trial_start = self.clock.stamp_ns(self.clock.decode(rt_ns)[0], 0)
        best: tuple[int, NDArray[np.float64]] | None = None
        while self.poses and self.poses[0][0] <= rt_ns:
            best = self.poses.popleft()
        if best is None or best[0] < trial_start:
            return None
        self.poses.appendleft(best)  # still the newest usable one at the next sample
        return Delivery(self.sender, best[0], best[1])

    def clear(self) -> None:
        """Forget everything held (an aborted trial); labels must still grow."""
        self.poses.clear()
        self.ticks.clear()

    def forget(self, until_ns: int) -> None:
        """Emulated: drop the ticks up to ``until_ns`` (their samples are commanded),
        counting each pose among them in ``unused``."""
        for tick in [x for x in self.ticks if x <= until_ns]:
            self.unused += self.ticks.pop(tick) is not None


# --------------------------------------------------------------------------- delay report

#: delays.csv columns: per link and delay tau [samples], how often the receiver measured it
#: (eq. 11), how often the link emulator injected it (empty with direct links: the network's
#: delays are only known through the measurement), and the model's probability; then, in
#: realtime and wall-clock runs, the link's one-way delay [ms] as the receiver's clock
#: exchanges measured it (``protocol.timesync``, the median since its estimate converged):
#: as the two clocks read (``measured_ms``), corrected by the estimate (``corrected_ms``),
#: and in an emulated run the true one (``injected_ms``), the same on each row of the link
DELAY_COLUMNS = ("link", "tau", "measured", "injected", "measured_fraction",
                 "model_probability", "measured_ms", "corrected_ms", "injected_ms")
#: the per-link one-way delay columns, and the keys of a clock block's ``delay``
ONE_WAY = ("measured_ms", "corrected_ms", "injected_ms")

Histograms = dict[str, dict[int, int]]


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return (_is_int(v) or isinstance(v, float)) and not isinstance(v, bool)


def _histograms(v: Any) -> bool:
    """{name: {"tau": count}} with integer taus and counts >= 0."""
    return isinstance(v, dict) and all(
        isinstance(h, dict) and all(isinstance(a, str) and a.isascii() and a.lstrip("-").isdigit()
                                    and _is_int(b) and b >= 0 for a, b in h.items())
        for h in v.values())


#: what a plant does on a contact (``protocol.physics_plant``)
CONTACT_ACTIONS = ("stop", "continue", "abort", "give_up")


#: where a plant says a contact happened: in a trial, or on the way back to the start poses
CONTACT_PHASES = ("trial", "return")


def _contact(v: Any) -> bool:
    return (isinstance(v, dict) and _is_int(v.get("slot")) and v["slot"] >= 0
            and _is_int(v.get("sample", 0)) and isinstance(v.get("line", ""), str)
            and len(v.get("line", "")) <= 2000 and v.get("action") in CONTACT_ACTIONS
            and isinstance(v.get("pairs", []), list) and len(v.get("pairs", [])) <= 10_000
            and (v.get("tilt") is None or _is_number(v.get("tilt")))
            and v.get("phase", "trial") in CONTACT_PHASES
            and _is_int(v.get("n", 0)) and isinstance(v.get("acts", True), bool))


def check_for_run(d: Mapping[str, Any], trials: int, contacts_from: Collection[str] = ()
                  ) -> None:
    """Diagnostics (checked by ``check_diagnostics``) that this run can have, or Malformed:
    a trial the run has (0 <= trial <= ``trials``, the leader's last word naming the
    count; -1: a node not ready yet), no slot below 0, and contacts (``contact``,
    ``contact_report``) only from ``contacts_from``, the nodes that watch this run's
    bodies (the physics plant, the physics bases; empty: no member of this run has
    bodies it watches)."""
    name = str(d.get("node"))[:100]
    k: Any = d.get("trial")
    if not (_is_int(k) and -1 <= k <= trials):
        raise Malformed(f"diagnostics of {name!r}: trial {k!r} is not one this run has "
                        f"(0..{trials - 1})")
    for key in ("contact", "contact_report"):
        if key in d and d.get("node") not in contacts_from:
            raise Malformed(f"diagnostics of {name!r}: {key} from a node that does not "
                            f"watch this run's bodies"
                            + (f" ({', '.join(contacts_from)})" if contacts_from
                               else " (none)"))
    for key in ("filter", "contact_report"):
        v = d.get(key)
        if isinstance(v, Mapping) and _is_int(v.get("slot")) and v["slot"] < 0:
            raise Malformed(f"diagnostics of {name!r}: {key} of slot {v['slot']}")


def check_diagnostics(d: Mapping[str, Any]) -> dict[str, Any]:
    """A node's diagnostics (a JSON object), checked where its readers rely on it: ``node``
    a name, ``trial`` an integer, the delay histograms (``delays``, ``injected``) integer
    counts by integer delay, ``dropped`` integer counts, ``timing`` numbers, ``missed`` an
    integer or integer counts, ``initial_shifts`` (x, y, theta) triples, ``watchdog`` (the
    leader's) an integer ``count`` and a text ``what``, ``filter`` (a robot's safety
    filter) integer counts with their ``slot``, ``contact_report`` (a plant with bodies)
    its ``slot`` and a list of ``pairs``, ``clock`` (clock estimates) a mapping of peers
    and a list of texts ``warn``, ``clock_word`` a list of (level, text) ``events``.
    Malformed naming
    the first field that is not; other fields pass as they are."""
    if not isinstance(d.get("node"), str):
        raise Malformed("diagnostics without a node name")
    if not _is_int(d.get("trial")):
        raise Malformed(f"diagnostics of {d['node'][:100]!r}: trial is not an integer")
    checks = {
        "delays": _histograms, "injected": _histograms,
        "dropped": lambda v: isinstance(v, dict) and all(_is_int(x) for x in v.values()),
        "timing": lambda v: isinstance(v, dict) and all(_is_number(x) for x in v.values()),
        "missed": lambda v: _is_int(v) or (isinstance(v, dict)
                                           and all(_is_int(x) for x in v.values())),
        "watchdog": lambda v: isinstance(v, dict) and _is_int(v.get("count"))
        and isinstance(v.get("what"), str) and len(v["what"]) <= 2000,
        "initial_shifts": lambda v: isinstance(v, dict) and all(
            isinstance(x, list) and len(x) == 3 and all(map(_is_number, x))
            for x in v.values()),
        # a robot's safety filter: the slot of the trial and integer counts
        "filter": lambda v: isinstance(v, dict) and (not v or (
            _is_int(v.get("slot")) and all(_is_int(x) for x in v.values()))),
        # a plant with bodies: the slot of the trial and the pairs that touched in it
        "contact_report": lambda v: isinstance(v, dict) and _is_int(v.get("slot"))
        and isinstance(v.get("pairs"), list) and len(v["pairs"]) <= 10_000,
        # a plant's contact, said the moment it happens: its slot and sample, the line
        # the launcher prints, what the plant does, the pairs, the tilt [rad] if any
        "contact": _contact,
        # clock estimates (protocol.timesync): per peer a mapping, the findings as texts
        "clock": lambda v: isinstance(v, dict) and isinstance(v.get("peers", {}), dict)
        and all(isinstance(p, dict) for p in v.get("peers", {}).values())
        and isinstance(v.get("warn", []), list)
        and all(isinstance(w, str) for w in v.get("warn", [])),
        # messages refused for their writer (protocol.writers): topic -> sender -> count
        "forged": lambda v: isinstance(v, dict) and len(v) <= 1000 and all(
            isinstance(s, dict) and len(s) <= 1000
            and all(_is_int(n) and n >= 0 for n in s.values()) for s in v.values()),
        # a word between reports: the clock events to say, (level, text) pairs
        "clock_word": lambda v: isinstance(v, dict) and isinstance(v.get("events"), list)
        and len(v["events"]) <= 100 and all(
            isinstance(e, list) and len(e) == 2 and all(isinstance(x, str) for x in e)
            and len(e[1]) <= 2000 for e in v["events"]),
    }
    for key, ok in checks.items():
        if key in d and not ok(d[key]):
            raise Malformed(f"diagnostics of {d['node'][:100]!r}: bad {key!r}")
    return dict(d)


def link_histograms(diagnostics: Mapping[str, Mapping[str, Any]]
                    ) -> tuple[Histograms, Histograms]:
    """(measured, injected) delay histograms per link name, from the nodes' last
    diagnostics: each robot's ``delays`` (keyed by sender) and the link emulator's
    ``injected`` (keyed by link)."""
    measured: Histograms = {}
    injected: Histograms = {}
    for node, d in diagnostics.items():
        for sender, hist in (d.get("delays") or {}).items():
            measured[link_name(sender, node)] = {int(a): int(b) for a, b in hist.items()}
        for link, hist in (d.get("injected") or {}).items():
            injected[link] = {int(a): int(b) for a, b in hist.items()}
    return measured, injected


def link_clocks(diagnostics: Mapping[str, Mapping[str, Any]]
                ) -> dict[str, dict[str, Any]]:
    """Each link's clock block (``protocol.timesync``) by link name: what the receiving
    robot's last diagnostics say of the sender's clock (estimate, one-way ``delay``)."""
    out: dict[str, dict[str, Any]] = {}
    for node, d in diagnostics.items():
        clock = d.get("clock")
        if not isinstance(clock, Mapping) or not node.startswith("robot_"):
            continue
        for sender, block in (clock.get("peers") or {}).items():
            if isinstance(block, Mapping):
                out[link_name(sender, node)] = dict(block)
    return out


def delay_rows(measured: Histograms, injected: Histograms | None,
               pmf: Mapping[int, float] | None,
               clocks: Mapping[str, Mapping[str, Any]] | None = None) -> list[list[Any]]:
    """Rows of DELAY_COLUMNS for every link a robot measured. Direct links have no link
    emulator and no delay model: pass None for ``injected`` and ``pmf``, and those columns
    are left empty. ``clocks``: each link's clock block (``link_clocks``); its one-way
    delays fill the last columns (empty where there is none)."""
    rows: list[list[Any]] = []
    for link in sorted(measured):
        hist = measured[link]
        inj = (injected or {}).get(link, {})
        total = sum(hist.values()) or 1
        delay = (clocks or {}).get(link, {}).get("delay") or {}
        one_way = [delay.get(k, "") for k in ONE_WAY]
        for tau in sorted({*hist, *inj, *(pmf or {})}):
            m = hist.get(tau, 0)
            rows.append([link, tau, m, "" if injected is None else inj.get(tau, 0),
                         m / total, "" if pmf is None else pmf.get(tau, 0.0), *one_way])
    return rows


def write_delays(path: str | Path, rows: list[list[Any]]) -> None:
    with Path(path).open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(DELAY_COLUMNS)
        w.writerows(rows)
