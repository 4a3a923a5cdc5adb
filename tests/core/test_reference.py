"""The core against an independent reference (tests/reference_law.py), and against values
worked by hand.

Most other tests compare the core with itself (batch simulator vs per-robot loop, both
calling ``formation_ilc.core.law``), so an error shared by both sides cancels out. Here the
other side is written from the paper and the documented choices, shares no code with the
core, and the cases are built to tell the choices apart: g != g', per-robot gains, both
gain headings, delays on every link and on the leader link, headings near +-pi and robots
started a turn (2 pi) away from their desired heading, several trials in a row.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from formation_ilc.config.scenario import scenario_from_text
from formation_ilc.core.delays import measure_delay, measure_delay_ns, measure_delays
from formation_ilc.core.law import HEADING_SOURCES, command, learn
from formation_ilc.model import checks
from formation_ilc.model.simulate import METRIC_COLUMNS, Problem, simulate

from .. import reference_law as ref

TOL = 1e-12
LAWS = (9, 22, 23)
MEMORIES = ("feedforward", "literal")


# --------------------------------------------------------------------------- random cases

def random_graph(rng: np.random.Generator, n: int
                 ) -> tuple[list[tuple[int, int, float]], dict[int, float]]:
    """A random digraph the leader spans: (edges (from, to, weight), {robot: a_i0}).

    Robots are 1-based as in a scenario file. A random tree from the leader first (so
    Theorem 2 holds), then extra edges and a second leader link, weights in [0.5, 2].
    """
    order = [int(r) + 1 for r in rng.permutation(n)]
    leader = {order[0]: float(rng.uniform(0.5, 2.0))}
    edges: dict[tuple[int, int], float] = {}
    for k in range(1, n):
        src = order[int(rng.integers(0, k))]
        edges[(src, order[k])] = float(rng.uniform(0.5, 2.0))
    for _ in range(n if n > 1 else 0):
        a, b = (int(x) + 1 for x in rng.choice(n, 2, replace=False))
        edges.setdefault((a, b), float(rng.uniform(0.5, 2.0)))
    if n > 1:
        leader.setdefault(order[-1], float(rng.uniform(0.5, 2.0)))
    return [(a, b, w) for (a, b), w in edges.items()], leader


def graph_arrays(n: int, edges: list[tuple[int, int, float]], leader: dict[int, float]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(adjacency (n, n) with a_ij > 0 if robot i receives from j, leader weights (n,))."""
    adjacency = np.zeros((n, n))
    for a, b, w in edges:
        adjacency[b - 1, a - 1] = w  # information flows from a to b
    lw = np.zeros(n)
    for r, w in leader.items():
        lw[r - 1] = w
    return adjacency, lw


def case_text(rng: np.random.Generator, n: int, samples: int, law: int, memory: str,
              heading: str, gain: list[float], gain_prime: list[float],
              edges: list[tuple[int, int, float]], leader: dict[int, float],
              delay: str, frame: str = "world", seed: int = 3) -> str:
    """Scenario YAML of a random team whose leader starts at a heading of 3.0 rad and turns
    through pi (so desired headings cross +-pi)."""
    offsets = "\n".join(f"    {i + 1}: {{x: {rng.uniform(-1, 1):.6f}, y: {rng.uniform(-1, 1):.6f}}}"
                        for i in range(n))
    edge_lines = "\n".join(f"    - {{from: {a}, to: {b}, weight: {w!r}}}" for a, b, w in edges)
    lead = ", ".join(f"{k}: {v!r}" for k, v in leader.items())
    return f"""\
name: ref-case
dt: 0.1
samples: {samples}
trials: 3
seed: {seed}
robots: {n}
reference: {{kind: unicycle, speed: 0.8, turn_radius: 2.0, start: [0.0, 0.0, 3.0]}}
formation:
  frame: {frame}
  offsets:
{offsets}
graph:
  leader: {{{lead}}}
  edges:
{edge_lines if edges else "    []"}
law:
  kind: {law}
  memory: {memory}
  gain: {gain!r}
  gain_prime: {gain_prime!r}
  gain_heading: {heading}
uncertainty:
  initial_shift: [0.05, 0.05, 0.1]
  disturbance: {{uniform: [0.02, 0.05]}}
  noise: {{uniform: [0.03, 0.03, 0.3]}}
delay: {delay}
"""


PAPER_LIKE_DELAY = ("{model: table, values: [0, 1, 2, 4], probabilities: [0.2, 0.3, 0.3, 0.2], "
                    "leader_link: true}")


