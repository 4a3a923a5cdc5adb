from dataclasses import replace

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario, scenario_from_text
from formation_ilc.core.kinematics import wrap_angle
from formation_ilc.model.simulate import (
    METRIC_COLUMNS,
    Problem,
    simulate,
    simulate_bytes,
    simulate_seeds,
    trial_errors,
)


def test_noise_free_hexagon_learns_by_orders_of_magnitude():
    # measured: 14.1 m at trial 0 -> 9.0e-4 m at trial 1999 (seed 1)
    sc = load_scenario("paper-hexagon6").with_options(noise=False, delay=False)
    res = simulate(sc, trials=2000)
    pos = res.column("max_position_error")
    head = res.column("max_heading_error")
    assert pos[0] > 10.0
    assert pos[-1] < 2e-3
    assert pos[0] / pos[-1] > 5e3
    assert head[-1] < 1e-3
    # still learning at the end: measured 7.8e-3 m at trial 1500, 9.0e-4 m at 1999
    assert pos[-1] < pos[-500] / 5


def test_noisy_delayed_hexagon_reaches_the_noise_floor_with_feedforward_memory():
    sc = load_scenario("paper-hexagon6")
    pos = simulate(sc, trials=2000).column("max_position_error")
    # measured noise floor about 0.2-0.3 m (output noise alone is up to 0.05 m per axis)
    assert pos[-1] < 0.5
    assert pos[-200:].max() < 0.6
    assert pos[0] / pos[-1] > 20


def test_literal_memory_diverges_with_noise_and_delay():
    # paper-notes 12: read literally, the law's heading error grows without bound
    sc = load_scenario("paper-hexagon6").with_options(memory="literal")
    pos = simulate(sc, trials=1000).column("max_position_error")
    assert pos[-1] > 100 * pos[0]


def test_predictive_only_law_is_slower_with_larger_transients():
    base = load_scenario("paper-hexagon6")
    p9 = simulate(base, trials=1200).column("max_position_error")
    p22 = simulate(base.with_options(law=22), trials=1200).column("max_position_error")
    # measured (seed 1): peaks 53.8 m vs 40.1 m; trial 300: 24.6 m vs 2.34 m;
    # trial 600: 2.30 m vs 0.54 m
    assert p22.max() > 1.2 * p9.max()
    assert p22[300] > 5 * p9[300]
    assert p22[600] > 3 * p9[600]


def test_same_seed_same_run_other_seed_other_run():
    sc = load_scenario("paper-triangle3")
    a = simulate(sc, trials=5).metrics
    b = simulate(sc, trials=5).metrics
    c = simulate(sc.with_options(seed=2), trials=5).metrics
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    assert a.shape == (5, len(METRIC_COLUMNS))
    np.testing.assert_array_equal(a[:, 0], np.arange(5))


def test_a_run_can_continue_from_a_learned_memory():
    sc = load_scenario("paper-triangle3")
    full = simulate(sc, trials=6)
    first = simulate(sc, trials=3)
    rest = simulate(sc, trials=3, initial_memory=first.memory, first_trial=3)
    np.testing.assert_array_equal(np.vstack([first.metrics, rest.metrics]), full.metrics)


def test_kept_trials_are_consistent_with_metrics():
    sc = load_scenario("paper-triangle3")
    res = simulate(sc, trials=4, keep=[0, 3])
    assert set(res.records) == {0, 3}
    rec = res.records[3]
    err = np.hypot(*(sc.desired.eta[:, 1:, :2] - rec.eta[:, 1:, :2]).transpose(2, 0, 1))
    assert err.max() == pytest.approx(res.column("max_position_error")[3])


