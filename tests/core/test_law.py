"""One law, two callers: the batch trial equals a loop over robots calling the per-step
function one robot at a time (as the robot node does), to round-off.
"""

import numpy as np
import pytest

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.kinematics import step as kstep
from formation_ilc.core.law import MEASURED, command, learn
from formation_ilc.model.simulate import Problem


def per_robot_trial(pb: Problem, memory, xi0, dist, noise, tau, tau0, interpreted=False):
    """A plain Python loop: each robot computes its own input from what it received."""
    cmd = command.py_func if interpreted else command.jit
    lrn = learn.py_func if interpreted else learn.jit
    n, n_t = pb.n, pb.samples
    n_links = pb.src.shape[1]
    xi = np.zeros((n, n_t + 1, 3))
    eta = np.zeros_like(xi)
    u = np.zeros((n, n_t, 2))
    xi[:, 0] = xi0
    for t in range(n_t):
        eta[:, t] = xi[:, t] + noise[:, t]
        for r in range(n):
            nb_eta = np.zeros((1, n_links, 3))
            nb_s = np.zeros((1, n_links), dtype=np.int64)
            for ell in range(n_links):
                s = t - tau[r, ell, t]
                nb_s[0, ell] = s
                if pb.src[r, ell] >= 0 and s >= 0:
                    nb_eta[0, ell] = eta[pb.src[r, ell], s]
            own = np.zeros((1, n_t + 1, 3))
            own[0, : t + 1] = eta[r, : t + 1]  # a robot knows only its past
            out = np.zeros((1, 2))
            cmd(t, pb.law, memory[r:r + 1, t], own, pb.eta_d[r:r + 1], nb_eta, nb_s,
                pb.src[r:r + 1], pb.weight[r:r + 1], pb.eta_d,
                np.array([t - tau0[r, t]], dtype=np.int64), pb.leader[r:r + 1],
                pb.gain_prime[r:r + 1], pb.heading, out)
            u[r, t] = out[0]
        xi[:, t + 1] = kstep(xi[:, t], u[:, t], pb.dt, dist[:, t])
    eta[:, n_t] = xi[:, n_t] + noise[:, n_t]
    nxt = np.zeros_like(memory)
    for r in range(n):
        nb_full = np.zeros((1, n_links, n_t + 1, 3))
        for ell in range(n_links):
            if pb.src[r, ell] >= 0:
                nb_full[0, ell] = eta[pb.src[r, ell]]
        lrn(pb.law, pb.memory, memory[r:r + 1], u[r:r + 1], eta[r:r + 1], pb.eta_d[r:r + 1],
            nb_full, pb.src[r:r + 1], pb.weight[r:r + 1], pb.eta_d, pb.leader[r:r + 1],
            pb.gain[r:r + 1], pb.heading, nxt[r:r + 1])
    return xi, eta, u, nxt


def batch_trial(pb, memory, xi0, dist, noise, tau, tau0):
    return pb.trial(memory, xi0, dist, noise, tau, tau0)


def draws(sc, pb, trial):
    shift, dist, noise = sc.uncertainty.draw_plant(sc.seed, trial, pb.n, pb.samples)
    tau, tau0 = sc.uncertainty.draw_delays(sc.seed, trial, pb.n, pb.src.shape[1], pb.samples)
    return pb.eta_d[:, 0] + shift, dist, noise, tau, tau0