def make_case(seed: int, law: int, memory: str, heading: str, n: int = 4, samples: int = 16,
              delay: str = PAPER_LIKE_DELAY, frame: str = "world"):
    """(scenario, reference setup) of one random case. The reference takes the law, memory
    reading, gain heading, gains and graph from this test's own choices, not from the
    parsed scenario, so a loader that drops a field is caught too."""
    rng = np.random.default_rng(seed)
    edges, leader = random_graph(rng, n)
    gain = [round(float(x), 6) for x in rng.uniform(0.3, 1.5, n)]
    gain_prime = [round(float(x), 6) for x in rng.uniform(0.3, 1.5, n)]  # g != g'
    text = case_text(rng, n, samples, law, memory, heading, gain, gain_prime, edges, leader,
                     delay, frame)
    sc = scenario_from_text(text, "ref-case.yaml")
    adjacency, lw = graph_arrays(n, edges, leader)
    setup = ref.Setup(dt=0.1, adjacency=adjacency, leader=lw, gain=np.array(gain),
                      gain_prime=np.array(gain_prime), eta_d=np.array(sc.desired.eta),
                      law=law, memory=memory, heading=heading)
    return sc, setup


def per_link_delays(setup: ref.Setup, tau_slots: np.ndarray) -> np.ndarray:
    """The core's per-slot delays (n, L, T+1) as tau[i, j, t] of the link j -> i.

    Slot ell of robot i is its ell-th sender in ascending order (``Graph.in_links``).
    """
    n = setup.n
    tau = np.full((n, n, tau_slots.shape[2]), -10**6, dtype=np.int64)
    for i in range(n):
        for ell, j in enumerate(setup.senders(i)):
            tau[i, j] = tau_slots[i, ell]
    return tau


def draws(sc, setup: ref.Setup, trial: int, turns: np.ndarray):
    """Trial ``trial``'s random draws, with robot i started ``turns[i]`` full turns away
    from its desired heading (the same pose, another branch of the angle)."""
    n, n_t = setup.n, setup.samples
    shift, dist, noise = sc.uncertainty.draw_plant(sc.seed, trial, n, n_t)
    n_links = max(1, max(len(setup.senders(i)) for i in range(n)))
    tau, tau0 = sc.uncertainty.draw_delays(sc.seed, trial, n, n_links, n_t)
    xi0 = setup.eta_d[:, 0] + shift
    xi0[:, 2] += 2 * np.pi * turns
    return xi0, dist, noise, tau, tau0


def max_diff(a, b) -> float:
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))))


# --------------------------------------------------------------------------- per step

def random_step_inputs(rng: np.random.Generator, n: int, n_t: int, t: int):
    """A team of n robots at sample t with random outputs near +-pi, random delays (labels
    down to below 0) and a random graph; both the reference's and the core's layout."""
    adjacency, lw = graph_arrays(n, *random_graph(rng, n))
    eta_d = rng.normal(scale=2.0, size=(n, n_t + 1, 3))
    eta_d[..., 2] = rng.choice([-1, 1], size=(n, n_t + 1)) * np.pi + rng.normal(
        scale=0.3, size=(n, n_t + 1)) + 2 * np.pi * rng.integers(-1, 2, size=(n, n_t + 1))
    eta = eta_d + rng.normal(scale=0.5, size=eta_d.shape)
    eta[..., 2] += 2 * np.pi * rng.integers(-2, 3, size=(n, n_t + 1))
    senders = [[j for j in range(n) if adjacency[i, j] > 0] for i in range(n)]
    width = max(1, max(len(s) for s in senders)) + 1  # one padding slot more than needed
    src = -np.ones((n, width), dtype=np.int64)
    wgt = np.zeros((n, width))
    labels = np.zeros((n, width), dtype=np.int64)
    nb_eta = np.zeros((n, width, 3))
    received = []
    for i in range(n):
        got = {}
        for ell, j in enumerate(senders[i]):
            s = t - int(rng.integers(0, t + 3))  # 0..t+2 samples late: labels <= 0 too
            src[i, ell], wgt[i, ell], labels[i, ell] = j, adjacency[i, j], s
            nb_eta[i, ell] = eta[j, max(s, 0)] if s >= 0 else rng.normal(size=3)
            got[j] = (s, nb_eta[i, ell].copy())
        received.append(got)
    lead_labels = t - rng.integers(0, t + 3, size=n)
    return dict(adjacency=adjacency, leader=lw, eta_d=eta_d, eta=eta, src=src, weight=wgt,
                labels=labels, nb_eta=nb_eta, received=received, lead_labels=lead_labels)