def test_seed_batch_equals_separate_runs():
    sc = load_scenario("paper-triangle3")
    batch = simulate_seeds(sc, [1, 2, 3], trials=4)
    for i, s in enumerate([1, 2, 3]):
        one = simulate(sc.with_options(seed=s), trials=4).column("max_position_error")
        np.testing.assert_allclose(batch[i], one, rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------------------
# simulate.py on a tiny team (fast even with the kernels interpreted): the metrics by
# hand, the run's plumbing (kept trials, callbacks, continuation, seeds stacked).

TEXT = """
name: tiny-sim
dt: 0.5
samples: 6
trials: 3
seed: 5
robots: 3
reference: {kind: unicycle, speed: 0.4, turn_radius: 2.0}
formation:
  frame: leader
  offsets:
    1: {x: 0.5, y: 0.0}
    2: {x: 0.0, y: 0.5}
    3: {x: 0.0, y: -0.5}
graph:
  leader: {1: 1.0}
  edges: [{from: 1, to: 2}, {from: 1, to: 3}, {from: 2, to: 3, weight: 0.5}]
law: {kind: 9, gain: 0.3, gain_prime: 0.2}
uncertainty:
  initial_shift: [0.05, 0.05, 0.02]
  disturbance: {uniform: [0.01, 0.01]}
  noise: {uniform: [0.02, 0.02, 0.01]}
delay: {model: uniform, low: 0, high: 2}
"""


@pytest.fixture(scope="module")
def sc():
    return scenario_from_text(TEXT)


def test_trial_errors_by_hand():
    rng = np.random.default_rng(2)
    n, m = 3, 5
    eta_d = rng.normal(size=(n, m, 3))
    eta = eta_d + rng.normal(scale=0.3, size=(n, m, 3))
    xi = eta_d + rng.normal(scale=0.3, size=(n, m, 3))
    eta[1, 2, 2] += 7.0  # a heading error past pi: wrapped
    eta[0, 0, :2] += 100.0  # t = 0 is not counted
    src = np.array([[-1, -1], [0, -1], [0, 1]])
    weight = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.5]])  # link 3 <- 1 has weight 0
    out = np.zeros(6)
    trial_errors(eta, xi, eta_d, src, weight, out)
    p = np.hypot(*(eta_d - eta)[:, 1:, :2].transpose(2, 0, 1))
    h = np.abs([[wrap_angle(a) for a in row] for row in (eta_d - eta)[:, 1:, 2]])
    tp = np.hypot(*(eta_d - xi)[:, 1:, :2].transpose(2, 0, 1))
    th = np.abs([[wrap_angle(a) for a in row] for row in (eta_d - xi)[:, 1:, 2]])
    f = []
    for r, j in ((1, 0), (2, 1)):
        e = (eta_d[r] - eta_d[j]) - (eta[r] - eta[j])
        f.append(np.hypot(e[1:, 0], e[1:, 1]).max())
    np.testing.assert_allclose(out, [p.max(), h.max(), tp.max(), th.max(),
                                     np.sqrt(np.mean(p ** 2)), max(f)], rtol=1e-14)
    assert h.max() < np.pi + 1e-12


def test_metrics_rows_records_and_callbacks_agree(sc):
    seen, data = [], []
    res = simulate(sc, keep=[0, 2], progress=lambda k, row: seen.append((k, row.copy())),
                   on_trial_data=lambda k, xi, eta, u, tau, tau0: data.append(
                       (k, xi.copy(), eta.copy(), u.copy(), tau.copy(), tau0.copy())))
    assert res.metrics.shape == (3, len(METRIC_COLUMNS))
    assert list(res.metrics[:, 0]) == [0, 1, 2]
    assert [k for k, _ in seen] == [0, 1, 2] and [d[0] for d in data] == [0, 1, 2]
    for i, (_, row) in enumerate(seen):
        np.testing.assert_array_equal(row, res.metrics[i])
    assert sorted(res.records) == [0, 2]
    pb = Problem.from_scenario(sc)
    for k in (0, 2):
        rec = res.records[k]
        _, xi, eta, u, tau, tau0 = data[k]
        np.testing.assert_array_equal(rec.xi, xi)
        np.testing.assert_array_equal(rec.eta, eta)
        np.testing.assert_array_equal(rec.u, u)
        row = np.zeros(6)
        trial_errors(rec.eta, rec.xi, pb.eta_d, pb.src, pb.weight, row)
        np.testing.assert_array_equal(row, res.metrics[k, 1:7])
        # the draws of trial k, as every process of the stack draws them
        t_ref, t0_ref = sc.uncertainty.draw_delays(sc.seed, k, 3, pb.src.shape[1], 6)
        np.testing.assert_array_equal(tau, t_ref)
        np.testing.assert_array_equal(tau0, t0_ref)
    np.testing.assert_array_equal(res.column("max_heading_error"), res.metrics[:, 2])
    assert res.memory is not None and res.memory.shape == (3, 6, 2)


def test_one_trial_by_problem_trial_equals_the_run(sc):
    pb = Problem.from_scenario(sc)
    res = simulate(sc, trials=2, keep=[1])
    first = simulate(sc, trials=1)
    shift, dist, noise = sc.uncertainty.draw_plant(sc.seed, 1, pb.n, pb.samples)
    tau, tau0 = sc.uncertainty.draw_delays(sc.seed, 1, pb.n, pb.src.shape[1], pb.samples)
    xi, eta, u, nxt = pb.trial(first.memory, pb.eta_d[:, 0] + shift, dist, noise, tau, tau0)
    np.testing.assert_array_equal(xi, res.records[1].xi)
    np.testing.assert_array_equal(u, res.records[1].u)
    np.testing.assert_array_equal(nxt, res.memory)


def test_a_run_continues_another_and_checks_the_memory_shape(sc):
    whole = simulate(sc, trials=3)
    head = simulate(sc, trials=2)
    tail = simulate(sc, trials=1, initial_memory=head.memory, first_trial=2)
    assert tail.metrics[0, 0] == 2
    np.testing.assert_array_equal(tail.metrics[0], whole.metrics[2])
    np.testing.assert_array_equal(tail.memory, whole.memory)
    with pytest.raises(ValueError, match=r"initial memory must have shape \(3, 6, 2\)"):
        simulate(sc, trials=1, initial_memory=np.zeros((3, 5, 2)))
    # u_0 = 0 is the default: the same as passing zeros
    zero = simulate(sc, trials=1, initial_memory=np.zeros((3, 6, 2)))
    np.testing.assert_array_equal(zero.metrics, whole.metrics[:1])