@pytest.mark.parametrize("law", [9, 22, 23])
@pytest.mark.parametrize("memory", ["feedforward", "literal"])
def test_batch_equals_loop_over_robots(law, memory):
    sc = load_scenario("paper-triangle3").with_options(law=law, memory=memory)
    pb = Problem.from_scenario(sc)
    rng = np.random.default_rng(7)
    mem = rng.normal(scale=0.1, size=(pb.n, pb.samples, 2))  # a learned-looking memory
    for trial in range(2):
        args = draws(sc, pb, trial)
        got = batch_trial(pb, mem, *args)
        ref = per_robot_trial(pb, mem, *args)
        for a, b in zip(got, ref, strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
        mem = got[3]


def test_compiled_law_equals_interpreted_law():
    sc = load_scenario("paper-triangle3")
    pb = Problem.from_scenario(sc)
    mem = np.random.default_rng(1).normal(scale=0.1, size=(pb.n, pb.samples, 2))
    args = draws(sc, pb, 0)
    got = per_robot_trial(pb, mem, *args)
    ref = per_robot_trial(pb, mem, *args, interpreted=True)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)
        assert a.tobytes() == b.tobytes()  # the same operations in the same order


def _one_robot_command(law, eta_own, nb_eta, nb_s, lead_s, t=5, heading=0.3):
    n_t = 10
    eta_d = np.zeros((2, n_t + 1, 3))
    eta_d[1, :, 0] = 1.0  # robot 2 desired 1 m ahead of robot 1 in x
    own = np.zeros((1, n_t + 1, 3))
    own[0] = eta_own
    own[0, t, 2] = heading
    out = np.zeros((1, 2))
    command(t, law, np.array([[0.5, 0.1]]), own, eta_d[:1], nb_eta, nb_s,
            np.array([[1]]), np.array([[1.0]]), eta_d, np.array([lead_s]), np.array([1.0]),
            np.array([0.08]), 0, out)
    return out[0]


def test_law9_pairs_outputs_at_the_delayed_sample_and_law23_does_not():
    n_t = 10
    eta_own = np.zeros((n_t + 1, 3))
    eta_own[:, 0] = np.arange(n_t + 1) * 0.1  # robot 1 drifts in x
    nb = np.array([[[1.2, 0.0, 0.0]]])  # robot 2's output labelled s = 3
    s = np.array([[3]])
    u9 = _one_robot_command(9, eta_own, nb, s, lead_s=3, heading=0.0)
    u23 = _one_robot_command(23, eta_own, nb, s, lead_s=3, heading=0.0)
    u22 = _one_robot_command(22, eta_own, nb, s, lead_s=3, heading=0.0)
    # law 9 at s = 3: link (0 - 1) - (0.3 - 1.2) = -0.1; leader 0 - 0.3 = -0.3
    assert u9[0] == pytest.approx(0.5 + 0.08 * (-0.1 - 0.3))
    # law 23 pairs own x at t = 5 (0.5): (0 - 1) - (0.5 - 1.2) = -0.3; leader 0 - 0.5
    assert u23[0] == pytest.approx(0.5 + 0.08 * (-0.3 - 0.5))
    assert tuple(u22) == (0.5, 0.1)  # predictive only: the memory itself
    # eq. (10): nothing labelled <= 0 is used
    u0 = _one_robot_command(9, eta_own, nb, np.array([[0]]), lead_s=0)
    assert tuple(u0) == (0.5, 0.1)


def test_heading_gain_projects_position_error_on_heading():
    eta_own = np.zeros((11, 3))
    nb = np.array([[[1.0, -1.0, 0.0]]])  # desired relative (-1, 0), actual (-1, +1): ey = -1
    u = _one_robot_command(9, eta_own, nb, np.array([[2]]), lead_s=0, heading=np.pi / 2)
    assert u[0] == pytest.approx(0.5 + 0.08 * (-1.0))  # sin(pi/2) * ey
    assert u[1] == pytest.approx(0.1)


def test_feedforward_memory_forgets_the_current_term_literal_keeps_it():
    sc = load_scenario("paper-triangle3").with_options(noise=False, delay=False)
    res = {}
    for memory in ("feedforward", "literal"):
        pb = Problem.from_scenario(sc.with_options(memory=memory))
        mem = np.zeros((pb.n, pb.samples, 2))
        xi0, dist, noise, tau, tau0 = draws(sc, pb, 0)
        xi, eta, u, nxt = batch_trial(pb, mem, xi0, dist, noise, tau, tau0)
        res[memory] = (u, nxt)
    u, ff = res["feedforward"]
    _, lit = res["literal"]
    # same trial 0 (memory 0); literal's next memory = feedforward's + what was applied
    np.testing.assert_allclose(lit - ff, u, atol=1e-12)
    assert np.abs(u).max() > 0.01


