"""formation_ilc.run: the Python entry point (README's example)."""

from __future__ import annotations

import numpy as np
import pytest

import formation_ilc
from formation_ilc.config.scenario import ScenarioError, load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate


def test_run_on_the_batch_simulator_returns_the_simulators_metrics(tmp_path):
    r = formation_ilc.run("paper-triangle3", trials=3, seed=4, out=tmp_path)
    ref = simulate(load_scenario("paper-triangle3").with_options(seed=4), trials=3).metrics
    np.testing.assert_array_equal(r.metrics, ref)
    assert r.trials == 3 and r["trial"].tolist() == [0, 1, 2]
    assert r["max_position_error"][-1] < r["max_position_error"][0]  # it learns
    np.testing.assert_array_equal(read_metrics(tmp_path / "metrics.csv"), ref)
    with pytest.raises(KeyError, match="no such column"):
        r["position"]


def test_bad_input_is_refused_in_one_line():
    with pytest.raises(ScenarioError, match="no-such-scenario"):
        formation_ilc.run("no-such-scenario", trials=1)
    with pytest.raises(formation_ilc.RunFailed) as exc:  # the launcher refuses: status 2
        formation_ilc.run("no-such-scenario", trials=1, stack=True)
    assert exc.value.status == 2
