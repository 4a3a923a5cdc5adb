"""Physics robots driven through the generic base bridge, in wall-clock trials.

``formation-ilc launch --plant base --physics-bases``: P3-DX-size physics robots expose
``cmd_vel`` and wheel odometry like any base; one bridge per robot, with the TurtleBot 4
preset's limits, drives them. A scenario too fast for those limits is refused with one
line; stretched with ``--time-scale`` it runs, it learns, and no command to a base exceeds
the limits (read back from the recording). The simulated bases tell their bridges the
true poses: the metrics' true columns, and the pose the bridges sample and return on (the
rehearsal's motion capture, ``--pose truth``), though a second process sends every base's
true pose again 1 km away (refused, counted by sender); the bases' wheel odometry drifts.
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

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402

import msgs_schema as ms  # noqa: E402
from formation_ilc.config.bases import BASES  # noqa: E402
from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.core.metrics import METRIC_COLUMNS, read_metrics  # noqa: E402
from formation_ilc.recordings.mcap_io import read_messages  # noqa: E402

from ..procs import end_forger, stop_group  # noqa: E402
from .shared import RUNS  # noqa: E402
from .test_stack import launch  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess, pytest.mark.slow]

TB4 = BASES["turtlebot4"].limits


def base_key(scenario: str, scale: str) -> tuple[str, tuple[str, ...]]:
    """The shared run of the TurtleBot 4 physics bases on ``scenario`` stretched ``scale``
    times (no noise, 40 s returns)."""
    return "base", (scenario, scale)


def test_too_fast_for_the_base_is_refused_then_runs_stretched(ros_env, tmp_path):
    scen = tmp_path / "short.yaml"
    scen.write_text(load_scenario("paper-triangle3").text.replace("samples: 140",
                                                                  "samples: 40"))
    common = [str(scen), "--plant", "base", "--base", "turtlebot4", "--physics-bases",
              "--no-noise", "--trials", "3"]
    res = launch(ros_env, tmp_path / "refused", *common, timeout=120.0)
    assert res.returncode == 2, res.stdout
    errors = [x for x in res.stdout.splitlines() if x.startswith("error:")]
    assert len(errors) == 1, res.stdout
    assert "exceeds its limit 0.306 m/s; --time-scale " in errors[0]
    assert errors[0].startswith("error: robot ")
    scale = errors[0].rsplit("--time-scale ", 1)[1].split()[0]

    rec = tmp_path / "run.mcap"
    # a second process sends, from trial 1 on, a copy of every base's true pose 1 km away
    # (before, the bridges took them: the true error read 63.9 m, exit 0): only the
    # physics bases' are taken, the forgeries counted by sender
    second = subprocess.Popen([sys.executable, str(Path(__file__).with_name("forger.py")),
                               "--truth", "1"], env=ros_env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        res = launch(ros_env, tmp_path / "run", *common, "--time-scale", scale,
                     "--return-timeout", "40", "--record", str(rec), timeout=900.0)
        said = end_forger(second)
    finally:
        stop_group(second)
    assert res.returncode == 0, res.stdout
    forged = [json.loads(ln) for ln in said.splitlines() if ln.startswith("{")]
    assert [d["forged"] for d in forged] == ["truth"] and forged[0]["count"] > 20, said
    truth_topics = forged[0]["topics"]
    assert len(truth_topics) == 3, said
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    refused = sum(by.get("/forger/forger", 0) for rep in summary["forged"].values()
                  for t, by in rep.items() if t in truth_topics)
    assert refused >= forged[0]["count"] // 2, summary["forged"]
    got = read_metrics(tmp_path / "run" / "metrics.csv")
    assert len(got) == 3 and got[-1, 1] < got[0, 1]  # it learns
    # the insecure run a secure one is compared with (tests/stack/test_secure.py)
    RUNS[base_key(scen.read_text(), scale)] = got
    # the simulated bases' truth: the true columns, and (--pose truth, the default) the
    # pose the bridges sample, as motion capture would give it: the measured columns equal
    # them, while the bases' wheel odometry drifted (their diagnostics)
    assert summary["true_state"] is True
    assert "m true, " in res.stdout  # the console shows both
    cols = {c: i for i, c in enumerate(METRIC_COLUMNS)}
    true_pos, pos = got[:, cols["true_max_position_error"]], got[:, cols["max_position_error"]]
    assert np.isfinite(true_pos).all() and np.isfinite(
        got[:, cols["true_max_heading_error"]]).all()
    # every trial's contacts counted, the last too (the bases say them on their wall
    # clock, at times after the robots' trajectories made the row: it takes them then)
    assert (got[:, cols["contacts"]] == 0).all(), got[:, cols["contacts"]]
    for b in summary["bridges"].values():
        # the P3-DX-size body pitches a few degrees as it brakes: inside the 10 deg bound
        assert b["limits"][0] == TB4.v_max and 0 < b["tilt_max_deg"] < 10.0
    # what the bases were asked, as recorded: never beyond the limits (accelerations on the
    # commands' stamps, which the bridge limits on)
    diags = [ms.msg_to_report(ms.deserialize(m.data, DiagnosticArray), ("node",))
             for m in read_messages(rec, {"/formation/diagnostics"})]
    bases = [d for d in diags if d["node"] == "physics_bases"]
    assert bases, "the physics bases' diagnostics are in the recording"
    seen = bases[-1]["commands_max"]
    assert len(seen) == 3
    drift = max(bases[-1]["odometry_drift"].values())
    assert 0 < drift
    np.testing.assert_array_equal(true_pos, pos)
    for c in seen.values():
        assert 0.1 < c["v"] <= TB4.v_max + 1e-12 and c["omega"] <= TB4.omega_max + 1e-12
        assert c["a"] <= TB4.a_max * (1 + 1e-9) and c["alpha"] <= TB4.alpha_max * (1 + 1e-9)


def _collision_memory(sc):
    """A memory that drives robots 2 and 3 of paper-triangle3 (side by side, 1.4 m
    apart, both facing +x) on arcs into each other, inside a P3-DX's limits (speed and
    turn rate ramped in); robot 1 (ahead of them, facing away) drives off, out of the
    way of their returns."""
    n_t = sc.samples
    mem = np.zeros((sc.n, n_t, 2))
    ramp = np.minimum(1.0, np.arange(n_t) / 8.0)
    mem[0, :, 0] = 0.3 * ramp
    mem[1, :, 0] = mem[2, :, 0] = 0.4 * ramp
    mem[1, :, 1], mem[2, :, 1] = -0.6 * ramp, 0.6 * ramp
    return mem


def test_a_contact_of_the_physics_bases_is_said_counted_and_ends_the_run(ros_env, tmp_path):
    """The rehearsal catches a contact (issue 37): two physics bases driven into each other
    (no filter) are said on the console the moment they touch, the leader aborts the trial
    the bases asked it to, the trial runs again and touches again, and with its retry spent
    the run ends with status 6. The contacts are counted per trial (summary.json's
    physics block; the ending contact a field of summary.json and a row of metrics.csv)."""
    from formation_ilc.store.memoryfile import save_memory

    scen = tmp_path / "short.yaml"
    scen.write_text(load_scenario("paper-triangle3").text.replace("samples: 140",
                                                                  "samples: 40"))
    sc = load_scenario(str(scen)).with_options(noise=False)
    mem = save_memory(tmp_path / "crash.npz", _collision_memory(sc), sc)
    res = launch(ros_env, tmp_path / "run", str(scen), "--plant", "base", "--base", "p3dx",
                 "--physics-bases", "--no-noise", "--no-safety", "--allow-contact",
                 "--init-memory", str(mem), "--trials", "3", "--contact-retries", "1",
                 "--return-timeout", "15", timeout=600.0)
    out = res.stdout
    assert res.returncode == 6, out
    said = [x for x in out.splitlines() if x.startswith("contact: ")]
    # the first contact of trial 0 (slot 0): stopped, the trial runs again (slot 1)
    assert said and said[0].startswith("contact: trial 0 (slot 0), t = "), out
    assert "robots 2 and 3 in contact" in said[0] and said[0].endswith(
        "the robots are stopped and the trial runs again (physics_bases)"), out
    ending = [x for x in said if "(slot 1)" in x and "the run ends (retries spent)" in x]
    assert ending, out
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    ended = summary["ended_by_contact"]
    assert ended["node"] == "physics_bases" and ended["action"] == "give_up"
    assert ended["trial"] == 0 and ended["slot"] == 1 and ended["phase"] == "trial"
    assert [p[:2] for p in ended["pairs"]] == [[2, 3]]
    physics = summary["physics"]
    assert "robot_2-robot_3" in physics["contacts_by_trial"]["0"]
    # every contact said is counted, the one that ended the run too (the bases' last
    # report, sent as the run ends, was refused as stale: it named trial -1)
    assert physics["contact_events"] == len(said) >= 2, (physics, said)
    rows = read_metrics(tmp_path / "run" / "metrics.csv")
    cols = {c: i for i, c in enumerate(METRIC_COLUMNS)}
    assert rows.shape[0] == 1 and rows[0, 0] == 0 and rows[0, cols["contacts"]] == 1
    assert np.isnan(rows[0, cols["max_position_error"]])  # the robots stood: no errors