@pytest.mark.parametrize("heading", HEADING_SOURCES)
@pytest.mark.parametrize("law", LAWS)
def test_command_equals_reference(law, heading):
    rng = np.random.default_rng(100 + law)
    worst = 0.0
    for _ in range(30):
        n, n_t = int(rng.integers(1, 6)), 8
        t = int(rng.integers(0, n_t))
        c = random_step_inputs(rng, n, n_t, t)
        g, gp = rng.uniform(0.1, 2, n), rng.uniform(0.1, 2, n)
        setup = ref.Setup(dt=0.1, adjacency=c["adjacency"], leader=c["leader"], gain=g,
                          gain_prime=gp, eta_d=c["eta_d"], law=law, memory="feedforward",
                          heading=heading)
        memory_t = rng.normal(size=(n, 2))
        # the core sees only the past of each robot's own output
        own = np.full_like(c["eta"], np.nan)
        own[:, : t + 1] = c["eta"][:, : t + 1]
        out = np.zeros((n, 2))
        command(t, law, memory_t, own, c["eta_d"], c["nb_eta"], c["labels"], c["src"],
                c["weight"], c["eta_d"], c["lead_labels"], c["leader"], gp,
                HEADING_SOURCES.index(heading), out)
        want = np.stack([ref.command(setup, i, t, memory_t[i], own[i], c["received"][i],
                                     int(c["lead_labels"][i])) for i in range(n)])
        assert np.isfinite(want).all()
        worst = max(worst, max_diff(out, want))
    assert worst <= TOL


@pytest.mark.parametrize("heading", HEADING_SOURCES)
@pytest.mark.parametrize("memory", MEMORIES)
@pytest.mark.parametrize("law", LAWS)
def test_learn_equals_reference(law, memory, heading):
    rng = np.random.default_rng(200 + law)
    worst = 0.0
    for _ in range(10):
        n, n_t = int(rng.integers(1, 6)), 8
        c = random_step_inputs(rng, n, n_t, 0)
        g, gp = rng.uniform(0.1, 2, n), rng.uniform(0.1, 2, n)
        setup = ref.Setup(dt=0.1, adjacency=c["adjacency"], leader=c["leader"], gain=g,
                          gain_prime=gp, eta_d=c["eta_d"], law=law, memory=memory,
                          heading=heading)
        mem = rng.normal(size=(n, n_t, 2))
        # law 22 applies exactly its memory; the others add their current term
        applied = mem.copy() if law == 22 else mem + rng.normal(size=(n, n_t, 2))
        eta = c["eta"]
        nb_full = np.zeros((n, c["src"].shape[1], n_t + 1, 3))
        for i in range(n):
            for ell, j in enumerate(c["src"][i]):
                if j >= 0:
                    nb_full[i, ell] = eta[j]
        out = np.zeros((n, n_t, 2))
        learn(law, MEMORIES.index(memory), mem, applied, eta, c["eta_d"], nb_full, c["src"],
              c["weight"], c["eta_d"], c["leader"], g, HEADING_SOURCES.index(heading), out)
        want = np.stack([ref.learn(setup, i, mem[i], applied[i], eta) for i in range(n)])
        worst = max(worst, max_diff(out, want))
    assert worst <= TOL


# --------------------------------------------------------------------------- whole trials

@pytest.mark.parametrize("heading", HEADING_SOURCES)
@pytest.mark.parametrize("memory", MEMORIES)
@pytest.mark.parametrize("law", LAWS)
def test_trials_in_sequence_equal_reference(law, memory, heading):
    sc, setup = make_case(10 * law + len(memory) + len(heading), law, memory, heading)
    pb = Problem.from_scenario(sc)
    rng = np.random.default_rng(5)
    turns = np.array([1, -1, 0, 1])  # robots started a turn away: errors across the seam
    mem_core = rng.normal(scale=0.2, size=(setup.n, setup.samples, 2))
    mem_ref = mem_core.copy()
    for k in range(3):  # the memory is carried from trial to trial on each side
        xi0, dist, noise, tau, tau0 = draws(sc, setup, k, turns)
        got = pb.trial(mem_core, xi0, dist, noise, tau, tau0)
        want = ref.trial(setup, mem_ref, xi0, dist, noise, per_link_delays(setup, tau), tau0)
        for name, a, b in zip(("xi", "eta", "u", "memory"), got, want, strict=True):
            assert max_diff(a, b) <= TOL, (k, name, max_diff(a, b))
        mem_core, mem_ref = got[3], want[3]
    # the case exercised what it is meant to: several delays on the links and on the
    # leader link, desired headings on both sides of the +-pi seam
    assert len(np.unique(tau)) >= 3 and len(np.unique(tau0)) >= 3
    assert (setup.eta_d[..., 2] > np.pi).any() and (setup.eta_d[..., 2] < np.pi).any()


