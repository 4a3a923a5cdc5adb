"""The view's numbers (formation_ilc.protocol.view): per-sample errors computed as the
metrics compute them, trial peaks only once every sample of every robot is in, markers
only for a whole team."""

from __future__ import annotations

import math

import numpy as np

from formation_ilc.config.scenario import load_scenario
from formation_ilc.model.simulate import simulate, trial_errors
from formation_ilc.protocol.view import (
    TrackingView,
    graph_links,
    marker_every,
    outline_order,
    run_parameters,
)


def test_peaks_of_a_simulated_trial_are_the_metrics_row():
    sc = load_scenario("paper-triangle3").with_options(seed=2)
    res = simulate(sc, trials=2, keep=(1,))
    rec = res.records[1]
    eta_d = sc.desired.eta
    view = TrackingView(eta_d)
    slot = 7
    for s in range(eta_d.shape[1]):
        for r in range(sc.n):
            view.observe(slot, r, s, rec.eta[r, s])
            if (r, s) == (0, 3):
                view.observe(slot, r, s, rec.eta[r, s])  # sent again: counted once
            if s < eta_d.shape[1] - 1 or r < sc.n - 1:
                assert view.trial_peaks(slot) is None
    peaks = view.trial_peaks(slot)
    assert peaks is not None and view.peaks == {}
    src, w = sc.graph.in_links()
    row = np.empty(6)
    trial_errors(rec.eta, rec.xi, eta_d, src, w, row)
    assert max(p.position for p in peaks) == row[0]
    assert max(p.heading for p in peaks) == row[1]


def test_error_is_desired_minus_measured_and_wrapped():
    eta_d = np.zeros((1, 3, 3))
    eta_d[0, 1] = (3.0, 4.0, math.pi - 0.1)
    view = TrackingView(eta_d)
    pos, head = view.error(0, 1, np.array((0.0, 0.0, -math.pi + 0.1)))
    assert pos == 5.0
    assert math.isclose(head, -0.2, abs_tol=1e-12)
    for bad in ((0, 3), (1, 0), (0, -1)):
        try:
            view.error(bad[0], bad[1], np.zeros(3))
        except ValueError:
            continue
        raise AssertionError(f"{bad} accepted")


def test_markers_wait_for_the_whole_team_and_forget_aborted_slots():
    eta_d = np.zeros((3, 11, 3))
    view = TrackingView(eta_d, every=5)
    assert view.position(0, 0, 3, np.zeros(3)) is None  # not a marker sample
    assert view.position(0, 0, 5, np.array((1.0, 2.0, 0.0))) is None
    assert view.position(0, 1, 5, np.zeros(3)) is None
    team = view.position(0, 2, 5, np.zeros(3))
    assert team == {0: (1.0, 2.0), 1: (0.0, 0.0), 2: (0.0, 0.0)}
    assert view.position(0, 0, 10, np.zeros(3)) is None  # the last sample is one too
    view.observe(0, 0, 1, np.zeros(3))
    view.forget(0)
    assert view.pending == {} and view.peaks == {}


def test_outline_links_and_marker_period():
    ring = np.array([[math.cos(a), math.sin(a), 0.0] for a in (0.0, 2.0, 4.0, 1.0, 3.0, 5.0)])
    order = outline_order(ring)
    angles = [math.atan2(ring[i, 1], ring[i, 0]) for i in order]
    assert angles == sorted(angles) and sorted(order) == list(range(6))
    assert graph_links(np.array([[-1, -1], [0, -1], [0, 1]])) == [(0, 1), (0, 2), (1, 2)]
    assert marker_every(0.5) == 1 and marker_every(0.1) == 5 and marker_every(0.0) == 1


def test_the_run_s_parameters_are_the_leader_s_named_as_foxglove_bridge_names_them():
    """What the live view's parameters capability serves: the leader's parameters, which
    give back the run's configuration (RunConfig.from_params), under /NS/virtual_leader."""
    from formation_ilc.config.runconfig import RunConfig, make_config

    cfg = make_config("paper-triangle3", trials=7, seed=3, run_id="rview")
    got = run_parameters(cfg, "/formation")
    assert got["/formation/virtual_leader.trials"] == 7
    assert got["/formation/virtual_leader.seed"] == 3
    assert got["/formation/virtual_leader.run_id"] == "rview"
    prefix = "/formation/virtual_leader."
    assert all(k.startswith(prefix) for k in got)
    back = RunConfig.from_params({k[len(prefix):]: v for k, v in got.items()})
    assert back.scenario.trials == 7 and back.run_id == "rview"
    assert run_parameters(cfg, "/lab/", ["/lab/virtual_leader.seed", "/lab/nope"]) == {
        "/lab/virtual_leader.seed": 3}
