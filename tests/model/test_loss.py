"""Lost messages: a neighbour sample that never arrives drops that link from the current
term for that sample only; the trial-end exchange still fills the predictive term.

The scenario's ``delay: loss: p`` makes every link lose each sample with probability p, drawn
from a stream of its own (a lossless scenario draws exactly what it always did). The batch
simulator and the link emulator of the stack draw the same losses.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from formation_ilc.config.scenario import ScenarioError, load_scenario, scenario_from_text
from formation_ilc.core.links import LOST
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate

from ..procs import stop_group


def lossy(name: str, loss: float) -> str:
    d = yaml.safe_load(load_scenario(name).text)
    d["delay"]["loss"] = loss
    return yaml.safe_dump(d)


def test_lost_samples_replace_delays_and_leave_the_rest_of_the_stream_alone():
    base = load_scenario("paper-triangle3")
    sc = scenario_from_text(lossy("paper-triangle3", 0.2), "lossy.yaml")
    n, n_l = base.n, 1
    t0, l0 = base.uncertainty.draw_delays(3, 4, n, n_l, base.samples)
    t1, l1 = sc.uncertainty.draw_delays(3, 4, n, n_l, base.samples)
    lost = t1 == LOST
    assert 0.17 < lost.mean() < 0.23 and 0.15 < (l1 == LOST).mean() < 0.25
    np.testing.assert_array_equal(t1[~lost], t0[~lost])
    np.testing.assert_array_equal(l1[l1 != LOST], l0[l1 != LOST])
    # the plant's draws are untouched
    for a, b in zip(base.uncertainty.draw_plant(3, 4, n, base.samples),
                    sc.uncertainty.draw_plant(3, 4, n, base.samples), strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_team_still_learns_with_20_percent_loss_on_every_link():
    trials = 100
    clean = simulate(load_scenario("paper-triangle3"), trials=trials).metrics
    m = simulate(scenario_from_text(lossy("paper-triangle3", 0.2), "lossy.yaml"),
                 trials=trials).metrics
    floor, floor_clean = np.median(m[-10:, 1]), np.median(clean[-10:, 1])
    assert floor < 0.15 * m[0, 1]                 # 4.5 m -> about 0.44 m
    assert floor < 2.0 * floor_clean              # lossless: about 0.33 m
    assert np.median(m[-10:, 2]) < 0.15 * m[0, 2]  # heading too
    assert np.isfinite(m[:, :8]).all()  # every error, and the filter's count (0)


@pytest.mark.parametrize("bad", [1.0, -0.1, "a lot"])
def test_a_loss_that_is_not_a_probability_is_refused(bad):
    d = yaml.safe_load(load_scenario("paper-triangle3").text)
    d["delay"]["loss"] = bad
    with pytest.raises(ScenarioError, match=r"bad\.yaml: delay\.loss"):
        scenario_from_text(yaml.safe_dump(d), "bad.yaml")


@pytest.mark.ros
@pytest.mark.multiprocess
def test_the_stack_with_lossy_emulated_links_equals_the_batch_simulator(ros_env, tmp_path):
    scen = tmp_path / "lossy.yaml"
    scen.write_text(lossy("paper-triangle3", 0.2))
    trials = 6
    argv = [sys.executable, "-m", "formation_ilc.cli", "launch", str(scen), "--trials",
            str(trials), "--seed", "5", "--out", str(tmp_path / "run"), "--domain-id",
            ros_env["ROS_DOMAIN_ID"], "--no-plots", "--timeout", "20"]
    proc = subprocess.Popen(argv, env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=240)
    finally:
        stop_group(proc)
    assert proc.returncode == 0, out
    got = read_metrics(tmp_path / "run" / "metrics.csv")
    sc = scenario_from_text(lossy("paper-triangle3", 0.2), str(scen)).with_options(seed=5)
    ref = simulate(sc, trials=trials).metrics
    np.testing.assert_allclose(got[:, 1:], ref[:, 1:], rtol=0, atol=1e-9)
    diag = json.loads(Path(tmp_path / "run" / "diagnostics.json").read_text())
    lost = diag["link_emulator"]["lost"]
    ticks = trials * sc.samples
    assert set(lost) == {"leader->robot_1", "robot_1->robot_2", "robot_1->robot_3"}
    for link, count in lost.items():
        assert 0.15 < count / ticks < 0.25, (link, count)
        # what a robot measured on the link plus what was lost covers every tick after the
        # first delays (eq. 11 counts deliveries only)
        robot = link.split("->")[1]
        sender = link.split("->")[0]
        measured = sum(diag[robot]["delays"][sender].values())
        assert measured + count <= ticks and measured + count > ticks - 5 * trials
