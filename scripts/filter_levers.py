#!/usr/bin/env python3
"""What each candidate lever would leave of the filter's changes to a formation's own motion.

    .venv/bin/python scripts/filter_levers.py [SCENARIO] [--base p3dx]

Runs the desired motion through the filter as ``check --base`` does (``filter_binds.py``:
the scenario's noise, its first trial's draw, speeds told) and, for every command the
filter changes, prints the deficit of its binding pair of discs (``filter_binds.py``'s
X_n - room, in mm; > 0: the barrier cuts the desired command) as the filter counts it now
and as two levers would count it (measurements, not filters: neither is built):

* ``support``: the room for the poses' noise as the two position boxes' extent along the
  pair's direction (|n_x| (hx_i + hx_j) + |n_y| (hy_i + hy_j)) instead of the sum of their
  half-diagonals. A lower bound of the true distance either way (project the true
  difference on the estimated direction); it needs no assumption the filter does not make.
* ``intent``: robot j has told the command it applies over this sample (its intention)
  before robot i filters, so the pair's closing X_i + X_j <= g is kept with robot j's own
  X_j (that command held a sample, then braked, as ``wish_reach`` bounds it) in place of
  B_j + robot j's share: robot i's room is g - X_j. Sound only if robot j applies what it
  told for the whole sample (no robot braking alone mid-sample: see docs/safety.md,
  "No more conservative than the robots").

Each lever's deficit is the worst over every other robot's pairs of discs; the robot named
(``vs``) is the one that binds as the filter counts now (robot 1 for paper-triangle3's
robot 3).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from filter_binds import pair_terms  # noqa: E402

from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.core import barrier as B  # noqa: E402
from formation_ilc.core.estimate import BOX, box_centre, box_error  # noqa: E402
from formation_ilc.core.safety import CHANGED, OTHER_FIELDS, filter_team, told  # noqa: E402
from formation_ilc.model.safety import TOLERANCE, body_spec  # noqa: E402

LEVERS = ("now", "support", "intent", "intent+support")


def deficits(k, params, discs, boxes, eta, before, wish, applied, t, i, j, lever):
    """The worst deficit [m] over the pairs of discs of robots i and j under ``lever``:
    robot i's ``wish`` against robot j, whose intention is what it ``applied``."""
    support, intent = "support" in lever, "intent" in lever
    xi, yi = box_centre(boxes, i)
    xj, yj = box_centre(boxes, j)
    nx, ny = xi - xj, yi - yj
    nn = math.hypot(nx, ny)
    nx, ny = nx / nn, ny / nn
    if support:
        hw = [(0.5 * (boxes[r, 1] - boxes[r, 0]), 0.5 * (boxes[r, 3] - boxes[r, 2]))
              for r in (i, j)]
        err = abs(nx) * (hw[0][0] + hw[1][0]) + abs(ny) * (hw[0][1] + hw[1][1])
    else:
        err = box_error(boxes, i) + box_error(boxes, j)

    def side(a, b, xa, ya, xb, yb, cmd):
        r = B.own_reach(float(before[a, 0]), float(before[a, 1]), k, params)
        w = B.wish_reach(float(cmd[a, t, 0]), float(cmd[a, t, 1]), k, r, True)
        row = np.zeros((1, OTHER_FIELDS))
        told(eta[b, t, 2], before[b, 0], before[b, 1], row, 0)
        h = B.heard_motion(xb, yb, eta[b, t, 2], row[0, 3], row[0, 4], row[0, 5], True, err,
                           0.0, xa, ya, k, r)
        return h, pair_terms(k, r, w, h, xa, ya, eta[a, t, 2], discs)

    h, rows_i = side(i, j, xi, yi, xj, yj, wish)
    _, rows_j = side(j, i, xj, yj, xi, yi, applied)
    nd = len(discs)
    worst = -math.inf
    for a in range(nd):
        for b in range(nd):
            p = rows_i[a * nd + b]
            if intent:  # robot j's own X for its told command; robot i takes what is left
                worst = max(worst, p["x_n"] - (p["dd"] - h.dj - rows_j[b * nd + a]["x_n"]))
            else:
                worst = max(worst, p["deficit"])
    return worst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", nargs="?", default="paper-triangle3")
    ap.add_argument("--base", default="p3dx")
    a = ap.parse_args()
    sc = load_scenario(a.scenario).for_plant("arc")
    noisy = sc.uncertainty.noisy
    spec = body_spec(a.base, sc.dt, sc.uncertainty if noisy else None, "commands")
    d = sc.desired
    eta = np.ascontiguousarray(d.eta)
    if noisy:
        eta = np.ascontiguousarray(
            eta + sc.uncertainty.draw_plant(sc.seed, 0, eta.shape[0], d.u.shape[1])[2])
    n, n_t = d.u.shape[0], d.u.shape[1]
    u = np.array(d.u, dtype=float)
    nominal, flags = np.empty_like(u), np.zeros((n, n_t), dtype=np.int64)
    prev, params = np.zeros((n, 2)), spec.params()
    k = B.numbers(params)
    others, ages, boxes = np.zeros((n, OTHER_FIELDS)), np.zeros(n), np.zeros((n, BOX))
    print(f"{a.scenario} on {a.base}: the binding pair's deficit [mm] per changed command "
          f"(> 0: the barrier cuts the desired command)")
    print("robot  t[s]  vs  " + "  ".join(f"{m:>15s}" for m in LEVERS))
    left = dict.fromkeys(LEVERS, 0)
    for t in range(n_t):
        before = prev.copy()
        filter_team.jit(t, u, eta, prev, 0.0, params, spec.window, nominal, flags, others,
                        ages, boxes)
        diff = np.abs(u[:, t] - d.u[:, t])
        for i in range(n):
            if not (flags[i, t] & CHANGED and (diff[i, 0] > TOLERANCE[0]
                                               or diff[i, 1] > TOLERANCE[1])):
                continue
            # the robot whose pair binds hardest now
            js = [j for j in range(n) if j != i]
            now = [deficits(k, params, spec.discs, boxes, eta, before, d.u, u, t, i, j, "now")
                   for j in js]
            j = js[int(np.argmax(now))]
            # each lever judged on every other robot's pairs, not only the binding one's
            row = [max(deficits(k, params, spec.discs, boxes, eta, before, d.u, u, t, i, o, m)
                       for o in js) for m in LEVERS]
            for m, x in zip(LEVERS, row, strict=True):
                left[m] += x > 0.0
            print(f"{i + 1:5d} {t * sc.dt:5.1f} {j + 1:3d}  "
                  + "  ".join(f"{1000 * x:+15.1f}" for x in row))
        prev[:] = d.u[:, t]
    print("commands still cut: " + ", ".join(f"{m} {left[m]}" for m in LEVERS))
    return 0


if __name__ == "__main__":
    sys.exit(main())
