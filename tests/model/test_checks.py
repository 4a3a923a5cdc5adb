"""checks.py on small cases with closed forms: the lifted heading map of the predictive law,
how each law and memory reading and delay changes it, the power iteration, the verdicts and
the report a user reads (condition 20 and law 9's map by hand: tests/core/test_reference.py)."""

import numpy as np
import pytest

from formation_ilc.config.scenario import scenario_from_text
from formation_ilc.model import checks


def tiny(law=22, n=2, gain=0.5, gain_prime=0.3, memory="feedforward", delay="none",
         samples=6, leader="{1: 2.0}", edges="[{from: 1, to: 2}]", trials=4):
    offsets = "\n".join(f"    {i + 1}: {{x: {float(i)}, y: 0.0}}" for i in range(n))
    text = f"""
name: tiny
dt: 0.5
samples: {samples}
trials: {trials}
robots: {n}
reference: {{kind: unicycle, speed: 0.4, turn_radius: 2.0}}
formation:
  frame: world
  offsets:
{offsets}
graph:
  leader: {leader}
  edges: {edges}
law: {{kind: {law}, memory: {memory}, gain: {gain}, gain_prime: {gain_prime}}}
delay: {{model: {delay}}}
"""
    return scenario_from_text(text)


def test_norm2_is_the_largest_singular_value():
    rng = np.random.default_rng(1)
    for shape in ((5, 5), (7, 3)):
        m = rng.normal(size=shape)
        assert checks._norm2(m) == pytest.approx(np.linalg.norm(m, 2), rel=1e-8)
    assert checks._norm2(np.zeros((3, 3))) == 0.0
    m = np.diag([3.0, 0.5, 0.25])  # converges at once: the early stop returns the value
    assert checks._norm2(m) == pytest.approx(3.0, rel=1e-12)


def test_heading_map_of_the_predictive_law_has_the_diagonal_closed_form():
    """Law 22, no current term: mu_{k+1}(t) = mu_k(t) - g (L+Omega) dt sum_{s<=t} mu_k(s),
    block lower triangular with diagonal blocks I - diag(g) (L+Omega) dt."""
    sc = tiny(law=22)
    h = checks.heading_map(sc)
    xi = np.array([[2.0, 0.0], [-1.0, 1.0]])
    dt, g = 0.5, 0.5
    blocks = np.eye(2) - g * dt * xi
    assert h.spectral_radius == pytest.approx(np.max(np.abs(np.linalg.eigvals(blocks))),
                                              abs=1e-12)
    # the whole map, built here from its definition, and its norm
    n_t = sc.samples
    lower = np.tril(np.ones((n_t, n_t)))
    m = np.eye(2 * n_t) - g * dt * np.kron(lower, xi)
    assert h.norm == pytest.approx(np.linalg.norm(m, 2), rel=1e-8)
    assert h.powers == (1, 2, 4)  # up to trials = 4
    for k, nk in zip(h.powers, h.norms, strict=True):
        assert nk == pytest.approx(np.linalg.norm(np.linalg.matrix_power(m, k), 2), rel=1e-6)
    assert h.growth == max(h.norms)
    assert h.growth_trial == h.powers[h.norms.index(h.growth)]
    mu0 = sc.desired.u[:, :, 1].T.reshape(-1)
    best = max(np.linalg.norm(np.linalg.matrix_power(m, k) @ mu0) / np.linalg.norm(mu0)
               for k in h.powers)
    assert h.initial_growth == pytest.approx(best, rel=1e-9)
    assert len(checks.heading_map(sc, trials=16).powers) == 5


def test_current_term_changes_the_map_and_literal_memory_adds_it():
    law22 = checks.heading_map(tiny(law=22))
    law9 = checks.heading_map(tiny(law=9))
    law23 = checks.heading_map(tiny(law=23, delay="fixed, samples: 1"))
    law9d = checks.heading_map(tiny(law=9, delay="fixed, samples: 1"))
    lit9 = checks.heading_map(tiny(law=9, memory="literal"))
    lit22 = checks.heading_map(tiny(law=22, memory="literal"))
    assert law9.norm != pytest.approx(law22.norm, rel=1e-6)
    assert law23.norm != pytest.approx(law9d.norm, rel=1e-6)  # they differ under delay
    assert lit9.norm != pytest.approx(law9.norm, rel=1e-6)
    assert lit22.norm == pytest.approx(law22.norm, rel=1e-12)  # law 22 has no current term
    # gain_prime = 0: law 9 is law 22
    assert checks.heading_map(tiny(law=9, gain_prime=0.0)).norm == pytest.approx(
        law22.norm, rel=1e-12)


def test_delayed_current_term_is_the_expected_operator():
    fixed1 = checks.heading_map(tiny(law=9, delay="fixed, samples: 1"))
    none = checks.heading_map(tiny(law=9))
    assert fixed1.norm != pytest.approx(none.norm, rel=1e-6)
    # a delay longer than the trial's usable samples leaves only the predictive term
    late = checks.heading_map(tiny(law=9, delay="fixed, samples: 6"))
    assert late.norm == pytest.approx(checks.heading_map(tiny(law=22)).norm, rel=1e-12)


