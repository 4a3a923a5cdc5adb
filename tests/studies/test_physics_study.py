"""The law against the physics engine in one process: it learns, from either pose source."""

import numpy as np
import pytest

pytest.importorskip("pybullet", reason="the physics extra: pip install -e .[physics]")

from formation_ilc.config.scenario import load_scenario, scenario_from_text  # noqa: E402
from formation_ilc.model.physics import MODELS  # noqa: E402
from formation_ilc.studies.physics import run_physics  # noqa: E402


def short_triangle(samples=60):
    text = load_scenario("paper-triangle3").text.replace("samples: 140", f"samples: {samples}")
    return scenario_from_text(text, "short.yaml").with_options(noise=False, delay=False)


def test_error_falls_and_truth_is_the_engine():
    sc = short_triangle()
    res = run_physics(sc, MODELS["p3dx"], 3, keep=(2,))
    err = res.column("max_position_error")
    assert err[2] < err[1] < err[0]
    # pose source truth: measured and true errors are the same numbers
    np.testing.assert_array_equal(err, res.column("true_max_position_error"))
    assert res.xi[2].shape == (3, 61, 3) and res.samples == 180
    assert len(res.contacts) == len(res.clearance) == 3 and max(res.tilt) < 0.1
    assert res.memory is not None and np.abs(res.memory).max() > 0


def test_odometry_pose_differs_from_truth():
    res = run_physics(short_triangle(40), MODELS["p3dx"], 1, pose="odometry")
    meas, true = res.column("max_position_error"), res.column("true_max_position_error")
    assert np.isfinite(meas).all() and meas[0] != true[0]
    with pytest.raises(ValueError, match="pose must be one of truth, odometry"):
        run_physics(short_triangle(40), MODELS["p3dx"], 1, pose="gps")
