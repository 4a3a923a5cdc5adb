"""The safety filter's named steps, each on its own (``core.barrier``, ``core.nearest``):
the box and the reach of a command, another robot's motion, the pairs' half-planes, the
shares of a pair's slack, the command nearest to the wish. ``filter_command`` composes them
(its behaviour: ``test_safety.py``); each step runs plain here and compiled where noted."""

from __future__ import annotations

import math

import numpy as np
import pytest

from formation_ilc.core.barrier import (
    PARAMS,
    _carry,
    chords,
    heard_motion,
    limits_box,
    numbers,
    own_reach,
    pair_constraints,
    planes_room,
    share,
    wish_reach,
)
from formation_ilc.core.limits import Limits
from formation_ilc.core.nearest import nearest_to_wish
from formation_ilc.core.safety import CHANGED_BARRIER, INFEASIBLE
from formation_ilc.model.footprint import footprint_of
from formation_ilc.model.safety import spec_for

P3 = Limits(1.2, math.radians(300), 0.3, math.radians(100))
DT = 0.2


def sample(v_prev=0.5, w_prev=0.1, v_n=0.55, w_n=0.1, limits=P3, own_bound=True,
           radius=None):
    params = spec_for(footprint_of("p3dx"), limits, DT, radius=radius).params()
    params[PARAMS.index("own_bound")] = 1.0 if own_bound else 0.0
    k = numbers(params)
    r = own_reach(v_prev, w_prev, k, params)
    w = wish_reach(v_n, w_n, k, r, own_bound)
    return k, r, w, chords(k, r, w)


def test_the_box_is_one_sample_of_acceleration_inside_the_speed_limits():
    assert limits_box(0.5, 0.0, 1.2, 5.0, 0.3, 1.0, DT) == pytest.approx(
        (0.44, 0.56, -0.2, 0.2))
    # at the speed limit the box stops there
    assert limits_box(1.2, 0.0, 1.2, 5.0, 0.3, 1.0, DT)[1] == 1.2
    # a previous command beyond the limit: the nearest edge, not an empty box
    assert limits_box(2.0, -9.0, 1.2, 5.0, 0.3, 1.0, DT) == (1.2, 1.2, -5.0, -5.0)
    # no limit: a large finite box (polygon clipping needs corners)
    v_lo, v_hi, _, _ = limits_box(0.0, 0.0, math.inf, math.inf, math.inf, math.inf, DT)
    assert v_lo == -1e6 and v_hi == 1e6


@pytest.mark.parametrize("v_prev", [-0.8, -0.02, 0.0, 0.03, 0.9])
def test_the_chords_with_their_errors_bound_the_carried_distance_over_the_box(v_prev):
    k, r, _, p = sample(v_prev=v_prev, w_prev=-0.4 * v_prev)
    for v in np.linspace(r.v_lo, r.v_hi, 41):
        chord = r.fv0 + r.kv * (v - r.v_lo)
        f = _carry(v, k.dt, r.a_b)
        assert chord - r.ev_dn - 1e-12 <= f <= chord + r.ev_up + 1e-12
    for w in np.linspace(r.w_lo, r.w_hi, 41):
        chord = r.g_off + r.kw * w
        g = _carry(w, k.dt, r.al_b)
        assert chord - r.ew_dn - 1e-12 <= g <= chord + r.ew_up + 1e-12
    # the braking command lies in the box and slows down
    assert r.v_lo <= r.vb <= r.v_hi and abs(r.vb) <= abs(v_prev)
    assert p.bx0 == r.v_lo and p.by1 == pytest.approx(k.c * r.w_hi)


def test_the_wish_is_judged_by_its_own_bound_only_inside_the_box():
    _, _, w, _ = sample(v_n=0.55)
    assert w.inside and w.judge
    _, _, w, _ = sample(v_n=0.55, own_bound=False)
    assert w.inside and not w.judge
    _, _, w, _ = sample(v_n=0.9)  # beyond one sample of acceleration
    assert not w.inside and not w.judge


def heard(k, r, x=1.0, y=0.0, th=math.pi, vx=-0.5, vy=0.0, wj=0.0, told=False, err=0.0,
          age=0.0):
    return heard_motion(x, y, th, vx, vy, wj, told, err, age, 0.0, 0.0, k, r)


def test_another_robot_beyond_the_radius_or_far_off_is_not_near():
    k, r, _, _ = sample()
    assert heard(k, r).near
    assert not heard(k, r, x=k.radius * 1.01).near
    # inside the radius but so far apart that no command of the box can meet a barrier
    k, r, _, _ = sample(radius=20.0)
    assert heard(k, r, x=5.0, vx=0.0).near
    assert not heard(k, r, x=15.0, vx=0.0).near


def test_an_old_pose_is_moved_on_by_its_motion_and_widens_the_distance():
    k, r, _, _ = sample()
    now = heard(k, r)
    old = heard(k, r, age=0.3)
    # the robot closes in at 0.5 m/s: 0.3 s on it is 0.15 m nearer
    assert old.ox == pytest.approx(1.0 - 0.5 * 0.3)
    assert old.dj > now.dj and old.sig > now.sig
    assert heard(k, r, err=0.05).dj == pytest.approx(now.dj + 0.05)
    # a told command is as wrong as told_uncertainty, not as the estimate's lag allows
    assert heard(k, r, told=True).sig <= now.sig