def test_leader_frame_formation_and_single_robot_equal_reference():
    for n, frame in ((1, "leader"), (3, "leader")):
        sc, setup = make_case(77 + n, 9, "feedforward", "measured", n=n, frame=frame)
        pb = Problem.from_scenario(sc)
        mem_core = np.zeros((setup.n, setup.samples, 2))
        mem_ref = mem_core.copy()
        turns = np.ones(setup.n, dtype=np.int64)
        for k in range(2):
            args = draws(sc, setup, k, turns)
            got = pb.trial(mem_core, *args)
            want = ref.trial(setup, mem_ref, *args[:3], per_link_delays(setup, args[3]),
                             args[4])
            assert max(max_diff(a, b) for a, b in zip(got, want, strict=True)) <= TOL
            mem_core, mem_ref = got[3], want[3]


@pytest.mark.parametrize(("law", "memory", "heading"),
                         [(9, "feedforward", "measured"), (23, "literal", "desired"),
                          (22, "feedforward", "desired")])
def test_simulate_equals_reference_run(law, memory, heading):
    """simulate(): draws of each trial index, memory carried, metrics and kept records."""
    sc, setup = make_case(300 + law, law, memory, heading, n=3, samples=12)
    rng = np.random.default_rng(9)
    initial = rng.normal(scale=0.2, size=(setup.n, setup.samples, 2))
    first = 2
    res = simulate(sc, trials=3, keep=(2, 4), initial_memory=initial, first_trial=first)
    mem = initial
    zero_turns = np.zeros(setup.n, dtype=np.int64)
    for i in range(3):
        k = first + i
        xi0, dist, noise, tau, tau0 = draws(sc, setup, k, zero_turns)
        xi, eta, u, mem = ref.trial(setup, mem, xi0, dist, noise, per_link_delays(setup, tau),
                                    tau0)
        assert res.metrics[i, 0] == k
        assert max_diff(res.metrics[i, 1:7], ref.trial_metrics(setup, xi, eta)) <= TOL
        assert res.metrics[i, 7] == 0 and np.isnan(res.metrics[i, 8])  # no filter, no bodies
        if k in (2, 4):
            rec = res.records[k]
            assert max(max_diff(rec.xi, xi), max_diff(rec.eta, eta), max_diff(rec.u, u)) <= TOL
    assert max_diff(res.memory, mem) <= TOL
    # the order ref.trial_metrics returns its columns in
    assert METRIC_COLUMNS[1:] == ("max_position_error", "max_heading_error",
                                  "true_max_position_error", "true_max_heading_error",
                                  "rms_position_error", "max_formation_error",
                                  "filter_active", "contacts")


# --------------------------------------------------------------------------- eq. (11)

def test_measure_delay_equals_reference():
    rng = np.random.default_rng(11)
    dt = 0.1
    st = rng.uniform(0, 100, 500)
    rt = st + rng.uniform(-0.3, 0.6, 500)  # clock skew (negative lags) included
    want = [ref.measure_delay(a, b, dt) for a, b in zip(rt, st, strict=True)]
    assert [measure_delay(a, b, dt) for a, b in zip(rt, st, strict=True)] == want
    assert measure_delays(rt, st, dt).tolist() == want
    assert min(want) == 0 and max(want) >= 5


@pytest.mark.parametrize("dt_ns", [100_000_000, 200_000_000, 3, 7, 33_333_333])
def test_measure_delay_ns_equals_reference(dt_ns):
    """Integer nanoseconds, odd dT too: every lag around each rounding boundary."""
    st = 1_234 * dt_ns
    for m in range(-2, 6):
        for off in (-2, -1, 0, 1, 2):
            lag = m * dt_ns - dt_ns // 2 + off  # near (m - 1/2) dT, where the count steps
            got = measure_delay_ns(st + lag, st, dt_ns)
            assert got == ref.measure_delay_ns(st + lag, st, dt_ns), (m, off)
            assert got >= 0


