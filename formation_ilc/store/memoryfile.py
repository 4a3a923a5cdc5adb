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
import zipfile
from pathlib import Path
from typing import IO, Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario
from formation_ilc.store.atomic import atomic_open

__all__ = ["FORMAT_VERSION", "MemoryFileError", "save_memory", "load_memory", "scenario_hash",
           "trials_learned"]

FORMAT_VERSION = 1


class MemoryFileError(ValueError):
    """A memory file that cannot be used for this run (the message names file and cause)."""


def scenario_hash(sc: Scenario) -> str:
    return hashlib.sha256(sc.text.encode()).hexdigest()


def save_memory(path: Path, memory: NDArray[np.float64], sc: Scenario,
                trials_learned: int = 0, durable: bool = True) -> Path:
    """Write ``memory`` (N, T, 2) learned on ``sc`` to ``path`` (.npz), atomically: a reader
    (or a crash) sees the old file or the new one, never a part. ``durable`` also flushes
    it to the disk before the rename (fsync), so a power cut keeps one of the two."""
    m = np.asarray(memory, dtype=float)
    if m.shape != (sc.n, sc.samples, 2):
        raise ValueError(f"memory has shape {m.shape}, {sc.name} needs "
                         f"{(sc.n, sc.samples, 2)}")
    if not np.isfinite(m).all():
        raise ValueError("memory holds inf or nan: a diverged run's memory is not saved")
    path = Path(path)
    with atomic_open(path, durable=durable) as fh:
        np.savez(fh, format_version=np.int64(FORMAT_VERSION), memory=m,
                 scenario=np.str_(sc.name), scenario_sha256=np.str_(scenario_hash(sc)),
                 n=np.int64(sc.n), samples=np.int64(sc.samples),
                 dt=np.float64(sc.dt), trials_learned=np.int64(trials_learned))
    return path


def _header(fh: IO[bytes], where: str) -> tuple[tuple[int, ...], np.dtype[Any]]:
    """(shape, dtype) of the .npy stream ``fh``, read from its header alone."""
    try:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
    except (ValueError, OSError, EOFError, SyntaxError) as exc:
        raise MemoryFileError(f"{where}: not a numpy array ({exc})") from None
    return tuple(int(x) for x in shape), dtype


def _check_headers(path: Path) -> dict[str, tuple[tuple[int, ...], np.dtype[Any]]]:
    """Refuse a file whose arrays are not the small scalars and the one (N, T, 2) float
    array of a memory file, from the headers alone: a hostile or corrupt file (a
    compressed 'memory' of terabytes, a string 'scenario' of gigabytes) is never loaded."""
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError, ValueError) as exc:
        raise MemoryFileError(f"{path}: cannot read a memory file: {exc}") from None
    with zf:
        shapes: dict[str, tuple[tuple[int, ...], np.dtype[Any]]] = {}
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            key = info.filename[:-4]
            try:
                with zf.open(info) as fh:
                    shapes[key] = _header(fh, f"{path}: {key}")
            except (zipfile.BadZipFile, OSError, RuntimeError, NotImplementedError) as exc:
                raise MemoryFileError(f"{path}: {key}: cannot read: {exc}") from None
    for key, (shape, dtype) in shapes.items():
        if key == "memory":
            ok = len(shape) == 3 and dtype.kind == "f" and shape[2] == 2
            why = "(robots, samples, 2) floats"
        elif key in ("scenario", "scenario_sha256"):
            ok = shape == () and dtype.kind == "U" and dtype.itemsize <= 4 * 1024
            why = "a short string"
        else:
            ok = shape == () and dtype.kind in "iuf"
            why = "a number"
        if not ok:
            raise MemoryFileError(f"{path}: {key}: expected {why}, got {dtype} of shape "
                                  f"{shape}")
    return shapes


