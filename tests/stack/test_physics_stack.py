"""The physics plant behind the plant contract: a lockstep formation in PyBullet.

``formation-ilc launch --plant physics`` runs the leader, the physics node and one process
per robot; the recording is analysed afterwards. The contact check refuses a run whose
cold start the batch simulator predicts will drive robots through each other.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

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

from ..procs import end_forger, stop_group  # noqa: E402
from .shared import RUNS
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
    # the insecure run a secure one is compared with (tests/stack/test_secure.py)
    RUNS[("physics", (scen.read_text(),))] = got
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
    engine = run_physics(sc, MODELS["p3dx"], 3).metrics[:, 1:7]
    kinematic = simulate(sc, trials=3, plant="arc").metrics[:, 1:7]
    assert np.abs(got[:, 1:7] - engine).max() < 2e-3
    assert np.abs(got[:, 1:7] - kinematic).max() > 2 * np.abs(got[:, 1:7] - engine).max()
    # the filter is on with bodies; this short start keeps its distance: it never acted
    assert (got[:, 7] == 0).all() and (got[:, 8] == 0).all()
    # the recording holds the run: analysed alone, it gives the launcher's metrics
    assert main(["analyze", str(rec), "--out", str(tmp_path / "an")]) == 0
    np.testing.assert_array_equal(read_metrics(tmp_path / "an" / "metrics.csv"), got)
    r = load_recording(rec)
    assert r.scenario.headings == "arc"  # a plant that drives arcs gets arc headings


def test_colliding_cold_start_is_refused(ros_env, tmp_path):
    res = launch(ros_env, tmp_path / "run", "paper-triangle3", "--plant", "physics",
                 "--trials", "20", "--no-noise", "--no-delay", "--no-safety", timeout=120.0)
    assert res.returncode == 2, res.stdout
    line = [x for x in res.stdout.splitlines() if x.startswith("error:")]
    assert len(line) == 1, res.stdout
    assert line[0].startswith("error: the batch simulator predicts contact from this cold "
                              "start (u_0 = 0): trial 1: robots 2 and 3 overlap by 0.13")
    assert "--init-memory" in line[0] and "--allow-contact" in line[0]
    assert "--safety" in line[0]
    assert not (tmp_path / "run" / "logs" / "physics_sim.log").exists()  # nothing started


def test_a_cold_start_on_bodies_learns_through_the_safety_filter(ros_env, tmp_path):
    """paper-triangle3 from u = 0 on P3-DX-size bodies, the filter on (the default with
    bodies): no contact, the filter acts in the transient, and the stack's errors and
    filter counts are the one-process physics study's through the same filter."""
    from formation_ilc.config.safety import SafetySettings, default_motion
    from formation_ilc.model.safety import spec_of

    rec = tmp_path / "run.mcap"
    # a second process sends, from trial 1 on, every robot's team poses 1 km away, one
    # sample ahead of the plant (before, the filters took them and let robots 2 and 3
    # touch): only the plant's are taken, the forgeries counted by sender
    second = subprocess.Popen([sys.executable, str(Path(__file__).with_name("forger.py")),
                               "--team-poses", "1"], env=ros_env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        res = launch(ros_env, tmp_path / "run", "paper-triangle3", "--plant", "physics",
                     "--trials", "3", "--no-noise", "--no-delay", "--record", str(rec),
                     timeout=600.0)
        said = end_forger(second)
    finally:
        stop_group(second)
    assert res.returncode == 0, res.stdout
    forged = [json.loads(ln) for ln in said.splitlines() if ln.startswith("{")]
    assert [d["forged"] for d in forged] == ["team_poses"] and forged[0]["count"] > 20, said
    assert "predicts no contact in the 3 trials of this run through the safety filter" \
        in res.stdout
    got = read_metrics(tmp_path / "run" / "metrics.csv")
    assert (got[:, 8] == 0).all()  # contacts: none
    filtered = got[:, 7]
    assert filtered[0] == 0 and filtered[1:].sum() > 0
    assert "true," in res.stdout and "filtered" in res.stdout  # truth beside measured
    sc = load_scenario("paper-triangle3").with_options(noise=False, delay=False)
    # the launch's filter: speeds told (``default_motion``), on robot_i/applied
    spec = spec_of(SafetySettings("p3dx", MODELS["p3dx"].limits, motion=default_motion(3)),
                   sc.dt)
    study = run_physics(sc, MODELS["p3dx"], 3, safety=spec)
    assert np.abs(got[:, 1:7] - study.metrics[:, 1:7]).max() < 0.02
    assert abs(filtered.sum() - sum(study.filtered)) <= 0.3 * sum(study.filtered)
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    for i in (1, 2, 3):
        by = summary["forged"][f"robot_{i}"]["/formation/team/poses"]
        assert by["/forger/forger"] >= forged[0]["count"] // 2, summary["forged"]
    assert "forged: " in res.stdout
    # the recording gives the launcher's rows back, counts included
    assert main(["analyze", str(rec), "--out", str(tmp_path / "an")]) == 0
    np.testing.assert_array_equal(read_metrics(tmp_path / "an" / "metrics.csv"), got)


def test_contacts_are_said_at_once_counted_and_acted_on(ros_env, tmp_path):
    """Without the filter, the cold start's robots touch in trial 1. continue: said on
    the console the moment it happens and counted in metrics.csv; stop: the robots are
    stopped and the leader aborts the trial, which runs again (deterministic here, so it
    touches again), and with the retries spent the run ends with status 6 naming the
    pair."""
    res = launch(ros_env, tmp_path / "go", "paper-triangle3", "--plant", "physics",
                 "--trials", "2", "--no-noise", "--no-delay", "--no-safety",
                 "--allow-contact", "--on-contact", "continue", timeout=600.0)
    assert res.returncode == 0, res.stdout
    said = [x for x in res.stdout.splitlines() if x.startswith("contact: trial 1 (slot 1)")]
    assert said and "robots 2 and 3 in contact" in said[0] and "going on" in said[0]
    lines = res.stdout.splitlines()
    assert lines.index(said[0]) < next(i for i, x in enumerate(lines)
                                       if x.startswith("trial 1 of 0..1"))  # before the row
    got = read_metrics(tmp_path / "go" / "metrics.csv")
    assert got[0, 8] == 0 and got[1, 8] >= 1
    res = launch(ros_env, tmp_path / "stop", "paper-triangle3", "--plant", "physics",
                 "--trials", "2", "--no-noise", "--no-delay", "--no-safety",
                 "--allow-contact", "--contact-retries", "1", timeout=600.0)
    assert res.returncode == 6, res.stdout
    said = [x for x in res.stdout.splitlines() if x.startswith("contact: trial 1")]
    assert len(said) == 2 and "runs again" in said[0] and "the run ends" in said[1], said
    assert "(slot 1)" in said[0] and "(slot 2)" in said[1]  # aborted, run in a new slot
    err = [x for x in res.stdout.splitlines() if x.startswith("error: ")]
    assert len(err) == 1 and "robots 2 and 3 in contact" in err[0], res.stdout
    assert "ending the run" in err[0]
    got = read_metrics(tmp_path / "stop" / "metrics.csv")
    # trial 1 never finished: its row is the contact that ended the run (the pair that
    # touched, no errors), and summary.json names it
    assert [int(k) for k in got[:, 0]] == [0, 1]
    assert got[1, 8] == 1 and np.isnan(got[1, 1:8]).all()
    ended = json.loads((tmp_path / "stop" / "summary.json").read_text())["ended_by_contact"]
    assert ended["trial"] == 1 and ended["slot"] == 2 and ended["action"] == "give_up"
    assert ended["node"] == "physics_sim" and [p[:2] for p in ended["pairs"]] == [[2, 3]]
