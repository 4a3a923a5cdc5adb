"""The compiled generator (formation_ilc/core/pcg.py) and the compiled draws give numpy's
numbers bit for bit: the same SeedSequence, PCG64 and Generator.random / uniform, and the
numpy contract of uncertainty.py for every delay model. And simulate(), which draws inside
its compiled loop, equals a loop of numpy draws and single trials."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numba import njit

from formation_ilc.config.scenario import load_scenario
from formation_ilc.core.delays import DelayModel
from formation_ilc.core.links import LOST
from formation_ilc.core.pcg import STATE_SIZE, next_double, next_uint64, seed_state, seed_words
from formation_ilc.core.uncertainty import (
    DELAY_STREAM,
    LOSS_STREAM,
    PLANT_STREAM,
    Harmonic,
    Uncertainty,
    delay_arrays,
    fill_delays,
    fill_plant,
    plant_arrays,
)
from formation_ilc.model.simulate import (
    METRIC_COLUMNS,
    Problem,
    run_trial,
    safety_arrays,
    simulate,
    trial_errors,
)

SEEDS = (0, 1, 7, 2**31 + 5, 2**32 - 1, 2**32, 2**40 + 3, 2**63 - 1, 2**64 + 17, 2**100 + 9)


@njit
def _doubles(seed, trial, stream, count):
    st = np.empty(STATE_SIZE, dtype=np.uint64)
    seed_state(seed, trial, stream, st)
    out = np.empty(count)
    for i in range(count):
        out[i] = next_double(st)
    return out


@njit
def _uint64s(seed, trial, stream, count):
    st = np.empty(STATE_SIZE, dtype=np.uint64)
    seed_state(seed, trial, stream, st)
    out = np.empty(count, dtype=np.uint64)
    for i in range(count):
        out[i] = next_uint64(st)
    return out


def test_seed_words_are_seedsequence_words():
    for v in (0, 1, 2**32 - 1, 2**32, 2**64 + 17, 2**100 + 9):
        words = seed_words(v)
        assert words.dtype == np.uint32
        # SeedSequence of the words equals SeedSequence of the integer
        np.testing.assert_array_equal(np.random.SeedSequence(v).generate_state(4),
                                      np.random.SeedSequence(words).generate_state(4))
    with pytest.raises(ValueError):
        seed_words(-1)


@pytest.mark.parametrize("seed", SEEDS)
def test_compiled_generator_is_default_rng(seed):
    words = seed_words(seed)
    for trial in (0, 1, 299, 2**32 - 1, 2**32 + 3, 2**40):
        for stream in (PLANT_STREAM, DELAY_STREAM, 5):
            ref = np.random.default_rng([seed, trial, stream])
            np.testing.assert_array_equal(_uint64s(words, trial, stream, 40),
                                          ref.integers(0, 2**64, 40, dtype=np.uint64,
                                                       endpoint=False))
            ref = np.random.default_rng([seed, trial, stream])
            got = _doubles(words, trial, stream, 300)
            np.testing.assert_array_equal(got, ref.random(300))
            np.testing.assert_array_equal(
                -1.0 + 2.0 * got[:50],
                np.random.default_rng([seed, trial, stream]).uniform(-1.0, 1.0, 50))


def test_two_words_each_of_trial_and_stream():
    """Trial and stream of 2**32 and more both at once: four entropy words past the seed's
    (up to 2**63 - 1: the kernels take int64)."""
    for seed in (0, 2**64 + 17):
        for trial, stream in ((2**32, 2**32), (2**40 + 1, 2**33 + 5), (2**63 - 1, 2**62 + 3)):
            np.testing.assert_array_equal(
                _uint64s(seed_words(seed), trial, stream, 8),
                np.random.default_rng([seed, trial, stream]).integers(
                    0, 2**64, 8, dtype=np.uint64, endpoint=False))


def _numpy_plant(u: Uncertainty, seed: int, trial: int, n: int, n_t: int):
    """uncertainty.py's contract, in numpy."""
    rng = np.random.default_rng([seed, trial, PLANT_STREAM])
    shift = rng.uniform(-1.0, 1.0, (n, 3)) * np.asarray(u.initial_shift)
    dist = rng.uniform(-1.0, 1.0, (n, n_t, 2)) * np.asarray(u.disturbance_uniform)
    noise = rng.uniform(-1.0, 1.0, (n, n_t + 1, 3)) * np.asarray(u.noise_uniform)
    for c, h in enumerate(u.disturbance_fixed):
        dist[..., c] += h(np.arange(n_t, dtype=float))
    for c, h in enumerate(u.noise_fixed):
        noise[..., c] += h(np.arange(n_t + 1, dtype=float))
    return shift, dist, noise


