"""Robots whose clocks disagree (issue 29), in real processes: each robot's clock emulated
(``--clock-offset-ms 300 --clock-drift-ppm 100``), the estimates made from the stamps the
nodes exchange, and what the estimator changes.

* realtime (the simulator samples every robot at once): every link's one-way delay,
  corrected by the receiver's estimate, is within 2 ms of the true delay; as the clocks
  read it (``--no-clock-sync``) it is off by the offsets; the learning is the run without
  offsets' (the labels of eq. 11 are the plant's; the robots' clocks enter only their send
  and receive times). The same across network namespaces (``--hosts netns``).
* wall-clock (bridges in front of fake drivers): with the estimator every bridge samples
  at the leader's instants, whatever its own clock reads; without it each samples at its
  own clock's, off by its offset.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.metrics import read_metrics
from formation_ilc.model.simulate import simulate
from tests.stack.test_realtime import short_scenario
from tests.stack.test_stack import launch

pytestmark = [pytest.mark.ros, pytest.mark.multiprocess, pytest.mark.slow]

#: the run's seed: robots 1, 2, 3 read -247, -155 and +158 ms at the start
#: (``EmulatedClock.seeded``), so every link's offset is tens of milliseconds or more
SEED = 7
TRIALS = 3
CLOCKS = ("--clock-offset-ms", "300", "--clock-drift-ppm", "100")
#: realtime direct runs against the batch simulator without delay: what the suite allows
#: a realtime run (a missed sample holds a command; tests/stack/test_realtime.py)
RT_ATOL = 0.05
#: [ms] the corrected delays' error the issue asks for
WITHIN_MS = 2.0


def realtime(ros_env, out: Path, scen: Path, *extra: str):
    res = launch(ros_env, out, str(scen), "--trials", str(TRIALS), "--seed", str(SEED),
                 "--mode", "realtime", "--links", "direct", *extra, timeout=300)
    assert res.returncode == 0, res.stdout
    return res


def delay_columns(out: Path) -> dict[str, dict[str, str]]:
    """delays.csv's one-way delays [ms] by link (the same on each row of a link)."""
    with (out / "delays.csv").open() as fh:
        return {r["link"]: {k: r[k] for k in ("measured_ms", "corrected_ms", "injected_ms")}
                for r in csv.DictReader(fh)}


def true_offsets(out: Path) -> dict[str, float]:
    """The emulated truth (summary.json): the sender's clock minus the receiver's [ms], by
    link, at the run's end."""
    summary = json.loads((out / "summary.json").read_text())
    return {link: c["true_offset_ms"] for link, c in summary["clocks"]["links"].items()}


def check_learning(out: Path, scen: Path) -> np.ndarray:
    got = read_metrics(out / "metrics.csv")
    sc = load_scenario(str(scen)).with_options(seed=SEED)
    ref = simulate(sc.with_options(delay=False), trials=TRIALS).metrics
    assert got.shape[0] == TRIALS
    np.testing.assert_allclose(got[:, 1:3], ref[:, 1:3], rtol=0, atol=RT_ATOL)
    return got


def check_estimated(out: Path) -> None:
    """Every link's corrected delay within WITHIN_MS of the true one: the median in
    delays.csv; and since the estimate converged, no answer's corrected delay shorter than
    the injected one by more (diagnostics' ``early_max_ms``: a loaded machine delivers
    late, never early, so only the estimate can err that way)."""
    cols = delay_columns(out)
    assert set(cols) == {"leader->robot_1", "robot_1->robot_2", "robot_1->robot_3"}
    offsets = true_offsets(out)
    diag = json.loads((out / "diagnostics.json").read_text())
    for link, c in cols.items():
        sender, receiver = link.split("->")
        measured, corrected, true = (float(c[k]) for k in ("measured_ms", "corrected_ms",
                                                            "injected_ms"))
        assert abs(corrected - true) <= WITHIN_MS, (link, c)
        # as the clocks read it the delay is off by the offset (seeded: tens of ms or more)
        assert abs(offsets[link]) > 20.0
        assert abs(measured - true + offsets[link]) <= WITHIN_MS, (link, c, offsets[link])
        block = diag[receiver]["clock"]["peers"][sender]
        assert block["converged"] and block["delay"]["n"] >= 20, block
        assert block["delay"]["early_max_ms"] <= WITHIN_MS, block
        assert abs(block["offset_ms"] - block["true_offset_ms"]) <= block["uncertainty_ms"]
        assert diag[receiver]["clock"]["warn"] == []