# ----------------------------------------------------------------------------------------
# The law's learning step with unit weights, by hand (weights of exactly 1, as in the
# paper's graphs; tests/core/test_reference.py covers random weights).

def test_learn_with_unit_link_and_leader_weights_by_hand():
    th0 = 0.4
    eta_own = np.array([[[0.0, 0.0, th0], [1.0, 2.0, 0.3]]])  # (R=1, T+1=2, 3)
    eta_d_own = np.array([[[0.0, 0.0, 0.0], [1.5, 2.5, 0.5]]])
    nb_eta = np.array([[[[0.0, 0.0, 0.0], [0.2, 0.1, 0.1]]]])  # (R, L=1, T+1, 3)
    eta_d_all = np.array([eta_d_own[0], [[0.0, 0.0, 0.0], [0.4, 0.3, 0.2]]])  # robot j = 1
    memory = np.array([[[0.1, -0.2]]])
    out = np.zeros_like(memory)
    learn(9, 0, memory, np.zeros_like(memory), eta_own, eta_d_own, nb_eta,
          np.array([[1]]), np.array([[1.0]]), eta_d_all, np.array([1.0]), np.array([0.5]),
          MEASURED, out)
    # link: (d_i - d_j) - (eta_i - eta_j); leader: d_i - eta_i; both with weight 1
    link = (np.array([1.5, 2.5, 0.5]) - [0.4, 0.3, 0.2]) - (np.array([1.0, 2.0, 0.3])
                                                           - [0.2, 0.1, 0.1])
    p = link + (np.array([1.5, 2.5, 0.5]) - [1.0, 2.0, 0.3])
    want = [0.1 + 0.5 * (np.cos(th0) * p[0] + np.sin(th0) * p[1]), -0.2 + 0.5 * p[2]]
    np.testing.assert_allclose(out[0, 0], want, rtol=1e-14)



def test_learn_with_more_robots_than_samples_is_each_robot_alone():
    """Three robots learning from a one-sample trial at once give what each gives alone:
    the per-robot scratch (cos and sin of the heading) is sized by robots, not samples."""
    rng = np.random.default_rng(4)
    r_n, n_t = 3, 1
    eta_own = rng.normal(size=(r_n, n_t + 1, 3))
    eta_d_own = rng.normal(size=(r_n, n_t + 1, 3))
    nb_eta = rng.normal(size=(r_n, 1, n_t + 1, 3))
    eta_d_all = rng.normal(size=(r_n, n_t + 1, 3))
    memory = rng.normal(size=(r_n, n_t, 2))
    applied = rng.normal(size=(r_n, n_t, 2))
    src = np.array([[1], [2], [0]])
    weight = np.array([[1.0], [0.5], [2.0]])
    lead = np.array([1.0, 0.0, 0.3])
    gain = np.array([0.5, 0.4, 0.2])
    out = np.zeros_like(memory)
    learn(9, 0, memory, applied, eta_own, eta_d_own, nb_eta, src, weight, eta_d_all, lead,
          gain, MEASURED, out)
    for r in range(r_n):
        one = np.zeros((1, n_t, 2))
        learn(9, 0, memory[r:r + 1], applied[r:r + 1], eta_own[r:r + 1], eta_d_own[r:r + 1],
              nb_eta[r:r + 1], src[r:r + 1], weight[r:r + 1], eta_d_all, lead[r:r + 1],
              gain[r:r + 1], MEASURED, one)
        np.testing.assert_array_equal(out[r], one[0])
    assert np.all(out != memory)  # every robot learned something
