"""Where an interrupted run goes on from, decided from its state files before anything moves.

``launch --resume DIR`` continues a run from ``DIR/state/``: the leader's schedule
(``leader.json``) and every robot's learning state (``robot_<i>.npz``). They were written
by processes that may have died at any instant, copied by hand, or edited; before a single
row of ``metrics.csv`` is rewritten or a node started, :func:`resume_point` reads them all
(bounded, validated: ``formation_ilc.protocol.schedule.read_state``,
``formation_ilc.store.robotstate.load_state``) and checks that they tell one story:

* every robot has learned ``committed`` iterations, or one more from the slot the leader
  left open (that step is rolled back by the abort the restarted leader sends);
* no robot is missing its file once the team has learned anything (and the run is not
  over: a finished run resumes to nothing, but the files that are there must agree);
* robot files without a leader file: refused (the leader's file is written before any
  robot learns).

Anything else is a :class:`ResumeError` naming the file and the disagreement: the user
decides, nothing is deleted.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from formation_ilc.config.scenario import Scenario
from formation_ilc.protocol.schedule import ScheduleError, read_state
from formation_ilc.store.memoryfile import MemoryFileError
from formation_ilc.store.robotstate import RobotState, load_state, state_path

__all__ = ["ResumeError", "ResumePoint", "resume_point", "LEADER_FILE"]

LEADER_FILE = "leader.json"


class ResumeError(ValueError):
    """The state of a run cannot be resumed; the message names the file and the cause."""


@dataclass(frozen=True)
class ResumePoint:
    """committed: iterations every robot has learned (the resumed run starts the next);
    open_slot: the slot the leader left open (aborted on resume), or None."""

    committed: int
    open_slot: int | None
    robots: dict[int, RobotState]


def resume_point(state_dir: Path, sc: Scenario) -> ResumePoint:
    """The point the run in ``state_dir`` goes on from; ResumeError when a file is
    damaged, of another run, or the files disagree (see the module's docstring)."""
    state_dir = Path(state_dir)
    leader = state_dir / LEADER_FILE
    try:
        st = read_state(leader, sc.trials)
    except ScheduleError as exc:
        raise ResumeError(str(exc)) from None
    robots: dict[int, RobotState] = {}
    for i in range(1, sc.n + 1):
        try:
            r = load_state(state_path(state_dir, i), sc, i)
        except MemoryFileError as exc:
            raise ResumeError(str(exc)) from None
        if r is not None:
            robots[i] = r
    if st is None:
        if robots:
            i = min(robots)
            raise ResumeError(f"{leader}: missing, but {state_path(state_dir, i)} holds "
                              f"{robots[i].iterations} learned trials: the leader's schedule "
                              f"is gone (restore it from a copy)")
        return ResumePoint(0, None, robots)
    c, slot, was_open = st["committed"], st["slot"], st["open"]
    for i in range(1, sc.n + 1):
        path = state_path(state_dir, i)
        r = robots.get(i)
        if r is None:
            if 0 < c < sc.trials:  # a finished run needs no robot to resume
                raise ResumeError(f"{path}: missing, but {leader} says the team has learned "
                                  f"{c} trials: this robot's memory is gone")
            continue
        if r.iterations == c:
            if r.slot > slot:
                raise ResumeError(f"{path}: learned from slot {r.slot}, after the last slot "
                                  f"{leader} started ({slot}): the files are of different "
                                  f"runs or moments")
            continue
        if r.iterations == c + 1 and was_open and r.slot == slot and r.prev_iterations == c:
            continue  # learned from the open slot: the abort rolls it back
        raise ResumeError(f"{path}: {r.iterations} trials learned (the last from slot "
                          f"{r.slot}), but {leader} says {c} (slot {slot}"
                          f"{', open' if was_open else ''}): the files disagree")
    return ResumePoint(c, slot if was_open else None, robots)