def test_realtime_clocks_that_disagree_are_estimated_and_change_nothing_learned(
        ros_env, tmp_path):
    scen = short_scenario(tmp_path)
    off = tmp_path / "offsets"
    res = realtime(ros_env, off, scen, *CLOCKS)
    assert "clocks (the receiver's estimate of the sender's clock" in res.stdout
    check_estimated(off)
    with_offsets = check_learning(off, scen)
    # the same run with the machine's clock
    plain = tmp_path / "plain"
    realtime(ros_env, plain, scen)
    without = check_learning(plain, scen)
    print("max position error per trial, offsets:", with_offsets[:, 1].round(4).tolist())
    print("max position error per trial, none   :", without[:, 1].round(4).tolist())
    np.testing.assert_allclose(with_offsets[:, 1:3], without[:, 1:3], rtol=0,
                               atol=2 * RT_ATOL)
    cols = delay_columns(plain)
    for link, c in cols.items():  # one clock: as read is as true, and nothing is emulated
        assert abs(float(c["measured_ms"]) - float(c["corrected_ms"])) <= WITHIN_MS, link
        assert c["injected_ms"] == ""
    # the estimator switched off: the delays stay as the clocks read them, off by the
    # offsets; nothing is corrected
    raw = tmp_path / "no-sync"
    res = realtime(ros_env, raw, scen, *CLOCKS, "--no-clock-sync")
    assert "estimator off, --no-clock-sync" in res.stdout
    offsets = true_offsets(raw)
    for link, c in delay_columns(raw).items():
        assert c["corrected_ms"] == ""
        error = float(c["measured_ms"]) - float(c["injected_ms"])
        assert abs(error + offsets[link]) <= WITHIN_MS and abs(error) > 20.0, (link, c)
    check_learning(raw, scen)


def test_realtime_clocks_across_network_namespaces(netns_support, ros_env, tmp_path):
    """The same with each robot on a simulated host of its own (UDP between them)."""
    scen = short_scenario(tmp_path)
    out = tmp_path / "run"
    res = launch(ros_env, out, str(scen), "--trials", str(TRIALS), "--seed", str(SEED),
                 "--mode", "realtime", "--hosts", "netns", *CLOCKS, timeout=300)
    assert res.returncode == 0, res.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["mode"] == "realtime" and len(summary["hosts"]["namespaces"]) >= 3
    check_estimated(out)
    check_learning(out, scen)


def wall_scenario(tmp: Path) -> Path:
    """paper-triangle3 shortened to 60 samples of 0.1 s (6 s a trial: the bridges return
    quickly)."""
    data = yaml.safe_load(load_scenario("paper-triangle3").text)
    data.update(dt=0.1, samples=60, name="triangle3-wall")
    path = tmp / "triangle3-wall.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def bridges(out: Path) -> dict[str, dict]:
    return json.loads((out / "summary.json").read_text())["clocks"]["bridges"]


def test_bridges_sample_at_the_leaders_instants_whatever_their_clocks_read(ros_env,
                                                                           tmp_path):
    scen = wall_scenario(tmp_path)
    args = (str(scen), "--plant", "pioneer", "--fake-drivers", "--no-noise", "--no-delay",
            "--trials", "1", "--return-timeout", "30", "--seed", str(SEED), *CLOCKS)
    out = tmp_path / "sync"
    res = launch(ros_env, out, *args, timeout=300)
    assert res.returncode == 0, res.stdout
    lags = {}
    diag = json.loads((out / "diagnostics.json").read_text())
    for b, c in bridges(out).items():
        assert c["converged"] and abs(c["offset_ms"] - c["true_offset_ms"]) <= WITHIN_MS
        assert set(c["sampled_on"]) == {"converged"}, c  # every sample on the estimate
        # each of the 61 instants sampled once or counted missed: a control tick that fell
        # behind past an instant (CI's three test processes on two cores: 3 of 61 once)
        # skips it rather than sampling late; rare, or the lags below say nothing
        missed = diag[b]["missed"]
        assert c["sample_lag_ms"]["n"] + missed == 61, (c["sample_lag_ms"], missed)
        assert missed <= 6, missed
        lags[b] = c["sample_lag_ms"]
    # each sample within a control tick (10 ms) and the estimate's error of the instant
    for b, lag in lags.items():
        assert -WITHIN_MS <= lag["min"] and lag["p50"] <= 10.0 + WITHIN_MS, (b, lag)
    # without the estimator each bridge samples on its own clock: off by its offset
    out = tmp_path / "own"
    res = launch(ros_env, out, *args, "--no-clock-sync", timeout=300)
    assert res.returncode == 0, res.stdout
    truth = json.loads((out / "summary.json").read_text())["clocks"]["truth"]
    for b, c in bridges(out).items():
        assert set(c["sampled_on"]) == {"own"}, c
        offset = truth[b.replace("bridge", "robot")]["offset_ms"]
        # a clock ahead samples early: the lag is minus its offset (within a tick)
        assert abs(offset) > 20.0
        assert -offset - WITHIN_MS <= c["sample_lag_ms"]["p50"] <= -offset + 10.0 + \
            WITHIN_MS, (b, c["sample_lag_ms"], offset)