def test_too_large_a_lifted_map_is_skipped(monkeypatch):
    assert checks.LIFTED_LIMIT == 3600
    monkeypatch.setattr(checks, "LIFTED_LIMIT", 12)
    assert checks.heading_map(tiny(n=2, samples=6)) is not None  # 2 x 6 = 12
    assert checks.heading_map(tiny(n=2, samples=7)) is None


def hm(norm, rho, growth):
    return checks.HeadingMap(norm, rho, growth, 8, growth, (1,), (norm,))


def test_verdicts():
    assert hm(1.2, 1.0, 3).verdict().startswith("will not converge")
    assert hm(0.999, 0.9, 1).verdict().startswith("converges monotonically")
    assert hm(1.0, 0.9, 9.99).verdict().startswith("converges, with a mild transient")
    long = hm(1.5, 0.9, 10.0)
    assert long.verdict().startswith("converges only in the long run")
    assert "trial 8" in long.verdict()
    assert "memory 'feedforward'" in long.verdict(literal=True)
    assert "law 9" in long.verdict(law=22)
    assert "a smaller gain_prime" in long.verdict(law=9)
    assert "a smaller gain_prime" in long.verdict(law=23)


def test_report_of_a_graph_without_spanning_tree():
    sc = tiny(n=3, edges="[{from: 1, to: 2}]")  # robot 3 hears nobody
    rep = checks.check_scenario(sc)
    assert not rep.spanning_tree and rep.unreachable == (2,)
    assert rep.heading is None
    text = "\n".join(rep.lines(sc))
    assert "NO spanning tree: the leader cannot reach robot(s) 3" in text
    assert "skipped" in text


def test_report_of_a_good_graph():
    sc = tiny()
    rep = checks.check_scenario(sc, trials=4)
    assert rep.spanning_tree and rep.unreachable == ()
    assert rep.cond20 == pytest.approx(checks.condition20(sc.graph, np.full(2, 0.5), 0.5))
    assert rep.cond20_paper == pytest.approx(
        checks.condition20(sc.graph, np.full(2, 0.5), 0.5, include_dt=False))
    lines = rep.lines(sc)
    assert lines[0] == "scenario tiny: 2 robots, T = 6 samples of 0.5 s, law (22), memory " \
                       "feedforward"
    assert lines[1].endswith("spanning tree: ok")
    assert ("holds" if rep.cond20 < 1 else "FAILS") in lines[2]
    assert rep.heading is not None and rep.heading.powers == (1, 2, 4)
    assert any(ln.startswith("verdict: " + rep.heading.verdict(False, 22)) for ln in lines)
    bad = checks.check_scenario(tiny(gain=5.0))
    assert bad.cond20 > 1 and "FAILS" in bad.lines(tiny(gain=5.0))[2]


def reference_map(sc):
    """The lifted heading map built column by column from its definition, one robot and
    one sample at a time: a unit memory error at (t0, r0) is run through the heading
    channel e(t+1) = e(t) + dT (mu(t) - g' C(t)) (C: the current term at the expected
    delays, eq. 10: nothing before sample 1) and learned from,
    mu'(t) = mu(t) - g (L + Omega) e(t+1) [- g' C(t), literal memory]."""
    n, n_t, dt = sc.n, sc.samples, sc.dt
    a, lead = sc.graph.adjacency, sc.graph.leader
    g, gp = np.asarray(sc.law.gain), np.asarray(sc.law.gain_prime)
    law = sc.law.kind
    pmf = sc.uncertainty.delay.pmf()
    pmf0 = pmf if sc.uncertainty.delay_leader else {0: 1.0}
    xi = sc.graph.xi
    m = np.zeros((n * n_t, n * n_t))
    for t0 in range(n_t):
        for r0 in range(n):
            mu = np.zeros((n_t, n))
            mu[t0, r0] = 1.0
            e = np.zeros((n_t + 1, n))
            cur = np.zeros((n_t, n))
            for t in range(n_t):
                for i in range(n):
                    c = 0.0
                    if law != 22:
                        for d, p in pmf.items():
                            if t - d >= 1:
                                own = e[t - d, i] if law == 9 else e[t, i]
                                c += p * sum(a[i, j] * (own - e[t - d, j]) for j in range(n))
                        for d, p in pmf0.items():
                            if t - d >= 1:
                                c += p * lead[i] * (e[t - d, i] if law == 9 else e[t, i])
                    cur[t, i] = c
                e[t + 1] = e[t] + dt * (mu[t] - gp * cur[t])
            new = mu - (g[None, :] * (e[1:] @ xi.T))
            if sc.law.memory == "literal" and law != 22:
                new -= gp[None, :] * cur
            m[:, t0 * n + r0] = new.reshape(-1)
    return m


