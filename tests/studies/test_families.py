"""The safety filter judged on formations nobody tuned (``studies.families``).

Generated crossing, following and swapping teams (4-6 robots, random spacing, speed, graph;
the paper's delays; with and without the paper's noise), and the later orbit, gate, lanes,
tusi and grid teams (3-10 robots), every one passing what ``check --base p3dx`` asks of
bodies (``fits``): through the batch filter from a cold start no two P3-DX footprints ever
overlap, and the filter lets each formation's own motion through. The search for the member
the filter slows most (``families.search``) is deterministic and finds one. The filter's
guarantee and its assumptions are in docs/safety.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from formation_ilc.config.scenario import scenario_from_data
from formation_ilc.core.trajectory import AxisScales
from formation_ilc.model.footprint import clearance, footprint_of
from formation_ilc.model.safety import body_spec, desired_clearance, desired_through_filter
from formation_ilc.model.simulate import simulate
from formation_ilc.studies.families import KINDS, TEAMS, draw, family_scenario, fits, scenario_data

#: the first three kinds (the documented study's); the later ones are tested below
FIRST = KINDS[:3]
LATER = KINDS[3:]

FP = footprint_of("p3dx")
#: cold trials per member: the overlaps of an unfiltered team happen in its first trials
TRIALS = 6


def _spec(sc):
    return body_spec("p3dx", sc.dt, sc.uncertainty)


def _least_clearance(sc, spec) -> tuple[float, int]:
    """The least footprint clearance of ``sc``'s first TRIALS cold trials through the
    filter ``spec`` (None: no filter), and the filter's changes in them."""
    least = [np.inf]

    def on(k, xi, *rest):
        least[0] = min(least[0], float(clearance(xi, FP).min()))

    res = simulate(sc, TRIALS, plant="arc", safety=spec, on_trial_data=on)
    changed = int(np.nansum(res.column("filter_active"))) if spec is not None else 0
    return least[0], changed


def test_a_hundred_generated_formations_never_overlap_through_the_filter():
    """102 members: 34 of each kind, every third with the paper's noise. Without the
    filter many of them overlap in their first trials (the reason for the filter); through
    it none does."""
    members = [(kind, seed, seed % 3 == 0) for kind in FIRST for seed in range(34)]
    unfiltered_overlaps, acted = 0, 0
    for kind, seed, noise in members:
        sc = family_scenario(kind, seed, noise=noise)
        spec = _spec(sc)
        least, changed = _least_clearance(sc, spec)
        assert least > 0.0, f"{kind} {seed} (noise {noise}): footprints overlap by {-least:.3f} m"
        acted += changed > 0
        if seed % 6 == 0:  # a sample without the filter, for the contrast
            unfiltered_overlaps += _least_clearance(sc, None)[0] < 0.0
    assert len(members) >= 100
    assert acted > len(members) // 2  # the cold starts did put the filter to work
    assert unfiltered_overlaps >= 3  # and without it, they collide


@pytest.mark.parametrize("kind", KINDS)
def test_every_member_fits_a_pioneer_and_passes_the_filter_untouched(kind):
    for seed in range(3):
        sc = family_scenario(kind, seed)
        spec = _spec(sc)
        assert desired_clearance(sc, spec).fits
        assert desired_through_filter(sc, spec).passes
        assert TEAMS[kind][0] <= sc.n <= TEAMS[kind][1]
        assert sc.graph.leader.sum() > 0


def test_the_families_are_what_they_say():
    """Crossing robots pass through the formation's centre; following robots keep a
    column behind the leader; swapping robots change sides (y in the leader's frame)."""
    cross = scenario_from_data(scenario_data("crossing", 1), "", "<test>")
    assert all(s.mean == 0.0 and s.amplitude > 0 for s in cross.scales)
    follow = scenario_from_data(scenario_data("following", 1), "", "<test>")
    assert np.all(follow.offsets[:, 0] < 0) and np.all(follow.offsets[:, 1] == 0)
    swap = scenario_from_data(scenario_data("swapping", 1), "", "<test>")
    assert all(isinstance(s, AxisScales) for s in swap.scales)
    lead = swap.reference
    rel = swap.desired.eta[..., :2] - lead[None, : swap.desired.eta.shape[1], :2]
    c, s = np.cos(lead[: rel.shape[1], 2]), np.sin(lead[: rel.shape[1], 2])
    side = -s * rel[..., 0] + c * rel[..., 1]  # y in the leader's frame
    assert np.all(side.max(axis=1) > 0.5) and np.all(side.min(axis=1) < -0.5)


