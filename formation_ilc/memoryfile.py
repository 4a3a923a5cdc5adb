"""The team's learning memory in one file, for sim-to-real carry-over.

``formation-ilc simulate`` writes ``memory.npz``: the memory for the trial after the last,
shape (N, T, 2) [m/s, rad/s], with a format version, the scenario's name, the SHA-256 of
its YAML text, N and T. ``formation-ilc launch --init-memory FILE`` hands the file to every
robot node, which loads its own row. A file learned for another scenario (text) or team
size is refused, naming the file and what differs. A plain ``.npy`` of shape (N, T, 2) (the
format before version 1) is still read, checked by shape only.

Written atomically: a temporary file in the same folder, then ``os.replace``.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .scenario import Scenario

__all__ = ["FORMAT_VERSION", "MemoryFileError", "save_memory", "load_memory", "scenario_hash"]

FORMAT_VERSION = 1


class MemoryFileError(ValueError):
    """A memory file that cannot be used for this run (the message names file and cause)."""


def scenario_hash(sc: Scenario) -> str:
    return hashlib.sha256(sc.text.encode()).hexdigest()


def save_memory(path: Path, memory: NDArray[np.float64], sc: Scenario,
                trials_learned: int = 0) -> Path:
    """Write ``memory`` (N, T, 2) learned on ``sc`` to ``path`` (.npz), atomically."""
    m = np.asarray(memory, dtype=float)
    if m.shape != (sc.n, sc.samples, 2):
        raise ValueError(f"memory has shape {m.shape}, {sc.name} needs "
                         f"{(sc.n, sc.samples, 2)}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".npz")
    try:
        with os.fdopen(fd, "wb") as fh:
            np.savez(fh, format_version=np.int64(FORMAT_VERSION), memory=m,
                     scenario=np.str_(sc.name), scenario_sha256=np.str_(scenario_hash(sc)),
                     n=np.int64(sc.n), samples=np.int64(sc.samples),
                     dt=np.float64(sc.dt), trials_learned=np.int64(trials_learned))
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return path


def load_memory(path: Path | str, sc: Scenario) -> NDArray[np.float64]:
    """The memory (N, T, 2) in ``path`` for scenario ``sc``; MemoryFileError naming the file
    and what differs (scenario, its text, N, T, format) when it does not fit."""
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise MemoryFileError(f"{path}: cannot read a memory file: {exc}") from None
    want = (sc.n, sc.samples, 2)
    if isinstance(data, np.ndarray):  # a bare .npy (before format version 1)
        if data.shape != want:
            raise MemoryFileError(f"{path}: memory has shape {data.shape}, {sc.name} needs "
                                  f"{want} (robots, samples, [v, omega])")
        return np.asarray(data, dtype=float)
    with data:
        keys = set(data.files)
        need = {"format_version", "memory", "scenario", "scenario_sha256", "n", "samples"}
        if not need <= keys:
            raise MemoryFileError(f"{path}: not a formation-ilc memory file (lacks "
                                  f"{sorted(need - keys)})")
        version = int(data["format_version"])
        if version != FORMAT_VERSION:
            raise MemoryFileError(f"{path}: memory file format {version}, this version reads "
                                  f"format {FORMAT_VERSION}")
        name, digest = str(data["scenario"]), str(data["scenario_sha256"])
        n, n_t = int(data["n"]), int(data["samples"])
        memory = np.array(data["memory"], dtype=float)
    diffs = []
    if name != sc.name:
        diffs.append(f"scenario {name!r}, this run {sc.name!r}")
    elif digest != scenario_hash(sc):
        diffs.append(f"scenario {name!r} with a different text (SHA-256 {digest[:12]}..., "
                     f"this run's {scenario_hash(sc)[:12]}...)")
    if n != sc.n:
        diffs.append(f"{n} robots, this run {sc.n}")
    if n_t != sc.samples:
        diffs.append(f"{n_t} samples, this run {sc.samples}")
    if diffs:
        raise MemoryFileError(f"{path}: learned for another run: " + "; ".join(diffs))
    if memory.shape != want or not np.isfinite(memory).all():
        raise MemoryFileError(f"{path}: memory has shape {memory.shape} or non-finite values, "
                              f"{sc.name} needs finite {want}")
    return memory
