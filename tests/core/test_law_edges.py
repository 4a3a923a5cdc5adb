"""The law's learning step with unit weights, by hand (weights of exactly 1, as in the
paper's graphs; tests/core/test_reference.py covers random weights)."""

import numpy as np

from formation_ilc.core.law import MEASURED, learn


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