WAYPOINTS = "reference: {kind: waypoints, times: [0, 1, 3], points: [[0, 0], [1, 0], [1, 2]]}"


@pytest.mark.parametrize("law, memory, delay, leader_link", [
    (9, "feedforward", "fixed, samples: 1", "true"),
    (23, "feedforward", "fixed, samples: 1", "true"),
    (9, "literal", "uniform, low: 0, high: 2", "true"),
    (23, "literal", "uniform, low: 0, high: 2", "false"),
    (9, "feedforward", "uniform, low: 1, high: 2", "false"),
])
def test_heading_map_equals_its_definition(law, memory, delay, leader_link):
    sc = tiny(law=law, memory=memory, delay=f"{delay}, leader_link: {leader_link}", n=3,
              samples=5, edges="[{from: 1, to: 2}, {from: 2, to: 3}, {from: 1, to: 3}]")
    m = reference_map(sc)
    h = checks.heading_map(sc, trials=4)
    # norms by power iteration (60 steps at most): a few 1e-6 off the SVD's
    assert h.norm == pytest.approx(np.linalg.norm(m, 2), rel=1e-4)
    for k, nk in zip(h.powers, h.norms, strict=True):
        assert nk == pytest.approx(np.linalg.norm(np.linalg.matrix_power(m, k), 2), rel=1e-4)
    blocks = [m[t * 3:(t + 1) * 3, t * 3:(t + 1) * 3] for t in range(5)]
    assert np.allclose(np.triu(m, 3), 0)  # block lower triangular in time
    assert h.spectral_radius == pytest.approx(
        max(np.abs(np.linalg.eigvals(b)).max() for b in blocks), rel=1e-12)


def test_initial_growth_is_that_of_the_desired_turn_rates():
    text_sc = tiny(law=9)
    sc = scenario_from_text(text_sc.text.replace(
        "reference: {kind: unicycle, speed: 0.4, turn_radius: 2.0}", WAYPOINTS))
    u = sc.desired.u
    assert not np.allclose(u[..., 0] * u[0, 1, 1] / u[0, 1, 0], u[..., 1])  # not proportional
    m = reference_map(sc)
    mu0 = u[:, :, 1].T.reshape(-1)
    h = checks.heading_map(sc, trials=4)
    best = max(np.linalg.norm(np.linalg.matrix_power(m, k) @ mu0) / np.linalg.norm(mu0)
               for k in h.powers)
    assert h.initial_growth == pytest.approx(best, rel=1e-7)


def test_powers_for_one_trial_or_none_and_ties():
    assert checks.heading_map(tiny(), trials=1).powers == (1,)
    assert checks.heading_map(tiny(), trials=0).powers == (1,)
    still = checks.heading_map(tiny(gain=0.0), trials=8)  # M = I: every power has norm 1
    # a 2-norm from an SVD: 1 to round-off (numpy 2.4 gives 1 - 2**-53)
    assert still.norms == pytest.approx((1.0, 1.0, 1.0, 1.0), rel=1e-12)
    assert still.growth == pytest.approx(1.0, rel=1e-12) and still.growth_trial == 1
    shrinking = checks.heading_map(tiny(gain=0.5, samples=2), trials=8)
    assert max(shrinking.norms) < 1 and shrinking.growth == max(shrinking.norms)


def test_report_verdict_advice_follows_the_law_and_memory():
    long = checks.HeadingMap(2.0, 0.9, 50.0, 16, 3.0, (1,), (2.0,))
    for law, memory, advice in ((9, "literal", "memory 'feedforward'"),
                                (22, "literal", "law 9 (its current term"),
                                (22, "feedforward", "law 9 (its current term"),
                                (23, "feedforward", "a smaller gain_prime")):
        sc = tiny(law=law, memory=memory)
        rep = checks.CheckReport(True, (), 1.0, 0.5, long)
        text = "\n".join(rep.lines(sc))
        assert advice in text, (law, memory)
        assert "(FAILS," in text  # 1.0 is not < 1
    ok = checks.CheckReport(True, (), 0.999, 0.5, long).lines(tiny())
    assert "(holds," in ok[2]
    bad = checks.CheckReport(True, (), 1.5, 0.5, long).lines(tiny())
    assert "(FAILS," in bad[2]


def test_value_types_are_frozen():
    import dataclasses

    h = checks.HeadingMap(1.0, 0.5, 1.0, 1, 1.0, (1,), (1.0,))
    for obj in (h, checks.CheckReport(True, (), 0.5, 0.5, None)):
        with pytest.raises(dataclasses.FrozenInstanceError):
            obj.norm = 2.0  # type: ignore[union-attr]


def test_initial_growth_is_zero_when_no_robot_turns():
    straight = scenario_from_text(tiny().text.replace(", turn_radius: 2.0", ""))
    assert not straight.desired.u[..., 1].any()
    with np.errstate(invalid="ignore", divide="ignore"):
        assert checks.heading_map(straight, trials=2).initial_growth == 0.0
