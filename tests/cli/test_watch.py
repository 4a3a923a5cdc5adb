"""The launcher's liveness backstop (formation_ilc.cli.launch.Watch), without ROS: a fake
monitor stands for what the launcher's monitor node has gathered."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from formation_ilc.cli.launch import Watch
from formation_ilc.cli.supervisor import trial_ranges
from formation_ilc.protocol.watchdog import Bounds


@dataclass
class Slots:
    first: int = 0
    done_at: tuple[int, int] | None = None


@dataclass
class FakeMonitor:
    rows: dict[int, Any] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    diagnostics: dict[str, Any] = field(default_factory=dict)
    slots: Slots = field(default_factory=Slots)

    def leader_present(self) -> bool:
        return True


BOUNDS = Bounds(startup=60.0, ready=30.0, sample=40.0)


def test_a_row_lost_after_done_stops_the_run_at_the_ready_bound(tmp_path: Path):
    """The leader is done, trial 21's row never came: the launcher says so once the ready
    bound has passed, long before its backstop (6 x the longest bound)."""
    w = Watch(BOUNDS, tmp_path, nodes=6, trials=40)
    mon = FakeMonitor(rows={k: None for k in range(40) if k != 21})
    assert w.tick(mon, 0.0) is None
    mon.slots.done_at = (40, 40)
    mon.events.append({"event": "done"})
    assert w.tick(mon, 1.0) is None
    assert w.tick(mon, 30.9) is None
    said = w.tick(mon, 31.1)
    assert said is not None and "metrics of trial 21 never came" in said and "done" in said


def test_done_with_every_row_is_not_stuck(tmp_path: Path):
    w = Watch(BOUNDS, tmp_path, nodes=6, trials=4)
    mon = FakeMonitor(rows={k: None for k in range(4)}, slots=Slots(done_at=(4, 4)))
    assert w.tick(mon, 0.0) is None
    assert w.tick(mon, 100.0) is None


def test_a_resumed_run_waits_only_for_its_own_rows(tmp_path: Path):
    """Rows below ``first`` are in metrics.csv already: not missing."""
    w = Watch(BOUNDS, tmp_path, nodes=6, trials=5)
    mon = FakeMonitor(rows={3: None, 4: None}, slots=Slots(first=3, done_at=(2, 5)))
    assert w.tick(mon, 0.0) is None
    assert w.tick(mon, 100.0) is None


def test_trial_ranges():
    assert trial_ranges([4]) == "trial 4"
    assert trial_ranges([9, 0, 1, 2, 5, 7, 8]) == "trials 0-2, 5, 7-9"


def test_a_finding_of_the_leader_comes_after_its_cause(tmp_path: Path, capsys):
    """A host that never joined: the leader's long finding names it last; the launcher says
    the cause first, with what to do."""
    w = Watch(BOUNDS, tmp_path, nodes=6, trials=4)
    w.cause = lambda: "host r2 (robot_2) never joined: start `formation-ilc launch ...`"
    mon = FakeMonitor(diagnostics={"virtual_leader": {"watchdog": {
        "count": 1, "what": "stuck: waiting for ready of " + "x" * 900 + " robot_2"}}})
    assert w.tick(mon, 0.0) is None
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "error: host r2 (robot_2) never joined: start `formation-ilc launch ...`"
    assert lines[1].startswith("virtual_leader: stuck")
