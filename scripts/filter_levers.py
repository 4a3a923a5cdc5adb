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

from filter_binds import Through, changed_commands, heard_pairs  # noqa: E402

from formation_ilc.config.scenario import load_scenario  # noqa: E402
from formation_ilc.core.estimate import box_centre, box_error  # noqa: E402

LEVERS = ("now", "support", "intent", "intent+support")


def deficits(st: Through, wish, t, i, j, lever):
    """The worst deficit [m] over the pairs of discs of robots i and j under ``lever``:
    robot i's ``wish`` against robot j, whose intention is what the filter left it."""
    boxes = st.boxes
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
    h, rows_i = heard_pairs(st, wish, t, i, j, xi, yi, xj, yj, err)
    _, rows_j = heard_pairs(st, st.u, t, j, i, xj, yj, xi, yi, err)
    nd = len(st.spec.discs)
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
    wish = sc.desired.u
    print(f"{a.scenario} on {a.base}: the binding pair's deficit [mm] per changed command "
          f"(> 0: the barrier cuts the desired command)")
    print("robot  t[s]  vs  " + "  ".join(f"{m:>15s}" for m in LEVERS))
    left = dict.fromkeys(LEVERS, 0)
    for st, t, i in changed_commands(sc, a.base, sc.uncertainty.noisy):
        # the robot whose pair binds hardest now
        js = [j for j in range(sc.n) if j != i]
        j = js[int(np.argmax([deficits(st, wish, t, i, j, "now") for j in js]))]
        # each lever judged on every other robot's pairs, not only the binding one's
        row = [max(deficits(st, wish, t, i, o, m) for o in js) for m in LEVERS]
        for m, x in zip(LEVERS, row, strict=True):
            left[m] += x > 0.0
        print(f"{i + 1:5d} {t * sc.dt:5.1f} {j + 1:3d}  "
              + "  ".join(f"{1000 * x:+15.1f}" for x in row))
    print("commands still cut: " + ", ".join(f"{m} {left[m]}" for m in LEVERS))
    return 0


if __name__ == "__main__":
    sys.exit(main())
