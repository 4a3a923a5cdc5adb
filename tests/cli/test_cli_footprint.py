"""simulate's exact-arc plant model, desired headings and footprint clearance."""

import csv
import json

from formation_ilc.cli import main
from formation_ilc.config.scenario import load_scenario
from formation_ilc.model.simulate import simulate


def test_simulate_arc_model_reports_clearance_per_trial(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", "paper-triangle3", "--trials", "6", "--no-noise", "--no-delay",
                 "--plant-model", "arc", "--footprint", "p3dx", "--no-plots",
                 "--out", str(out)]) == 0
    rows = list(csv.DictReader((out / "clearance.csv").open()))
    assert [r["trial"] for r in rows] == [str(k) for k in range(6)]
    # the cold start drives robots 2 and 3 through each other in trial 1
    assert float(rows[1]["least_clearance"]) < 0 < float(rows[0]["least_clearance"])
    assert (rows[1]["robot_i"], rows[1]["robot_j"]) == ("2", "3")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["footprint"]["overlapping_trials"] >= 1
    assert "footprints (p3dx): " in capsys.readouterr().out
    # the arc model with the arc headings auto gives it, as simulate(plant='arc') runs it
    sc = load_scenario("paper-triangle3").with_options(noise=False, delay=False, trials=6)
    ref = simulate(sc, plant="arc").metrics
    got = [float(r["max_position_error"]) for r in csv.DictReader((out / "metrics.csv").open())]
    assert got == list(ref[:, 1])


def test_simulate_refuses_a_bad_time_scale(tmp_path, capsys):
    assert main(["simulate", "paper-triangle3", "--trials", "2", "--time-scale", "0.5",
                 "--out", str(tmp_path / "r")]) == 2
    assert "desired.time_scale: must be in [1, 20]" in capsys.readouterr().err