@pytest.mark.parametrize(("lag", "want"), [(0.125, 1), (0.124, 0), (0.375, 2), (-0.125, 0),
                                            (-1.0, 0), (0.374, 1)])
def test_measure_delay_boundaries(lag, want):
    """Eq. (11) rounds half up: with dT = 0.25 s the half-sample boundaries are exact."""
    assert measure_delay(10.0 + lag, 10.0, 0.25) == want == ref.measure_delay(10.0 + lag, 10.0,
                                                                              0.25)
    assert measure_delays(np.array([10.0 + lag]), np.array([10.0]), 0.25).tolist() == [want]


# --------------------------------------------------------------------------- by hand

def _hand_learn(law=9, memory=0, heading=0, applied=None):
    """The learn case of test_learn_by_hand: robot 1 with neighbour robot 2 (a_12 = 2)
    and the leader (a_10 = 0.5), g = 0.1, T = 2."""
    eta_own = np.array([[[0.0, 0.0, np.pi / 2], [0.1, 0.2, np.pi], [0.3, -0.1, -3.0]]])
    eta_d = np.array([[[0.0, 0.0, 0.0], [0.2, 0.0, 3.0], [0.5, 0.0, 3.1]],
                      [[0.0, 0.0, 0.0], [-1.0, 0.0, 2.9], [-0.8, 0.0, 3.0]]])
    nb = np.array([[[[0.0, 0.0, 0.0], [-0.7, 0.1, 2.8], [-0.6, 0.3, 3.1]]]])
    mem = np.array([[[0.3, 0.05], [0.4, -0.02]]])
    app = mem if applied is None else applied
    out = np.zeros((1, 2, 2))
    learn(law, memory, mem, app, eta_own, eta_d[:1], nb, np.array([[1]]), np.array([[2.0]]),
          eta_d, np.array([0.5]), np.array([0.1]), heading, out)
    return out[0]


def test_learn_by_hand():
    # t = 0 uses sample 1:
    #   e_12(1) = (0.2 - -1.0, 0 - 0, 3.0 - 2.9) - (0.1 - -0.7, 0.2 - 0.1, pi - 2.8)
    #           = (0.4, -0.1, 2.9 - pi)
    #   e_1(1)  = (0.2 - 0.1, 0 - 0.2, 3.0 - pi) = (0.1, -0.2, 3.0 - pi)
    #   P = 2 e_12 + 0.5 e_1 = (0.85, -0.3, 7.3 - 2.5 pi)
    #   Gamma at the measured heading at t = 0, pi/2: v-row picks the y error
    #   v = 0.3 + 0.1 (cos(pi/2) 0.85 + sin(pi/2) (-0.3)) = 0.27
    #   w = 0.05 + 0.1 (7.3 - 2.5 pi)
    # t = 1 uses sample 2 (headings across the seam):
    #   e_12(2) = (0.5 + 0.8, 0, 3.1 - 3.0) - (0.3 + 0.6, -0.1 - 0.3, -3.0 - 3.1)
    #           = (0.4, 0.4, 6.2 -> 6.2 - 2 pi)
    #   e_1(2)  = (0.5 - 0.3, 0 + 0.1, 3.1 + 3.0 -> 6.1 - 2 pi)
    #   P = (0.8 + 0.1, 0.8 + 0.05, 12.4 - 4 pi + 3.05 - pi) = (0.9, 0.85, 15.45 - 5 pi)
    #   Gamma at the measured heading at t = 1, pi: v = 0.4 + 0.1 (-0.9) = 0.31
    #   w = -0.02 + 0.1 (15.45 - 5 pi)
    want = np.array([[0.27, 0.05 + 0.1 * (7.3 - 2.5 * np.pi)],
                     [0.31, -0.02 + 0.1 * (15.45 - 5 * np.pi)]])
    np.testing.assert_allclose(_hand_learn(), want, rtol=0, atol=1e-14)
    # literal reading: the same increments on top of what was applied
    applied = np.array([[[0.5, 0.1], [0.6, 0.0]]])
    lit = _hand_learn(memory=1, applied=applied)
    np.testing.assert_allclose(lit - applied[0], want - [[0.3, 0.05], [0.4, -0.02]],
                               rtol=0, atol=1e-14)
    # law 22 learns the same predictive term on its memory in either reading
    np.testing.assert_allclose(_hand_learn(law=22, memory=1, applied=applied), want,
                               rtol=0, atol=1e-14)
    # gain heading 'desired': Gamma at theta_d(0) = 0 and theta_d(1) = 3.0
    des = _hand_learn(heading=1)
    assert des[0, 0] == pytest.approx(0.3 + 0.1 * 0.85, abs=1e-14)
    assert des[1, 0] == pytest.approx(0.4 + 0.1 * (math.cos(3.0) * 0.9 + math.sin(3.0) * 0.85),
                                      abs=1e-14)
    np.testing.assert_allclose(des[:, 1], want[:, 1], rtol=0, atol=1e-14)


