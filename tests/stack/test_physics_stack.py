"""The physics plant behind the plant contract: a lockstep formation in PyBullet.

``formation-ilc launch --plant physics`` runs the leader, the physics node and one process
per robot; the recording is analysed afterwards. The contact check refuses a run whose
cold start the batch simulator predicts will drive robots through each other.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("pybullet", reason="the physics extra: pip install -e .[physics]")
pytest.importorskip("mcap_ros2")

from formation_ilc.cli import main  # noqa: E402
from formation_ilc.config.scenario import load_scenario, scenario_from_text  # noqa: E402
from formation_ilc.core.metrics import read_metrics  # noqa: E402
from formation_ilc.model.physics import MODELS  # noqa: E402
from formation_ilc.model.simulate import simulate  # noqa: E402
from formation_ilc.recordings.recording import load_recording  # noqa: E402
from formation_ilc.studies.physics import run_physics  # noqa: E402

from .test_stack import launch  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess]


def short_triangle(path):
    """paper-triangle3 cut to 60 samples (12 s): its cold start keeps 0.7 m of clearance."""
    text = load_scenario("paper-triangle3").text.replace("samples: 140", "samples: 60")
    path.write_text(text)
    return path


def test_lockstep_physics_learns_from_the_engine_recorded_and_analysed(ros_env, tmp_path):
    scen = short_triangle(tmp_path / "short.yaml")
    rec = tmp_path / "run.mcap"
    res = launch(ros_env, tmp_path / "run", str(scen), "--plant", "physics", "--trials", "3",
                 "--no-noise", "--no-delay", "--links", "direct", "--record", str(rec),
                 timeout=600.0)
    assert res.returncode == 0, res.stdout
    got = read_metrics(tmp_path / "run" / "metrics.csv")
    err = got[:, 1]
    assert len(got) == 3 and err[2] < err[1] < err[0]
    # ground truth as the pose: measured and true columns are the engine's, both finite
    np.testing.assert_array_equal(got[:, 1], got[:, 3])
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["plant"] == ["physics_sim"] and summary["true_state"]
    assert summary["physics"]["model"] == "p3dx" and summary["physics"]["substeps"] == 48
    assert summary["physics"]["contacts_by_trial"] == {}
    assert all(0 < t < 0.05 for t in summary["physics"]["tilt_by_trial"].values())
    # the same law against the same engine in one process: the stack's errors are the
    # engine's. Not to round-off: poses cross the wire with headings as quaternions (an
    # ulp) and the contact solver turns that into up to 1e-3 m over 3 trials; the exact-arc
    # kinematic model, the closest plant without bodies, is several times further away
    sc = scenario_from_text(scen.read_text(), str(scen)).with_options(noise=False,
                                                                        delay=False)
    engine = run_physics(sc, MODELS["p3dx"], 3).metrics[:, 1:]
    kinematic = simulate(sc, trials=3, plant="arc").metrics[:, 1:]
    assert np.abs(got[:, 1:] - engine).max() < 2e-3
    assert np.abs(got[:, 1:] - kinematic).max() > 2 * np.abs(got[:, 1:] - engine).max()
    # the recording holds the run: analysed alone, it gives the launcher's metrics
    assert main(["analyze", str(rec), "--out", str(tmp_path / "an")]) == 0
    np.testing.assert_array_equal(read_metrics(tmp_path / "an" / "metrics.csv"), got)
    r = load_recording(rec)
    assert r.scenario.headings == "arc"  # a plant that drives arcs gets arc headings


def test_colliding_cold_start_is_refused(ros_env, tmp_path):
    res = launch(ros_env, tmp_path / "run", "paper-triangle3", "--plant", "physics",
                 "--trials", "20", "--no-noise", "--no-delay", timeout=120.0)
    assert res.returncode == 2, res.stdout
    line = [x for x in res.stdout.splitlines() if x.startswith("error:")]
    assert len(line) == 1, res.stdout
    assert line[0].startswith("error: the batch simulator predicts contact from this cold "
                              "start (u_0 = 0): trial 1: robots 2 and 3 overlap by 0.13")
    assert "--init-memory" in line[0] and "--allow-contact" in line[0]
    assert not (tmp_path / "run" / "logs" / "physics_sim.log").exists()  # nothing started
