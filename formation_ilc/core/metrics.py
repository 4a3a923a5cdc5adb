"""metrics.csv: the one writer and reader of per-trial metrics, at full precision.

``formation-ilc simulate``, ``launch`` and ``analyze`` all write their rows here, so their
files agree to round-off when the runs do. Columns: METRIC_COLUMNS (metres and radians;
max over robots and t in [1, T] of the measured-output error unless marked ``true_``, the
true state; trial 0 is the first run). A plant that does not publish the true state leaves
the ``true_`` columns empty (``nan``).
"""

from __future__ import annotations

import contextlib
import csv
import math
from pathlib import Path
from typing import IO

import numpy as np
from numpy.typing import NDArray

__all__ = ["METRIC_COLUMNS", "TRUE_COLUMNS", "ERROR_COLUMNS", "COUNT_COLUMNS", "V1_COLUMNS",
           "MetricsWriter", "write_metrics", "read_metrics",
           "format_row", "TARGET_POSITION", "TARGET_HEADING", "robot_errors", "RobotCurves"]

#: the levels a team has learned its formation at [m, rad]: what ``tune`` minimises the
#: trials to, and the target lines of the error plots
TARGET_POSITION = 1.0
TARGET_HEADING = 0.1

#: metrics.csv columns
METRIC_COLUMNS = (
    "trial",
    "max_position_error",
    "max_heading_error",
    "true_max_position_error",
    "true_max_heading_error",
    "rms_position_error",
    "max_formation_error",
    "filter_active",
    "contacts",
)
#: the columns before the safety filter and contacts were counted (older files)
V1_COLUMNS = METRIC_COLUMNS[:7]
#: the error columns (all but the trial and the counts): finite in every trial that did not
#: diverge
ERROR_COLUMNS = METRIC_COLUMNS[1:7]
#: counts of events, not errors: ``contacts`` is nan on a plant without bodies
COUNT_COLUMNS = ("filter_active", "contacts")
#: the columns that need the plant's true state
TRUE_COLUMNS = ("true_max_position_error", "true_max_heading_error")


def format_row(row: NDArray[np.float64]) -> list[str]:
    """A metrics row as text: the trial as an integer, the rest with 17 significant digits
    (a float64 round-trips exactly)."""
    return [str(int(row[0]))] + ["nan" if math.isnan(x) else f"{x:.17g}" for x in row[1:]]


class MetricsWriter:
    """Writes rows as they come and flushes each one, so a crash keeps every finished
    trial."""

    def __init__(self, path: str | Path, append: bool = False):
        """A new file with its header, or (``append``) rows after those already there."""
        self.path = Path(path)
        self._fh: IO[str] = self.path.open("a" if append else "w", newline="")
        self._w = csv.writer(self._fh)
        try:
            if not append:
                self._w.writerow(METRIC_COLUMNS)
            self._fh.flush()
        except OSError as exc:  # a full disk: the error names this file
            with contextlib.suppress(OSError):  # its own flush fails the same way
                self._fh.close()
            raise OSError(exc.errno, exc.strerror, str(self.path)) from exc

    def write(self, row: NDArray[np.float64]) -> None:
        """One row, flushed; an OSError (a full disk) names this file."""
        try:
            self._w.writerow(format_row(row))
            self._fh.flush()
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(self.path)) from exc

    def close(self) -> None:
        try:
            self._fh.close()
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(self.path)) from exc

    def __enter__(self) -> MetricsWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_metrics(path: str | Path, metrics: NDArray[np.float64]) -> None:
    """All rows at once, shape (K, len(METRIC_COLUMNS))."""
    with MetricsWriter(path) as w:
        for row in metrics:
            w.write(row)


def read_metrics(path: str | Path) -> NDArray[np.float64]:
    """The rows of a metrics.csv, shape (K, len(METRIC_COLUMNS)); ValueError naming the file
    and line if it is not one."""
    path = Path(path)
    with path.open(newline="") as fh:
        rows = list(csv.reader(fh))
    if not rows or tuple(rows[0]) not in (METRIC_COLUMNS, V1_COLUMNS):
        raise ValueError(f"{path}: not a metrics.csv (header {rows[0] if rows else 'missing'})")
    width = len(rows[0])
    out = np.full((len(rows) - 1, len(METRIC_COLUMNS)), np.nan)
    for i, r in enumerate(rows[1:]):
        try:
            if len(r) != width:
                raise ValueError
            out[i, :width] = [float(x) for x in r]
        except ValueError:
            raise ValueError(f"{path}: line {i + 2}: not numbers: {r}") from None
    return out


def robot_errors(eta: NDArray[np.float64], eta_d: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each robot's largest measured-output error of one trial over t in [1, T]: shape
    (N, 2), position [m] and heading [rad] (the metrics' max over robots, per robot).
    eta, eta_d : shape (N, T+1, 3)."""
    d = eta_d[:, 1:] - eta[:, 1:]
    pos = np.hypot(d[..., 0], d[..., 1]).max(axis=1)
    from formation_ilc.core.kinematics import wrap_angle

    head = np.abs(wrap_angle(d[..., 2])).max(axis=1)
    return np.stack([pos, head], axis=1)


class RobotCurves:
    """Each robot's errors (``robot_errors``) of trials ``first`` .. ``first + total - 1``,
    of every trial up to ``cap`` of them, else of every ``total // cap``-th (a plot's
    worth of points, in bounded memory)."""

    def __init__(self, eta_d: NDArray[np.float64], first: int, total: int, cap: int = 2000):
        self.eta_d = eta_d
        self.first = first
        self.stride = max(1, -(-total // cap))
        self.trials: list[int] = []
        self.errors: list[NDArray[np.float64]] = []

    def take(self, k: int, eta: NDArray[np.float64]) -> None:
        if (k - self.first) % self.stride == 0:
            self.trials.append(k)
            self.errors.append(robot_errors(eta, self.eta_d))

    def arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
        """(trials, errors of shape (K, N, 2)), or None before any trial."""
        if not self.trials:
            return None
        return np.array(self.trials, dtype=float), np.array(self.errors)