def _numpy_delays(u: Uncertainty, seed: int, trial: int, n: int, n_links: int, n_t: int):
    rng = np.random.default_rng([seed, trial, DELAY_STREAM])
    tau = u.delay.draw(rng, (n, n_links, n_t + 1))
    tau0 = (u.delay.draw(rng, (n, n_t + 1)) if u.delay_leader
            else np.zeros((n, n_t + 1), dtype=np.int64))
    if u.link_loss > 0.0:
        lrng = np.random.default_rng([seed, trial, LOSS_STREAM])
        tau[lrng.random(tau.shape) < u.link_loss] = LOST
        if u.delay_leader:
            tau0[lrng.random(tau0.shape) < u.link_loss] = LOST
    return tau, tau0


H = (Harmonic(0.1, 0.2, 0.3), Harmonic(0.4, 0.5, 0.6), Harmonic(0.7, 0.8, 0.9))
BASE = Uncertainty(initial_shift=(0.1, 0.2, 0.3), disturbance_fixed=H[:2],
                   disturbance_uniform=(0.4, 0.0), noise_fixed=H,
                   noise_uniform=(0.6, 0.7, 0.8))
MODELS = [DelayModel(), DelayModel("fixed", samples=3), DelayModel("uniform", low=0, high=0),
          DelayModel("uniform", low=1, high=4), DelayModel.paper(),
          DelayModel("table", values=(5, 0, 2), probabilities=(0.25, 0.0, 0.75))]


def _compiled_plant(u: Uncertainty, seed: int, trial: int, n: int, n_t: int):
    """The batch simulator's draws: the compiled kernel."""
    shift, dist, noise = np.empty((n, 3)), np.empty((n, n_t, 2)), np.empty((n, n_t + 1, 3))
    fill_plant.jit(seed_words(seed), trial, *plant_arrays(u, n_t),
                   np.empty(STATE_SIZE, dtype=np.uint64), shift, dist, noise)
    return shift, dist, noise


def _compiled_delays(u: Uncertainty, seed: int, trial: int, n: int, n_links: int, n_t: int):
    tau = np.empty((n, n_links, n_t + 1), dtype=np.int64)
    tau0 = np.empty((n, n_t + 1), dtype=np.int64)
    fill_delays.jit(seed_words(seed), trial, *delay_arrays(u),
                    np.empty(STATE_SIZE, dtype=np.uint64), tau, tau0)
    return tau, tau0


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.kind}-{m.values or m.high}")
@pytest.mark.parametrize("leader", [True, False])
@pytest.mark.parametrize("loss", [0.0, 0.3])
def test_compiled_draws_follow_the_numpy_contract(model, leader, loss):
    """The compiled kernels (the batch simulator's) and ``Uncertainty.draw_plant`` /
    ``draw_delays`` (the nodes') both give the contract's numbers."""
    u = dataclasses.replace(BASE, delay=model, delay_leader=leader, link_loss=loss)
    for seed, trial, n, n_links, n_t in ((3, 0, 2, 4, 5), (2**40 + 3, 17, 6, 1, 300),
                                         (0, 2**33, 3, 0, 7)):
        ref_plant = _numpy_plant(u, seed, trial, n, n_t)
        for draws in (u.draw_plant(seed, trial, n, n_t), _compiled_plant(u, seed, trial, n, n_t)):
            for got, ref in zip(draws, ref_plant, strict=True):
                assert got.shape == ref.shape and got.dtype == ref.dtype
                np.testing.assert_array_equal(got, ref)
                # bit for bit, signed zeros too (0 * a negative draw)
                assert got.tobytes() == ref.tobytes()
        refs = _numpy_delays(u, seed, trial, n, n_links, n_t)
        for draws in (u.draw_delays(seed, trial, n, n_links, n_t),
                      _compiled_delays(u, seed, trial, n, n_links, n_t)):
            for got, ref in zip(draws, refs, strict=True):
                assert got.shape == ref.shape and got.dtype == ref.dtype == np.int64
                np.testing.assert_array_equal(got, ref)
        if loss and refs[0].size > 100:
            assert (refs[0] == LOST).any()  # the loss stream was drawn
    with pytest.raises(ValueError):
        u.draw_plant(1, -1, 2, 3)