def test_seeds_stacked_equal_separate_runs(sc):
    got = simulate_seeds(sc, [5, 8], 2)
    assert got.shape == (2, 2)
    for i, s in enumerate((5, 8)):
        ref = simulate(replace(sc, seed=s), trials=2).column("max_position_error")
        np.testing.assert_allclose(got[i], ref, rtol=1e-12, atol=1e-15)
    assert not np.allclose(got[0], got[1])


def test_tiled_problem_offsets_the_senders_of_each_copy(sc):
    pb = Problem.from_scenario(sc)
    t = pb.tiled(3)
    assert t.n == 3 * pb.n and t.samples == pb.samples
    for c in range(3):
        rows = slice(c * pb.n, (c + 1) * pb.n)
        np.testing.assert_array_equal(t.src[rows], np.where(pb.src >= 0, pb.src + c * pb.n, -1))
        np.testing.assert_array_equal(t.weight[rows], pb.weight)
        np.testing.assert_array_equal(t.eta_d[rows], pb.eta_d)
        np.testing.assert_array_equal(t.gain[rows], pb.gain)
        np.testing.assert_array_equal(t.gain_prime[rows], pb.gain_prime)
        np.testing.assert_array_equal(t.leader[rows], pb.leader)
    assert (t.law, t.memory, t.heading, t.dt) == (pb.law, pb.memory, pb.heading, pb.dt)


def test_formation_error_counts_real_links_only():
    """The largest formation error sits on a link of weight 0 (not a link) and on the
    padding; the counted one is robot 2's link to robot 1 (index 0), weight 1."""
    eta_d = np.zeros((3, 2, 3))
    eta = np.zeros((3, 2, 3))
    eta[1, 1, 0] = 0.5  # robot 2 off by 0.5 m: link 2 <- 1 sees 0.5
    eta[2, 1, 0] = 9.0  # robot 3 off by 9 m, but its only link has weight 0
    src = np.array([[-1], [0], [0]])
    weight = np.array([[0.0], [1.0], [0.0]])
    out = np.zeros(6)
    trial_errors(eta, eta, eta_d, src, weight, out)
    assert out[5] == pytest.approx(0.5)
    weight[1, 0] = 0.0
    trial_errors(eta, eta, eta_d, src, weight, out)
    assert out[5] == 0.0


def test_value_types_are_frozen(sc):
    import dataclasses

    from formation_ilc.model.simulate import TrialRecord

    for obj in (Problem.from_scenario(sc), TrialRecord(0, np.zeros(1), np.zeros(1), np.zeros(1))):
        with pytest.raises(dataclasses.FrozenInstanceError):
            obj.dt = 1.0  # type: ignore[union-attr]


def test_simulate_bytes_by_hand(sc):
    """The estimate's formula on the tiny team: 3 robots, 6 samples, robot 3 has two
    in-links (L = 2), 9 metric columns of 8 bytes per trial."""
    assert len(METRIC_COLUMNS) == 9
    per = 3 * (6 + 2)  # robots x (samples + 2)
    assert simulate_bytes(sc) == 8 * (32 + 4 * 2) * per + 3 * 8 * 9
    assert simulate_bytes(sc, 10, keep=2) == 8 * (32 + 8 + 16) * per + 10 * 8 * 9
    assert simulate_bytes(sc, 10, keep=1, store_metrics=False) == 8 * (32 + 8 + 8) * per
    # a team where nobody has a neighbour still counts one link per robot
    alone = scenario_from_text(TEXT.replace(
        "leader: {1: 1.0}", "leader: {1: 1.0, 2: 1.0, 3: 1.0}").replace(
        "edges: [{from: 1, to: 2}, {from: 1, to: 3}, {from: 2, to: 3, weight: 0.5}]",
        "edges: []"))
    assert simulate_bytes(alone, 1) == 8 * (32 + 4) * per + 8 * 9


def test_each_robots_errors_peak_at_the_teams_metrics():
    """errors.png's per-robot curves: the largest of them is the metrics' team error."""
    from formation_ilc.core.metrics import RobotCurves

    sc = load_scenario("paper-triangle3")
    curves = RobotCurves(sc.desired.eta, 0, 4, cap=2)  # every 2nd trial: 0 and 2
    res = simulate(sc, trials=4, keep=[0, 1, 2, 3],
                   on_trial_data=lambda k, xi, eta, *rest: curves.take(k, eta))
    got = curves.arrays()
    assert got is not None
    trials, e = got
    assert trials.tolist() == [0.0, 2.0] and e.shape == (2, 3, 2)
    np.testing.assert_allclose(e.max(axis=1), res.metrics[[0, 2], 1:3], rtol=1e-12)
    assert (e[:, :, 0] < e[:, :, 0].max(axis=1, keepdims=True)).any()  # robots differ