def _hand_command(law, heading_source=0, link_label=1, lead_label=2):
    """Robot 1 at t = 3 of T = 4; neighbour robot 2 (a_12 = 1.5) delivered its output
    labelled 1 (tau = 2), the leader (a_10 = 2) its reference labelled 2 (tau = 1);
    g' = 0.2, memory (0.4, 0.1)."""
    own = np.zeros((1, 5, 3))
    own[0, 1] = (1.0, 2.0, 0.5)
    own[0, 2] = (1.5, 2.5, 3.0)
    own[0, 3] = (2.0, 3.0, 3.1)
    own[0, 4] = np.nan  # the future: must not be read
    eta_d = np.zeros((2, 5, 3))
    eta_d[0, 1] = (1.2, 2.0, 0.4)
    eta_d[0, 2] = (1.6, 2.4, -3.1)
    eta_d[0, 3] = (2.1, 3.2, -3.0)
    eta_d[1, 1] = (0.2, 1.0, 0.3)
    eta_d[1, 3] = (1.0, 2.0, 3.1)
    nb = np.array([[[0.1, 1.2, 0.2]]])  # robot 2's output labelled 1
    out = np.zeros((1, 2))
    command(3, law, np.array([[0.4, 0.1]]), own, eta_d[:1], nb, np.array([[link_label]]),
            np.array([[1]]), np.array([[1.5]]), eta_d, np.array([lead_label]),
            np.array([2.0]), np.array([0.2]), heading_source, out)
    return out[0]


def test_command_law9_delayed_with_leader_by_hand():
    # link at s = 1: (1.2 - 0.2, 2.0 - 1.0, 0.4 - 0.3) - (1.0 - 0.1, 2.0 - 1.2, 0.5 - 0.2)
    #              = (0.1, 0.2, -0.2)
    # leader at s0 = 2: (1.6 - 1.5, 2.4 - 2.5, -3.1 - 3.0 -> -6.1 + 2 pi)
    # C = 1.5 (0.1, 0.2, -0.2) + 2 (0.1, -0.1, 2 pi - 6.1) = (0.35, 0.1, 4 pi - 12.5)
    # Gamma' at the measured heading at t = 3, 3.1 rad
    u = _hand_command(9)
    assert u[0] == pytest.approx(0.4 + 0.2 * (math.cos(3.1) * 0.35 + math.sin(3.1) * 0.1),
                                 abs=1e-14)
    assert u[1] == pytest.approx(0.1 + 0.2 * (4 * np.pi - 12.5), abs=1e-14)
    # gain heading 'desired': theta_d(3) = -3.0
    u = _hand_command(9, heading_source=1)
    assert u[0] == pytest.approx(0.4 + 0.2 * (math.cos(-3.0) * 0.35 + math.sin(-3.0) * 0.1),
                                 abs=1e-14)
    # eq. (10): a link labelled 0 is dropped, only the leader's term is left
    u = _hand_command(9, link_label=0)
    assert u[1] == pytest.approx(0.1 + 0.2 * 2 * (2 * np.pi - 6.1), abs=1e-14)
    # and with the leader labelled 0 as well: the memory alone
    assert tuple(_hand_command(9, link_label=0, lead_label=0)) == (0.4, 0.1)