def _reference_run(sc, trials: int, first: int = 0):
    """simulate() as it was: numpy draws, one trial per call, metrics per trial; the kernels
    interpreted, as the nodes run them (so this also pins interpreted = compiled, bit for
    bit)."""
    pb = Problem.from_scenario(sc)
    n, n_t, n_links = pb.n, pb.samples, pb.src.shape[1]
    memory = np.zeros((n, n_t, 2))
    nxt, xi, u = np.empty_like(memory), np.empty((n, n_t + 1, 3)), np.empty((n, n_t, 2))
    eta = np.empty_like(xi)
    metrics = np.empty((trials, len(METRIC_COLUMNS)))
    row = np.empty(6)
    for i in range(trials):
        k = first + i
        shift, dist, noise = _numpy_plant(sc.uncertainty, sc.seed, k, n, n_t)
        tau, tau0 = _numpy_delays(sc.uncertainty, sc.seed, k, n, n_links, n_t)
        run_trial(pb.law, pb.memory, pb.heading, pb.plant, pb.dt, memory,
                  pb.eta_d[:, 0] + shift, dist, noise, tau, tau0, pb.src, pb.weight, pb.leader,
                  pb.eta_d, pb.gain, pb.gain_prime, xi, eta, u, nxt, safety_arrays(pb))
        trial_errors(eta, xi, pb.eta_d, pb.src, pb.weight, row)
        metrics[i, 0] = k
        metrics[i, 1:7] = row
        metrics[i, 7:] = (0.0, np.nan)  # no filter, no bodies
        memory, nxt = nxt, memory
    return metrics, memory, xi


@pytest.mark.parametrize("name, law, memory, seed, loss", [
    ("paper-hexagon6", 9, "feedforward", 1, 0.0), ("paper-hexagon6", 23, "literal", 2**40 + 3, 0.0),
    ("paper-triangle3", 22, "feedforward", 0, 0.0), ("paper-triangle3", 9, "literal", 5, 0.0),
    ("paper-hexagon6", 9, "feedforward", 2, 0.2)])
def test_simulate_equals_numpy_draws_and_single_trials(name, law, memory, seed, loss):
    sc = load_scenario(name).with_options(law=law, memory=memory, seed=seed)
    sc = dataclasses.replace(sc, uncertainty=dataclasses.replace(sc.uncertainty,
                                                                 link_loss=loss))
    ref_m, ref_mem, ref_xi = _reference_run(sc, 7, first=3)
    fast = simulate(sc, trials=7, first_trial=3)  # every trial in one compiled call
    assert fast.metrics.tobytes() == ref_m.tobytes()
    assert fast.memory is not None and fast.memory.tobytes() == ref_mem.tobytes()
    seen: list[int] = []
    slow = simulate(sc, trials=7, first_trial=3, keep=[9], progress=lambda k, r: seen.append(k))
    assert seen == list(range(3, 10))
    assert slow.metrics.tobytes() == ref_m.tobytes()
    assert slow.memory is not None and slow.memory.tobytes() == ref_mem.tobytes()
    assert slow.records[9].xi.tobytes() == ref_xi.tobytes()
    # a learning run: the metrics change from trial to trial
    assert len(set(ref_m[:, 1])) == 7
