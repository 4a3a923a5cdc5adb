"""A robot's learning state on disk: what a robot process needs to come back after a crash.

One file per robot (``<state_dir>/robot_<i>.npz``), written atomically (temporary file,
fsync, ``os.replace``) each time the robot learns from a trial or rolls one back, before it
says ready for the next trial. It holds the memory, how many iterations it has learned and
from which slot, and the same one step earlier (``prev_*``), so that a trial the leader
aborts after this robot learned from it can be undone (``formation_ilc.protocol.schedule``). The
scenario's SHA-256, N, T and the robot's number are checked on load, so a file of another
run is refused, naming what differs.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario
from formation_ilc.store.atomic import atomic_open
from formation_ilc.store.memoryfile import MemoryFileError, scenario_hash

__all__ = ["RobotState", "save_state", "load_state", "state_path"]

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


def load_state(path: Path, sc: Scenario, robot_id: int) -> RobotState | None:
    """The state in ``path``, None if there is no file; MemoryFileError naming the file and
    what differs when it belongs to another run or is damaged."""
    try:
        data = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        return None
    except (OSError, ValueError, EOFError) as exc:
        raise MemoryFileError(f"{path}: unreadable robot state: {exc}") from None
    try:
        with data:
            if int(data["format"]) != FORMAT:
                raise MemoryFileError(f"{path}: robot state format {int(data['format'])}, "
                                      f"this version reads {FORMAT}")
            diffs = []
            if int(data["robot"]) != robot_id:
                diffs.append(f"robot {int(data['robot'])}, this node is robot {robot_id}")
            if str(data["scenario_sha256"]) != scenario_hash(sc):
                diffs.append("another scenario text")
            if (int(data["n"]), int(data["samples"])) != (sc.n, sc.samples):
                diffs.append(f"{int(data['n'])} robots x {int(data['samples'])} samples, "
                             f"this run {sc.n} x {sc.samples}")
            if diffs:
                raise MemoryFileError(f"{path}: state of another run: " + "; ".join(diffs))
            st = RobotState(np.array(data["memory"], dtype=float), int(data["iterations"]),
                            int(data["slot"]), np.array(data["prev_memory"], dtype=float),
                            int(data["prev_iterations"]), int(data["prev_slot"]))
    except (KeyError, ValueError, EOFError) as exc:
        raise MemoryFileError(f"{path}: damaged robot state: {exc}") from None
    want = (sc.samples, 2)
    for m in (st.memory, st.prev_memory):
        if m.shape != want or not np.isfinite(m).all():
            raise MemoryFileError(f"{path}: memory of shape {m.shape} or non-finite, "
                                  f"need finite {want}")
    return st