def test_command_law23_delayed_with_leader_by_hand():
    # law 23 pairs the own output at t = 3 with the delayed neighbour output (label 1),
    # and desired values at t = 3:
    # link: (2.1 - 1.0, 3.2 - 2.0, -3.0 - 3.1) - (2.0 - 0.1, 3.0 - 1.2, 3.1 - 0.2)
    #     = (1.1 - 1.9, 1.2 - 1.8, -6.1 - 2.9) = (-0.8, -0.6, -9.0 -> -9.0 + 2 pi)
    # leader: eta_d(s0 = 2) - eta(t = 3) = (1.6 - 2.0, 2.4 - 3.0, -3.1 - 3.1 -> 2 pi - 6.2)
    # C = 1.5 (-0.8, -0.6, 2 pi - 9) + 2 (-0.4, -0.6, 2 pi - 6.2) = (-2.0, -2.1, 7 pi - 25.9)
    u = _hand_command(23)
    assert u[0] == pytest.approx(0.4 + 0.2 * (math.cos(3.1) * -2.0 + math.sin(3.1) * -2.1),
                                 abs=1e-14)
    assert u[1] == pytest.approx(0.1 + 0.2 * (7 * np.pi - 25.9), abs=1e-14)
    # law 22: no current term
    assert tuple(_hand_command(22)) == (0.4, 0.1)


HAND_MAP = """\
name: hand
dt: 0.5
samples: 2
robots: 2
reference: {kind: lemniscate}
formation:
  frame: world
  offsets: {1: {x: 0, y: 0}, 2: {x: 1, y: 0}}
graph:
  leader: {1: 1.0}
  edges: [{from: 1, to: 2}]
law: {kind: 9, memory: MEMORY, gain: [1.0, 0.5], gain_prime: [1.0, 1.0]}
"""


def _hand_map_matrix(literal: bool) -> np.ndarray:
    """The lifted heading map of HAND_MAP, worked by hand.

    Heading channel: e(t+1) = e(t) + dT (mu(t) - g' C(t)), e(0) = 0, mu = omega_d - memory;
    law 9 without delay: C(t) = Xi e(t) for t >= 1 (eq. 10: C(0) = 0); learning
    mu_{k+1}(t) = mu_k(t) - diag(g) Xi e(t+1) (robot i's gain on robot i's P_i), and in the
    literal reading also - diag(g') C(t).
    Xi = L + Omega = [[1, 0], [-1, 1]], dT = 0.5, g = (1, 0.5), g' = (1, 1).
    e(1) = 0.5 mu(0); e(2) = (I - 0.5 Xi) 0.5 mu(0) + 0.5 mu(1), I - 0.5 Xi = [[.5, 0], [.5, .5]]
    diag(g) Xi = [[1, 0], [-0.5, 0.5]]
    block (0, 0) = I - 0.5 diag(g) Xi = [[0.5, 0], [0.25, 0.75]]
    block (1, 0) = -diag(g) Xi (I - 0.5 Xi) 0.5 = -0.5 [[0.5, 0], [0, 0.25]]
                 = [[-0.25, 0], [0, -0.125]]
    block (1, 1) = block (0, 0)
    literal, block (1, 0) also - diag(g') Xi e(1) / mu(0) = - 0.5 Xi = [[-0.5, 0], [0.5, -0.5]]
    Order of mu: (robot 1 at t = 0, robot 2 at 0, robot 1 at 1, robot 2 at 1).
    """
    m = np.array([[0.5, 0.0, 0.0, 0.0],
                  [0.25, 0.75, 0.0, 0.0],
                  [-0.25, 0.0, 0.5, 0.0],
                  [0.0, -0.125, 0.25, 0.75]])
    if literal:
        m[2:, :2] += [[-0.5, 0.0], [0.5, -0.5]]
    return m


@pytest.mark.parametrize("memory", MEMORIES)
def test_heading_map_by_hand(memory):
    sc = scenario_from_text(HAND_MAP.replace("MEMORY", memory))
    hm = checks.heading_map(sc, trials=4)
    m = _hand_map_matrix(memory == "literal")
    # block lower triangular: the eigenvalues are the diagonal blocks' diagonals
    assert hm.spectral_radius == pytest.approx(0.75, abs=1e-12)
    assert hm.norm == pytest.approx(np.linalg.norm(m, 2), abs=1e-9)
    assert hm.powers == (1, 2, 4)
    for k, nk in zip(hm.powers, hm.norms, strict=True):
        assert nk == pytest.approx(np.linalg.norm(np.linalg.matrix_power(m, k), 2), abs=1e-9)


