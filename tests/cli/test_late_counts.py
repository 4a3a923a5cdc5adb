"""metrics.csv takes a count its row was written without (the physics bases say a trial's
contacts on their wall clock, after the robots' trajectories made the row), and keeps
every other line as it was: a contact's own row, which ended the run in a return."""

from __future__ import annotations

import numpy as np

from formation_ilc.cli.launch import _late_counts
from formation_ilc.core.metrics import METRIC_COLUMNS, MetricsWriter, read_metrics

CONTACTS = METRIC_COLUMNS.index("contacts")


def _row(trial: int, err: float, contacts: float) -> np.ndarray:
    r = np.full(len(METRIC_COLUMNS), err)
    r[0], r[CONTACTS] = trial, contacts
    return r


def test_a_late_count_fills_its_trials_row_and_nothing_else(tmp_path):
    path = tmp_path / "metrics.csv"
    w = MetricsWriter(path)
    written = [_row(0, 4.5, 0), _row(1, 1.2345678901234567, np.nan), _row(2, 0.9, np.nan),
               _row(2, np.nan, 1)]  # trial 2's return ended the run with a contact
    for r in written:
        w.write(r)
    w.close()
    monitor = {0: _row(0, 4.5, 0), 1: _row(1, 1.2345678901234567, 0),
               2: _row(2, 0.9, np.nan)}
    _late_counts(path, monitor, {1})
    got = read_metrics(path)
    assert got.shape == (4, len(METRIC_COLUMNS))
    assert got[1, CONTACTS] == 0 and got[1, 1] == 1.2345678901234567  # to the last bit
    np.testing.assert_array_equal(got[[0, 2, 3]], np.array(written)[[0, 2, 3]])
