"""tune: guarantees hold for what it picks, the written file reproduces the report, and on
paper-hexagon6 it meets issue 9's targets (slow)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from formation_ilc.cli import main
from formation_ilc.config.scenario import load_scenario
from formation_ilc.model.checks import condition20, heading_map
from formation_ilc.model.simulate import simulate
from formation_ilc.studies.study import reduce_metrics
from formation_ilc.studies.tune import TuneOptions, graph_depths, tune


def test_graph_depths():
    assert graph_depths(load_scenario("paper-hexagon6")).tolist() == [1, 2, 2, 1, 2, 2]
    assert graph_depths(load_scenario("paper-triangle3")).tolist() == [1, 2, 2]


def _small() -> TuneOptions:
    return TuneOptions(seeds=(1, 2), screen_trials=25, verify_trials=40, floor_window=10,
                       floor_factor=3.0, finalists=2, gain_grid=(0.1, 0.2),
                       prime_grid=(0.1, 0.2), max_growth=10.0)


def test_tune_keeps_its_guarantees(tmp_path):
    sc = load_scenario("paper-triangle3")
    opt = _small()
    res = tune(sc, opt, workers=1, log=lambda m: None)
    assert res.best is not None
    best = res.best
    # every finalist was checked, and keeps condition (20) and the transient bound
    for c in res.finalists:
        assert c.cond20 < 1 and c.rho < 1 and c.growth <= res.max_growth
    # recomputed independently of the tuner
    tuned = sc.with_options()
    from dataclasses import replace

    tuned = replace(sc, law=replace(sc.law, gain=best.gain, gain_prime=best.gain_prime))
    assert condition20(tuned.graph, np.asarray(best.gain), tuned.dt) == pytest.approx(best.cond20)
    hm = heading_map(tuned, early_stop=True)
    assert hm is not None and hm.spectral_radius == pytest.approx(best.rho)
    # per graph depth: robots 2 and 3 (depth 2) share a pair
    assert best.gain[1] == best.gain[2] and best.gain_prime[1] == best.gain_prime[2]
    if res.ok:
        worst = max(max(r["trials_to_position"], r["trials_to_heading"]) for r in best.rows)
        base = [r["trials_to_position"] for r in res.baseline.rows]
        assert all(b is None or b >= worst for b in base)


def test_cli_tune_file_reproduces_report(tmp_path):
    out = tmp_path / "o"
    rc = main(["tune", "paper-triangle3", "--gain-grid", "0.1,0.2", "--prime-grid",
               "0.1,0.2", "--seeds", "2", "--verify-trials", "40",
               "--screen-trials", "25", "--floor-window", "10", "--floor-factor", "3",
               "--max-growth", "10",
               "--workers", "1", "--out", str(out)])
    assert rc in (0, 1)
    report = json.loads((out / "tune.json").read_text())
    assert (out / "report.md").read_text().startswith("# Tuning paper-triangle3")
    tuned = report["tuned"]
    assert tuned is not None
    sc = load_scenario(out / "paper-triangle3-tuned.yaml")  # the strict loader
    assert list(sc.law.gain) == tuned["gain"] and list(sc.law.gain_prime) == tuned["gain_prime"]
    rows = [reduce_metrics(simulate(sc.with_options(seed=s, trials=40)).metrics, 1.0, 0.1, 10)
            for s in tuned["seeds"]]
    for key in ("trials_to_position", "trials_to_heading", "floor_position", "floor_heading",
                "peak_position", "trial0_position", "above_trial0"):
        vals = [r[key] for r in rows]
        if any(v is None for v in vals):
            assert tuned[key] == vals, key
        else:
            assert tuned[key] == [min(vals), max(vals)], key  # exactly, not approximately


@pytest.mark.slow
@pytest.mark.multiprocess  # a pool of worker processes, about 2 minutes on 2 cores
def test_tune_hexagon_meets_issue_targets(tmp_path):
    """Issue 9: >= 30x fewer trials than gain 0.08 to 1 m and 0.1 rad (<= 14 and <= 24), no
    trial above trial 0, floors within 1.5x of the paper gain's, over seeds 1..5."""
    sc = load_scenario("paper-hexagon6")
    res = tune(sc, TuneOptions(), log=lambda m: None)
    assert res.ok, res.reason
    b = res.best
    assert b is not None
    assert b.worst("trials_to_position") <= 14 and b.worst("trials_to_heading") <= 24
    assert b.worst("above_trial0") == 0
    assert b.worst("floor_position") <= 1.5 * res.baseline.median("floor_position")
    assert b.worst("floor_heading") <= 1.5 * res.baseline.median("floor_heading")
    # not merely the scaled paper gain: per-depth pairs with g != g'
    assert len(set(b.gain)) > 1 or len(set(b.gain_prime)) > 1 or b.gain != b.gain_prime


def test_tune_says_when_nothing_qualifies():
    sc = load_scenario("paper-triangle3")
    opt = TuneOptions(seeds=(1,), screen_trials=2, verify_trials=20, floor_window=5,
                      gain_grid=(0.1,), prime_grid=(0.1,), max_growth=10.0)
    res = tune(sc, opt, workers=1, log=lambda m: None)
    assert not res.ok and res.best is None
    assert "within 2 trials" in res.reason