def test_condition20_by_hand():
    sc = scenario_from_text(HAND_MAP.replace("MEMORY", "feedforward"))
    # ||I - dT Xi diag(g)||_2 (eq. 20, Gamma_i B_i = g_i dT I_2) with Xi = [[1, 0], [-1, 1]]:
    # equal gains g = 0.08, dT = 0.1: [[a, 0], [b, a]], a = 0.992, b = 0.008, whose largest
    # singular value is (b + sqrt(4 a^2 + b^2)) / 2
    a, b = 1 - 0.008, 0.008
    assert checks.condition20(sc.graph, np.array([0.08, 0.08]), 0.1) == pytest.approx(
        (b + math.sqrt(4 * a * a + b * b)) / 2, abs=1e-12)
    # dT left out of B (paper-notes 11): a = 0.92, b = 0.08
    a, b = 1 - 0.08, 0.08
    assert checks.condition20(sc.graph, np.array([0.08, 0.08]), 0.1,
                              include_dt=False) == pytest.approx(
        (b + math.sqrt(4 * a * a + b * b)) / 2, abs=1e-12)
    # per-robot gains g = (1, 0.5), dT = 0.5: Xi diag(g) dT = [[0.5, 0], [-0.5, 0.25]],
    # I - that = [[0.5, 0], [0.5, 0.75]] =: [[p, 0], [q, r]]; sigma_max^2 is the larger root
    # of s^2 - (p^2 + q^2 + r^2) s + p^2 r^2 = 0
    p, q, r = 0.5, 0.5, 0.75
    tr2 = p * p + q * q + r * r
    smax = math.sqrt((tr2 + math.sqrt(tr2 * tr2 - 4 * p * p * r * r)) / 2)
    assert checks.condition20(sc.graph, np.array([1.0, 0.5]), 0.5) == pytest.approx(smax,
                                                                                     abs=1e-12)


def test_desired_heading_at_T_continues_the_last_turn_by_hand():
    """Robot at the leader's point of a sampled path whose steps turn by 0.3 rad each:
    headings 0, 0.3, 0.6 on the steps of t = 0, 1, 2, and at t = T = 3, where no step of
    the trial starts, the last turn continues: 0.9 (held would be 0.6)."""
    p = [(0.0, 0.0), (1.0, 0.0)]
    p.append((p[-1][0] + math.cos(0.3), p[-1][1] + math.sin(0.3)))
    p.append((p[-1][0] + math.cos(0.6), p[-1][1] + math.sin(0.6)))
    pts = ", ".join(f"[{x!r}, {y!r}]" for x, y in p)
    sc = scenario_from_text(f"""\
name: turn
dt: 0.5
samples: 3
robots: 1
reference: {{kind: samples, points: [{pts}]}}
formation: {{frame: world, offsets: {{1: {{x: 0, y: 0}}}}}}
graph: {{leader: {{1: 1.0}}}}
""")
    d = sc.desired
    np.testing.assert_allclose(d.eta[0, :, 2], [0.0, 0.3, 0.6, 0.9], rtol=0, atol=1e-12)
    # u_d: unit steps in dT = 0.5 s -> 2 m/s; turn 0.3 rad per 0.5 s -> 0.6 rad/s, also on
    # the last step (t = 2), which ends at theta_d(T)
    np.testing.assert_allclose(d.u[0], [[2.0, 0.6], [2.0, 0.6], [2.0, 0.6]], rtol=0, atol=1e-12)


@pytest.mark.parametrize("frame", ["world", "leader"])
def test_desired_trajectories_of_random_cases_follow_assumption1(frame):
    """The desired outputs the reference takes from the loader, checked against eq. (2)
    and paper-notes 3: each heading theta_i^d(t), t < T, is the tangent of robot i's own
    step t -> t+1 (either way along it), u_i^d replays it, and theta_i^d(T), where no step
    of the trial starts, continues the last turn."""
    sc, setup = make_case(500, 9, "feedforward", "measured", n=4, samples=30, frame=frame)
    eta, u, dt = setup.eta_d, np.asarray(sc.desired.u), setup.dt
    for i in range(setup.n):
        for t in range(setup.samples):
            dx, dy = eta[i, t + 1, :2] - eta[i, t, :2]
            th = eta[i, t, 2]
            assert dx * math.sin(th) - dy * math.cos(th) == pytest.approx(0.0, abs=1e-12)  # (2)
            along = dx * math.cos(th) + dy * math.sin(th)
            assert u[i, t, 0] == pytest.approx(along / dt, abs=1e-12)
            assert u[i, t, 1] == pytest.approx((eta[i, t + 1, 2] - th) / dt, abs=1e-12)
        assert eta[i, -1, 2] == pytest.approx(2 * eta[i, -2, 2] - eta[i, -3, 2], abs=1e-12)
        assert abs(eta[i, -1, 2] - eta[i, -2, 2]) > 1e-3  # the leader turns: held would differ