def test_the_two_shares_of_a_pair_add_up_to_twice_gamma_and_lean_to_the_one_behind():
    rng = np.random.default_rng(5)
    for _ in range(200):
        gamma = rng.uniform(0.05, 0.5)
        ang = rng.uniform(-math.pi, math.pi)
        n = (math.cos(ang), math.sin(ang))  # from j's disc to i's
        hi, hj = rng.uniform(-math.pi, math.pi, 2)
        a0_i = -(n[0] * math.cos(hi) + n[1] * math.sin(hi))
        a0_j = n[0] * math.cos(hj) + n[1] * math.sin(hj)
        s_i = share(gamma, a0_i, n[0], n[1], math.cos(hj), math.sin(hj))
        s_j = share(gamma, a0_j, -n[0], -n[1], math.cos(hi), math.sin(hi))
        assert s_i + s_j == pytest.approx(2 * gamma)
        assert s_i >= 0 and s_j >= 0
    # robot i right behind robot j, both heading the same way (towards +x): i closes in
    behind = share(0.5, 1.0, -1.0, 0.0, 1.0, 0.0)
    ahead = share(0.5, -1.0, 1.0, 0.0, 1.0, 0.0)
    assert behind == pytest.approx(0.95) and ahead == pytest.approx(0.05)


@pytest.mark.parametrize("compiled", [False, True])
def test_head_on_the_pair_gives_half_planes_the_braking_command_keeps(compiled):
    k, r, w, p = sample(v_prev=0.3, w_prev=0.0, v_n=0.35, w_n=0.0)
    h = heard(k, r, x=1.2, vx=-0.3)  # 1.2 m apart, closing in at 0.3 m/s each
    room = planes_room(1, k.n_discs)
    ha0, ha1, hb = np.empty(room), np.empty(room), np.empty(room)
    fn = pair_constraints.jit if compiled else pair_constraints
    m, barrier, infeasible = fn(k, r, w, p, h, 0.0, 0.0, 1.0, 0.0, ha0, ha1, hb, 0)
    assert 0 < m <= room and barrier and not infeasible
    # every half-plane ha0 v + ha1 (c w) >= hb is kept by braking, cuts off the wish
    # (speeding up head-on) in one at least
    vb, cwb = r.vb, k.c * r.wb
    assert np.all(ha0[:m] * vb + ha1[:m] * cwb >= hb[:m] - 1e-12)
    assert np.any(ha0[:m] * w.zx + ha1[:m] * w.zy < hb[:m])
    # the same robot driving away: nothing binds
    h = heard(k, r, x=1.2, th=0.0, vx=0.3)
    m, barrier, infeasible = fn(k, r, w, p, h, 0.0, 0.0, 1.0, 0.0, ha0, ha1, hb, 0)
    assert not barrier and not infeasible


def test_a_pair_past_braking_apart_is_infeasible():
    k, r, w, p = sample(v_prev=0.8, w_prev=0.0, v_n=0.8, w_n=0.0)
    h = heard(k, r, x=k.dist * 0.5, vx=-0.8)  # discs overlap already
    room = planes_room(1, k.n_discs)
    ha0, ha1, hb = np.empty(room), np.empty(room), np.empty(room)
    _, _, infeasible = pair_constraints(k, r, w, p, h, 0.0, 0.0, 1.0, 0.0, ha0, ha1, hb, 0)
    assert infeasible


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("compiled", [False, True])
def test_the_nearest_command_is_the_grid_optimum_of_the_cut_box(seed, compiled):
    rng = np.random.default_rng(seed)
    k, r, w, p = sample(v_prev=rng.uniform(-0.5, 0.5), w_prev=rng.uniform(-1, 1),
                        v_n=rng.uniform(-1, 1), w_n=rng.uniform(-2, 2))
    m = 3
    ang = rng.uniform(-math.pi, math.pi, m)
    ha0, ha1 = np.cos(ang), np.sin(ang)
    # each half-plane through a point of the box: the cut box is not empty there
    cx, cy = 0.5 * (p.bx0 + p.bx1), 0.5 * (p.by0 + p.by1)
    hb = ha0 * cx + ha1 * cy - rng.uniform(0, 0.01, m)
    out = np.zeros(2)
    fn = nearest_to_wish.jit if compiled else nearest_to_wish
    flags = fn(k, r, w, ha0, ha1, hb, m, 0, out)
    assert flags == 0
    vs, cws = np.meshgrid(np.linspace(p.bx0, p.bx1, 301), np.linspace(p.by0, p.by1, 301))
    ok = np.all([a * vs + b * cws >= c - 1e-12
                 for a, b, c in zip(ha0, ha1, hb, strict=True)], axis=0)
    d = (vs - w.zx) ** 2 + (cws - w.zy) ** 2
    best = d[ok].min()
    got = (out[0] - w.zx) ** 2 + (k.c * out[1] - w.zy) ** 2
    step = max(p.bx1 - p.bx0, p.by1 - p.by0) / 300
    assert got <= best + 1e-12
    assert got >= best - 4 * step * math.sqrt(best) - 2 * step * step
    assert p.bx0 <= out[0] <= p.bx1 and r.w_lo <= out[1] <= r.w_hi


def test_with_nothing_left_in_the_box_the_robot_brakes():
    k, r, w, p = sample(v_prev=0.8, w_prev=0.3)
    # v >= 5 m/s: no command of the box
    out = np.zeros(2)
    flags = nearest_to_wish(k, r, w, np.array([1.0]), np.array([0.0]), np.array([5.0]), 1, 0,
                            out)
    assert flags == CHANGED_BARRIER | INFEASIBLE
    assert tuple(out) == (r.vb, r.wb) and r.vb < 0.8