def test_a_draw_that_does_not_fit_is_drawn_again():
    # tight columns: some draws bring two bodies closer than the filter keeps them
    tight = [s for s in range(30) if not fits(draw("following", s))]
    assert tight, "every draw fit: the test no longer tests the redraw"
    sc = family_scenario("following", tight[0])
    assert fits(sc)
    assert sc.name == f"following-{tight[0]}"


def test_a_bad_kind_is_refused():
    with pytest.raises(ValueError, match="crossing, following, swapping"):
        scenario_data("zigzag", 1)


@pytest.mark.slow
def test_a_sample_of_the_families_on_the_physics_plant_never_touches():
    """Cold starts of a crossing and a swapping member on P3-DX bodies in the PyBullet
    world (one process, lockstep, exact poses): the bodies never touch nor tilt, and the
    error falls."""
    pytest.importorskip("pybullet")
    from formation_ilc.model.physics import MODELS
    from formation_ilc.studies.physics import run_physics

    for kind, seed in (("crossing", 0), ("swapping", 1)):
        sc = family_scenario(kind, seed).with_options(delay=False)
        res = run_physics(sc, MODELS["p3dx"], 4, safety=_spec(sc))
        assert not any(res.contacts), f"{kind} {seed}: {res.contacts}"
        assert min(c.value for c in res.clearance) > 0.0
        assert max(res.tilt) < np.radians(2.0)
        err = res.metrics[:, 3]  # the true error
        assert err[-1] < 0.7 * err[0]


@pytest.mark.parametrize("kind, seed", [("following", 13), ("crossing", 13)])
def test_a_noisy_member_learns_through_the_filter_as_well_as_without_it(kind, seed):
    """With the paper's noise the learned commands keep touching the base's limits; a
    memory that takes in only a share of a limit's clipping winds up outside the limits
    (following-13 ended at 1.51 m against 0.13 m without the filter, crossing-13 at 0.46
    against 0.14 m). Learned in full there (``core.through.learn_base``), each ends within 2x
    of the unfiltered run. Members beyond the documented study's seeds: not the ones the
    readings were chosen on."""
    sc = family_scenario(kind, seed, noise=True)
    trials = 100
    err = simulate(sc, trials, plant="arc", safety=_spec(sc)).column("max_position_error")
    free = simulate(sc, trials, plant="arc").column("max_position_error")
    assert err[-1] <= 2.0 * free[-1], (err[-1], free[-1])


def test_a_member_the_filter_trimmed_learns_as_fast_as_without_it():
    """Exact poses, the held-out member furthest beyond 2x before the Q-filter, which was
    not chosen on it: the filter's trims flicker from sample to sample, and the paper's
    law kept that flicker in the memory (swapping-19 ended trial 99 at 1.32 m against
    0.049 m without the filter, the filter still changing 233 commands a trial). Learned
    through the Q-filter (``core.through.smooth_learning``), it ends within 2x of the
    unfiltered run at the same trial, and the filter's changes fall to under a fiftieth of
    the first trial's. (Of the four held-out members furthest beyond 2x before the
    Q-filter, swapping-12 and crossing-13 still end at 2.1x: docs/safety.md.)"""
    sc = family_scenario("swapping", 19)
    trials = 100
    res = simulate(sc, trials, plant="arc", safety=_spec(sc))
    err = res.column("max_position_error")
    free = simulate(sc, trials, plant="arc").column("max_position_error")
    assert err[-1] <= 2.0 * free[-1], (err[-1], free[-1])
    changed = res.column("filter_active")
    assert changed[-10:].mean() < 0.02 * changed[0], (changed[0], changed[-10:])


# -- the later kinds: orbit, gate, lanes, tusi, grid ------------------------------------


@pytest.mark.parametrize("kind", LATER)
def test_a_later_kind_fits_a_pioneer_and_is_the_same_for_a_seed(kind):
    """Each later kind's members, exact and noisy, pass what ``check --base p3dx`` asks
    (``fits``: the base's limits, the filter's distance, the desired motion through the
    filter unchanged, for poses as noisy as the member's), and a seed draws the same
    member every time while another seed draws another."""
    from formation_ilc.model.safety import motion_fit

    for seed, noise in ((0, False), (1, False), (2, True)):
        sc = family_scenario(kind, seed, noise=noise)
        fit = motion_fit(sc, "p3dx", sc.uncertainty)
        assert fit.fits, (kind, seed, noise, fit.limits_line, fit.clearance.fits)
        assert TEAMS[kind][0] <= sc.n <= TEAMS[kind][1]
        assert (sc.uncertainty.pose_bounds()[0] > 0) == noise
        again = family_scenario(kind, seed, noise=noise)
        assert again.text == sc.text
        assert np.array_equal(again.desired.eta, sc.desired.eta)
    assert scenario_data(kind, 0) == scenario_data(kind, 0)
    assert scenario_data(kind, 0) != scenario_data(kind, 1)