def load_memory(path: Path | str, sc: Scenario) -> NDArray[np.float64]:
    """The memory (N, T, 2) in ``path`` for scenario ``sc``; MemoryFileError naming the file
    and what differs (scenario, its text, N, T, format) when it does not fit. Every array's
    shape is checked from its header before any is loaded."""
    path = Path(path)
    want = (sc.n, sc.samples, 2)
    # the file holds one (N, T, 2) float64 array and a few scalars: refuse anything else
    # (a device, a pipe, a file of gigabytes) before reading it
    limit = 2 * 16 * sc.n * sc.samples + (1 << 20)
    try:
        if not path.is_file():
            why = "not a regular file" if path.exists() else "no such file"
            raise MemoryFileError(f"{path}: cannot read a memory file: {why}")
        if path.stat().st_size > limit:
            raise MemoryFileError(f"{path}: {path.stat().st_size} bytes, more than a memory "
                                  f"file of {sc.name} can be ({limit})")
        with open(path, "rb") as fh:
            magic = fh.read(6)
            if magic == b"\x93NUMPY":  # a bare .npy (before format version 1)
                fh.seek(0)
                shape, dtype = _header(fh, str(path))
                if shape != want or dtype.kind != "f":
                    raise MemoryFileError(f"{path}: memory has shape {shape}, {sc.name} "
                                          f"needs {want} (robots, samples, [v, omega])")
    except OSError as exc:
        raise MemoryFileError(f"{path}: cannot read a memory file: {exc}") from None
    shapes = _check_headers(path) if magic != b"\x93NUMPY" else {}
    try:
        data = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise MemoryFileError(f"{path}: cannot read a memory file: {exc}") from None
    if isinstance(data, np.ndarray):  # a bare .npy (before format version 1)
        if data.shape != want:
            raise MemoryFileError(f"{path}: memory has shape {data.shape}, {sc.name} needs "
                                  f"{want} (robots, samples, [v, omega])")
        if not np.isfinite(data).all():
            raise MemoryFileError(f"{path}: memory holds non-finite values")
        _check_magnitude(path, np.asarray(data, dtype=float))
        return np.asarray(data, dtype=float)
    with data:
        keys = set(data.files)
        need = {"format_version", "memory", "scenario", "scenario_sha256", "n", "samples"}
        if not need <= keys:
            raise MemoryFileError(f"{path}: not a formation-ilc memory file (lacks "
                                  f"{sorted(need - keys)})")
        try:
            version = int(data["format_version"])
            if version != FORMAT_VERSION:
                raise MemoryFileError(f"{path}: memory file format {version}, this version "
                                      f"reads format {FORMAT_VERSION}")
            name, digest = str(data["scenario"]), str(data["scenario_sha256"])
            n, n_t = int(data["n"]), int(data["samples"])
            diffs = []
            if name != sc.name:
                diffs.append(f"scenario {name!r}, this run {sc.name!r}")
            elif digest != scenario_hash(sc):
                diffs.append(f"scenario {name!r} with a different text (SHA-256 "
                             f"{digest[:12]}..., this run's {scenario_hash(sc)[:12]}...)")
            if n != sc.n:
                diffs.append(f"{n} robots, this run {sc.n}")
            if n_t != sc.samples:
                diffs.append(f"{n_t} samples, this run {sc.samples}")
            if diffs:
                raise MemoryFileError(f"{path}: learned for another run: " + "; ".join(diffs))
            if shapes["memory"][0] != want:  # checked before the array is read
                raise MemoryFileError(f"{path}: memory has shape {shapes['memory'][0]}, "
                                      f"{sc.name} needs {want}")
            memory = np.array(data["memory"], dtype=float)
        except (OSError, ValueError, EOFError, OverflowError, zipfile.BadZipFile) as exc:
            if isinstance(exc, MemoryFileError):
                raise
            raise MemoryFileError(f"{path}: cannot read a memory file: {exc}") from None
    if memory.shape != want or not np.isfinite(memory).all():
        raise MemoryFileError(f"{path}: memory has shape {memory.shape} or non-finite values, "
                              f"{sc.name} needs finite {want}")
    _check_magnitude(path, memory)
    return memory


#: [m/s, rad/s] the largest command a memory may hold: beyond it no robot drives it, and a
#: run from it only overflows (1e300 made every error infinite in the first trial)
MEMORY_LIMIT = 1e6


def _check_magnitude(path: Path, memory: NDArray[np.float64]) -> None:
    """MemoryFileError naming the file, the robot and the sample when a command of the
    memory is beyond MEMORY_LIMIT (the memory of a run that diverged)."""
    big = np.abs(memory) > MEMORY_LIMIT
    if big.any():
        r, t, c = (int(x) for x in np.argwhere(big)[0])
        raise MemoryFileError(f"{path}: robot {r + 1}'s {'v' if c == 0 else 'omega'} at sample "
                              f"{t} is {memory[r, t, c]:.3g}, beyond {MEMORY_LIMIT:g} (m/s, "
                              f"rad/s): no robot's command (the memory of a run that "
                              f"diverged?)")


def trials_learned(path: Path | str) -> int | None:
    """How many trials the memory in ``path`` learned from (the index of the trial it is
    for), or None if the file does not say."""
    try:
        with np.load(path, allow_pickle=False) as data:
            return int(data["trials_learned"]) if "trials_learned" in data.files else None
    except (OSError, ValueError, KeyError, EOFError, AttributeError, zipfile.BadZipFile):
        return None
