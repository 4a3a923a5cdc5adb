#!/usr/bin/env python3
"""What makes the safety filter change a formation's own desired motion (docs/safety.md).

    .venv/bin/python scripts/filter_binds.py [SCENARIO] [--base p3dx] [--exact] [--offsets K]

Runs every robot's desired command through the filter as ``check --base`` does
(``model.safety.desired_through_filter``: the desired poses with the scenario's noise, or
exact with ``--exact``, speeds told), and for every command it changes prints the pair of
discs that binds hardest and the terms of its barrier: the discs' distance dd, the gap
g = dd - D - (the two positions' error: the noise's room), robot i's own closing X_n of
the desired command (held a sample, then braked) split into its hold (a0 v dT), its
braking and its turn, B_i (robot i braking now), B_j (robot j braking now: its straight
part, then its turn's), the slack g - B_i - B_j, robot i's share of it, and the deficit
X_n - (B_i + share x slack) (> 0: the barrier cuts the desired command). The terms are
``core.barrier.pair_constraints``'s, recomputed here in the open (keep the two alike).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from formation_ilc.config.scenario import Scenario, load_scenario  # noqa: E402
from formation_ilc.core import barrier as B  # noqa: E402
from formation_ilc.core.estimate import BOX, box_centre, box_error  # noqa: E402
from formation_ilc.core.safety import (  # noqa: E402
    CHANGED,
    OTHER_FIELDS,
    SafetySpec,
    filter_team,
    told,
)
from formation_ilc.model.safety import TOLERANCE, body_spec  # noqa: E402


def pair_terms(k, r, w, h, x, y, th, discs):
    """Every pair of discs of robot i (pose x, y, th; reach r, wish w) and robot j (h)."""
    cth, sth = math.cos(th), math.sin(th)
    rows = []
    for ell in discs:
        sx, sy = x + ell * cth - h.ox, y + ell * sth - h.oy
        for ellj in discs:
            dx, dy = sx - ellj * h.cj, sy - ellj * h.sj
            dd = math.hypot(dx, dy)
            ux, uy = dx / dd, dy / dd
            a0 = -(ux * cth + uy * sth)
            bside = ux * sth - uy * cth
            a1c = ell * bside
            sp = a1c + (r.path_i * bside if bside > 0 else 0.0) + r.q_i
            sm = a1c + (r.path_i * bside if bside < 0 else 0.0) - r.q_i
            b_i = a0 * r.f_b + (sp * r.g_b if r.g_b >= 0 else sm * r.g_b)
            s_j = ux * h.vxj + uy * h.vyj + h.sig
            if s_j >= 0:
                r_j = s_j * h.tau_j
            elif h.v_dn > 0 and a0 * r.a_b * h.v_dn <= -s_j * k.a_max:
                r_j = s_j * h.tau_jlo
            else:
                r_j = s_j * h.tau_jsoon
            turn_j = B.turn_closing(h, ellj, ux, uy, k.l_max)
            b_j = r_j + turn_j
            slack = dd - h.dj - b_i - b_j
            mine = B.share(k.share, a0, ux, uy, h.cj, h.sj)
            room = b_i + mine * max(slack, 0.0)
            bend = w.path_n * bside
            turn = ((a1c + (bend if bside > 0 else 0.0) + w.q_n) * w.g_n if w.g_n >= 0
                    else (a1c + (bend if bside < 0 else 0.0) - w.q_n) * w.g_n)
            hold = a0 * w.zx * k.dt
            rows.append(dict(dd=dd, g=dd - h.dj, b_i=b_i, r_j=r_j, turn_j=turn_j, b_j=b_j,
                             slack=slack, share=mine, room=room, x_n=a0 * w.f_n + turn,
                             hold=hold, brake=a0 * w.f_n - hold, turn=turn,
                             deficit=a0 * w.f_n + turn - room))
    return rows


@dataclass
class Through:
    """The desired motion through the filter at one sample: ``before`` the commands of the
    sample before (told), ``boxes`` the position boxes, ``u`` what the filter left."""

    sc: Scenario
    spec: SafetySpec
    k: Any
    params: Any
    eta: np.ndarray
    before: np.ndarray
    boxes: np.ndarray
    u: np.ndarray


def changed_commands(sc: Scenario, base: str, noisy: bool) -> Iterator[tuple[Through, int, int]]:
    """(state, t, i) for every command of robot i at sample t that the filter changes
    beyond ``TOLERANCE`` as ``check --base`` runs it (the desired poses with the
    scenario's noise, its first trial's draw, when ``noisy``; speeds told)."""
    spec = body_spec(base, sc.dt, sc.uncertainty if noisy else None, "commands")
    d = sc.desired
    eta = np.ascontiguousarray(d.eta)
    if noisy:
        eta = np.ascontiguousarray(
            eta + sc.uncertainty.draw_plant(sc.seed, 0, eta.shape[0], d.u.shape[1])[2])
    n, n_t = d.u.shape[0], d.u.shape[1]
    u = np.array(d.u, dtype=float)
    nominal, flags = np.empty_like(u), np.zeros((n, n_t), dtype=np.int64)
    prev, params = np.zeros((n, 2)), spec.params()
    others, ages, boxes = np.zeros((n, OTHER_FIELDS)), np.zeros(n), np.zeros((n, BOX))
    state = Through(sc, spec, B.numbers(params), params, eta, prev, boxes, u)
    for t in range(n_t):
        state.before = prev.copy()
        filter_team.jit(t, u, eta, prev, 0.0, params, spec.window, nominal, flags, others,
                        ages, boxes)
        diff = np.abs(u[:, t] - d.u[:, t])
        for i in range(n):
            if flags[i, t] & CHANGED and (diff[i, 0] > TOLERANCE[0]
                                          or diff[i, 1] > TOLERANCE[1]):
                yield state, t, i
        prev[:] = d.u[:, t]


def heard_pairs(st: Through, cmd: np.ndarray, t: int, a: int, b: int, xa: float, ya: float,
                xb: float, yb: float, err: float) -> tuple[Any, list[dict]]:
    """Robot a's command ``cmd[a, t]`` against robot b as the filter hears b (at xb, yb,
    its last command told; ``err`` the two positions' error): b's heard motion and the
    terms of every pair of their discs (``pair_terms``)."""
    r = B.own_reach(float(st.before[a, 0]), float(st.before[a, 1]), st.k, st.params)
    w = B.wish_reach(float(cmd[a, t, 0]), float(cmd[a, t, 1]), st.k, r, True)
    row = np.zeros((1, OTHER_FIELDS))
    told(st.eta[b, t, 2], st.before[b, 0], st.before[b, 1], row, 0)
    h = B.heard_motion(xb, yb, st.eta[b, t, 2], row[0, 3], row[0, 4], row[0, 5], True, err,
                       0.0, xa, ya, st.k, r)
    return h, pair_terms(st.k, r, w, h, xa, ya, st.eta[a, t, 2], st.spec.discs)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", nargs="?", default="paper-triangle3")
    ap.add_argument("--base", default="p3dx")
    ap.add_argument("--exact", action="store_true", help="exact poses (no noise, no room)")
    ap.add_argument("--offsets", type=float, default=1.0, help="the offsets x this")
    a = ap.parse_args()
    sc = load_scenario(a.scenario).for_plant("arc")
    if a.offsets != 1.0:
        sc = replace(sc, offsets=sc.offsets * a.offsets)
    noisy = not a.exact and sc.uncertainty.noisy
    distance = body_spec(a.base, sc.dt, sc.uncertainty if noisy else None,
                         "commands").distance
    print(f"{a.scenario} on {a.base}, {'exact poses' if not noisy else 'noisy poses'}: "
          f"D = {distance:.3f} m; per changed command, its binding pair of discs [m]")
    print("robot  t[s]  vs  apart   dd     room4noise  g     X_n = hold + brake + turn"
          "      B_i    B_j (straight, turn)    slack  share  deficit")
    changed = 0
    for st, t, i in changed_commands(sc, a.base, noisy):
        changed += 1
        x, y = box_centre(st.boxes, i)
        worst = None
        for j in range(sc.n):
            if j == i:
                continue
            ox, oy = box_centre(st.boxes, j)
            err = box_error(st.boxes, j) + box_error(st.boxes, i)
            h, pairs = heard_pairs(st, sc.desired.u, t, i, j, x, y, ox, oy, err)
            if not h.near:
                continue
            for pair in pairs:
                pair.update(j=j, err=err, apart=math.hypot(x - ox, y - oy))
                if worst is None or pair["deficit"] > worst["deficit"]:
                    worst = pair
        assert worst is not None, "a changed command has a robot near"
        p = worst
        print(f"{i + 1:5d} {t * sc.dt:5.1f} {p['j'] + 1:3d} {p['apart']:6.3f} "
              f"{p['dd']:6.3f} {p['err']:8.3f} {p['g']:8.3f}  {p['x_n']:6.3f} = "
              f"{p['hold']:5.3f} + {p['brake']:5.3f} + {p['turn']:5.3f} "
              f"{p['b_i']:6.3f} {p['b_j']:+6.3f} ({p['r_j']:+6.3f}, {p['turn_j']:5.3f}) "
              f"{p['slack']:6.3f} {p['share']:6.3f} {1000 * p['deficit']:+6.1f} mm")
    print(f"{changed} commands changed")
    return 0


if __name__ == "__main__":
    sys.exit(main())
