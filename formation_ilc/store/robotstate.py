"""A robot's learning state on disk: what a robot process needs to come back after a crash.

One file per robot (``<state_dir>/robot_<i>.npz``), written atomically (temporary file,
fsync, ``os.replace``) each time the robot learns from a trial or rolls one back, before it
says ready for the next trial. It holds the memory, how many iterations it has learned and
from which slot, and the same one step earlier (``prev_*``), so that a trial the leader
aborts after this robot learned from it can be undone (``formation_ilc.protocol.schedule``). The
scenario's SHA-256, N, T and the robot's number are checked on load, so a file of another
run is refused, naming what differs. The file is read bounded (a regular file, at most
``state_limit`` bytes: ``formation_ilc.store.bounded``); a damaged one (cut short, a flipped
bit that its zip CRC catches) or one with counters no learner writes is one MemoryFileError
naming it, never a traceback.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario
from formation_ilc.store.atomic import atomic_open
from formation_ilc.store.bounded import StateFileError, read_bounded
from formation_ilc.store.memoryfile import MemoryFileError, scenario_hash

__all__ = ["RobotState", "save_state", "load_state", "state_path", "state_limit"]

FORMAT = 1


@dataclass
class RobotState:
    """memory (T, 2) for the next trial; ``iterations`` learned, the last from ``slot``."""

    memory: NDArray[np.float64]
    iterations: int
    slot: int
    prev_memory: NDArray[np.float64]
    prev_iterations: int
    prev_slot: int


def state_path(state_dir: Path | str, robot_id: int) -> Path:
    return Path(state_dir) / f"robot_{robot_id}.npz"


def save_state(path: Path, st: RobotState, sc: Scenario, robot_id: int) -> None:
    with atomic_open(path) as fh:
        np.savez(fh, format=np.int64(FORMAT), robot=np.int64(robot_id),
                 scenario_sha256=np.str_(scenario_hash(sc)), n=np.int64(sc.n),
                 samples=np.int64(sc.samples), memory=st.memory,
                 iterations=np.int64(st.iterations), slot=np.int64(st.slot),
                 prev_memory=st.prev_memory, prev_iterations=np.int64(st.prev_iterations),
                 prev_slot=np.int64(st.prev_slot))


#: arrays and scalars a state file holds: anything else is not one
_KEYS = ("format", "robot", "scenario_sha256", "n", "samples", "memory", "iterations", "slot",
         "prev_memory", "prev_iterations", "prev_slot")


def state_limit(sc: Scenario) -> int:
    """The most bytes a robot state file of ``sc`` can hold: two (T, 2) float arrays, a
    few scalars and the zip's own records."""
    return 2 * 16 * sc.samples + (64 << 10)


def load_state(path: Path, sc: Scenario, robot_id: int) -> RobotState | None:
    """The state in ``path``, None if there is no file; MemoryFileError naming the file and
    what is wrong when it belongs to another run, is damaged (truncated, bit-flipped: its
    zip CRCs), is not a regular file or is larger than a state of ``sc`` can be, or holds
    counters that no run can have written. Nothing larger than ``state_limit`` is read."""
    try:
        raw = read_bounded(path, state_limit(sc), "a robot state file")
    except StateFileError as exc:
        raise MemoryFileError(str(exc)) from None
    if raw is None:
        return None
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as data:
            missing = [k for k in _KEYS if k not in data.files]
            if missing:
                raise MemoryFileError(f"{path}: not a robot state file (lacks "
                                      f"{', '.join(missing)})")
            st = _check(path, data, sc, robot_id)
    except MemoryFileError:
        raise
    except Exception as exc:  # noqa: BLE001 - zip, zlib, numpy: whatever damage makes them do
        raise MemoryFileError(f"{path}: damaged robot state ({type(exc).__name__}: "
                              f"{str(exc)[:120]}): remove it to start this robot afresh, "
                              f"or restore it from a copy") from None
    return st


def _scalar(path: Path, data: Any, key: str) -> int:
    a = data[key]
    if a.shape != () or a.dtype.kind not in "iu":
        raise MemoryFileError(f"{path}: {key}: expected an integer, got {a.dtype} of shape "
                              f"{a.shape}")
    return int(a)


def _check(path: Path, data: Any, sc: Scenario, robot_id: int) -> RobotState:
    fmt = _scalar(path, data, "format")
    if fmt != FORMAT:
        raise MemoryFileError(f"{path}: robot state format {fmt}, this version reads {FORMAT}")
    diffs = []
    if _scalar(path, data, "robot") != robot_id:
        diffs.append(f"robot {int(data['robot'])}, this node is robot {robot_id}")
    if str(data["scenario_sha256"]) != scenario_hash(sc):
        diffs.append("another scenario text")
    if (_scalar(path, data, "n"), _scalar(path, data, "samples")) != (sc.n, sc.samples):
        diffs.append(f"{int(data['n'])} robots x {int(data['samples'])} samples, "
                     f"this run {sc.n} x {sc.samples}")
    if diffs:
        raise MemoryFileError(f"{path}: state of another run: " + "; ".join(diffs))
    it, slot = _scalar(path, data, "iterations"), _scalar(path, data, "slot")
    pit, pslot = _scalar(path, data, "prev_iterations"), _scalar(path, data, "prev_slot")
    # what a learner can have written: one step of history, slots that only grow, and at
    # least one slot per iteration learned
    if not (0 <= it and it - 1 <= slot and pit in (it - 1, it) and pit >= 0
            and pit - 1 <= pslot <= slot and slot < (1 << 53)):
        raise MemoryFileError(f"{path}: inconsistent robot state: {it} trials learned, the "
                              f"last from slot {slot}; one step back {pit} from slot {pslot}")
    want = (sc.samples, 2)
    mem = []
    for key in ("memory", "prev_memory"):
        m = data[key]
        if m.shape != want or m.dtype.kind != "f":
            raise MemoryFileError(f"{path}: {key}: {m.dtype} of shape {m.shape}, need "
                                  f"floats of shape {want}")
        m = np.array(m, dtype=float)
        if not np.isfinite(m).all():
            raise MemoryFileError(f"{path}: {key} holds inf or nan")
        mem.append(m)
    return RobotState(mem[0], it, slot, mem[1], pit, pslot)