def test_the_later_kinds_are_what_they_say():
    """tusi: every robot passes through the formation's centre, on its own line, the lines
    pi/n apart and its phase its line's angle (the team a regular polygon at every
    instant); orbit: every robot keeps its distance from the centre and goes round it;
    grid and lanes: teams of up to 10 robots; gate: the rows close to a column."""
    tusi = draw("tusi", 3)
    t = np.arange(0.0, 120.0, 0.2)
    pos = np.stack([s(t) for s in tusi.scales]) * tusi.offsets[:, None, :]  # leader frame
    radius = np.hypot(pos[..., 0], pos[..., 1])
    assert np.all(radius.min(axis=1) < 0.05)  # each through the centre
    n = tusi.n
    angles = np.sort(np.mod(np.arctan2(pos[:, 0, 1] - pos[:, 1, 1],
                                       pos[:, 0, 0] - pos[:, 1, 0]), np.pi))
    assert np.allclose(np.diff(angles), np.pi / n, atol=1e-6)  # lines pi/n apart
    centre_dist = np.hypot(*(pos - pos.mean(axis=0)).transpose(2, 0, 1))
    assert np.ptp(centre_dist) < 1e-6  # a regular polygon about its centre, rolling
    orbit = draw("orbit", 0)
    pos = np.stack([s(t) for s in orbit.scales]) * orbit.offsets[:, None, :]
    r = np.hypot(pos[..., 0], pos[..., 1])
    assert np.all(np.ptp(r, axis=1) < 1e-6) and np.all(r > 0.5)
    turned = np.unwrap(np.arctan2(pos[..., 1], pos[..., 0]), axis=1)
    assert np.all(np.abs(turned[:, -1] - turned[:, 0]) > np.pi)
    sizes = {family_scenario(k, s).n for k in ("grid", "lanes") for s in range(8)}
    assert max(sizes) == 10 and min(sizes) >= 4
    gate = draw("gate", 0)
    y = np.stack([s(t)[..., 1] for s in gate.scales]) * gate.offsets[:, None, 1:2][..., 0]
    spread = np.ptp(y, axis=0)
    assert spread.max() > 1.0 and spread.min() < 0.35 * spread.max()


def test_later_kinds_never_overlap_through_the_filter():
    """Three cold members of each later kind (one noisy) through the batch filter: no two
    P3-DX footprints overlap."""
    for kind in LATER:
        for seed, noise in ((0, False), (1, False), (0, True)):
            sc = family_scenario(kind, seed, noise=noise)
            least, _ = _least_clearance(sc, _spec(sc))
            assert least > 0.0, f"{kind} {seed} (noise {noise}): overlap by {-least:.3f} m"


# -- the search ----------------------------------------------------------------------


def test_perturb_moves_what_it_says_and_nothing_else():
    from formation_ilc.studies.families import perturb

    data = scenario_data("orbit", 4)
    n = data["robots"]
    assert perturb(data, [0.0] * (3 + n)) == data
    moved = perturb(data, [0.1, -0.1, 0.2] + [0.3] * n)
    assert moved["reference"]["speed"] == pytest.approx(data["reference"]["speed"] * np.exp(0.1))
    off, off0 = moved["formation"]["offsets"][1], data["formation"]["offsets"][1]
    assert off["x"] == pytest.approx(off0["x"] * np.exp(-0.1))
    sc, sc0 = moved["formation"]["scales"]["x1"], data["formation"]["scales"]["x1"]
    assert sc["period"] == pytest.approx(sc0["period"] * np.exp(0.2))
    assert sc["phase"] == pytest.approx(sc0["phase"] + 0.3)
    assert data["formation"]["scales"]["x1"] is not sc  # a copy


def test_the_search_is_deterministic_and_its_local_steps_find_worse_members():
    """A tiny budget: two random members, then eight local steps about the worse of them.
    The same seed gives the same members and ratios; the worst member found is a perturbed
    one (a step of the local search) whose ratio exceeds its starting member's, and it
    still fits a P3-DX team."""
    from formation_ilc.studies.families import scenario_of, search

    def run():
        return search(seed=1, trial=6, kinds=("gate", "lanes"), random_budget=2,
                      local_budget=8, starts=1, noise_share=0.0)

    first, second = run(), run()
    assert [(m.name, m.x, m.safe, m.free) for m in first] == \
           [(m.name, m.x, m.safe, m.free) for m in second]
    starts = [m for m in first if not any(m.x)]
    worst = first[0]
    start = next(m for m in starts if (m.kind, m.seed) == (worst.kind, worst.seed))
    assert any(worst.x), "the local search found nothing worse than its start"
    assert worst.ratio > start.ratio
    assert fits(scenario_of(worst.data))
