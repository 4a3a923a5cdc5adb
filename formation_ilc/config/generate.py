"""A scenario for a team of any size, written from a formation pattern and a graph rule.

``formation-ilc team N`` writes one (``team_yaml``); the built-in ``team50`` is its default
for 50 robots. Everything but the team comes from a base scenario (default paper-hexagon6:
its reference, sample time, trial length, law and gains, uncertainty and delays), so a
large team learns the paper's study.

* **Patterns** (world-frame offsets from the reference, at least ``spacing`` apart), robots
  numbered along the pattern's path (each next one ``spacing`` from the one before):
  ``grid`` (rows of ``columns`` robots, centred, numbered left to right, then right to left
  in the next row, and so on; ``columns`` defaults to about twice the number of rows) and
  ``ring`` (one circle, numbered counter-clockwise).
* **Graph rule** ``relay`` (the paper's leader-relay tree, paper-notes 11, which
  paper-hexagon6 is for six robots in a ring): along the path, the robots go three at a
  time: the middle one
  sees the leader and its two path neighbours follow it (a last pair: the first sees the
  leader, the second follows). Every robot is one hop from the leader at most and relays
  to at most two: condition (20) holds as for paper-hexagon6, whatever the team's size
  (a deeper or bushier tree of unit weights fails it from a few hops and children on).
  All weights are 1, as in the paper's graphs.
"""

from __future__ import annotations

import math
from typing import Any

import yaml

from formation_ilc.config.scenario import load_scenario, scenario_from_text

__all__ = ["PATTERNS", "GRAPH_RULES", "positions", "relay_tree", "team_yaml"]

PATTERNS = ("grid", "ring")
GRAPH_RULES = ("relay",)


def positions(pattern: str, n: int, spacing: float, columns: int | None = None
              ) -> list[tuple[float, float]]:
    """Offsets (x, y) [m] of robots 1..n in ``pattern``, centred on the origin."""
    if n < 1:
        raise ValueError(f"a team has at least 1 robot, got {n}")
    if not spacing > 0:
        raise ValueError(f"the spacing must be positive, got {spacing}")
    if pattern == "grid":
        cols = min(n, columns or max(1, math.ceil(math.sqrt(2 * n))))
        rows = math.ceil(n / cols)
        out = []
        for i in range(n):
            r, c = divmod(i, cols)
            if r % 2:  # every other row right to left: the path turns, one spacing on
                c = cols - 1 - c
            out.append(((c - (cols - 1) / 2) * spacing, ((rows - 1) / 2 - r) * spacing))
        return out
    if pattern == "ring":
        if n == 1:
            return [(0.0, 0.0)]
        radius = spacing / (2 * math.sin(math.pi / n))  # neighbours one chord apart
        return [(radius * math.cos(2 * math.pi * i / n), radius * math.sin(2 * math.pi * i / n))
                for i in range(n)]
    raise ValueError(f"pattern must be one of {', '.join(PATTERNS)}, got {pattern!r}")


def relay_tree(n: int) -> tuple[list[int], list[tuple[int, int]]]:
    """The ``relay`` rule for robots 1..n along the path: (robots that see the leader,
    edges (from, to))."""
    roots: list[int] = []
    edges: list[tuple[int, int]] = []
    for k in range(0, n, 3):
        group = list(range(k, min(n, k + 3)))
        relay = group[1] if len(group) == 3 else group[0]
        roots.append(relay + 1)
        edges += [(relay + 1, i + 1) for i in group if i != relay]
    return sorted(roots), sorted(edges, key=lambda e: e[1])


def team_yaml(n: int, pattern: str = "grid", graph: str = "relay", spacing: float = 1.5,
              columns: int | None = None, base: str = "paper-hexagon6",
              name: str | None = None) -> str:
    """The scenario file's text of a team of ``n`` robots (validated: it loads). ValueError
    for an option no team can have; ScenarioError for a base that does not load."""
    if graph not in GRAPH_RULES:
        raise ValueError(f"graph rule must be one of {', '.join(GRAPH_RULES)}, got {graph!r}")
    pos = positions(pattern, n, spacing, columns)
    roots, edges = relay_tree(n)
    src = load_scenario(base)
    data: dict[str, Any] = yaml.safe_load(src.text)
    name = name or f"team{n}"
    head = {
        "name": name,
        "description": (
            f"{n} robots in a {pattern} {spacing:g} m apart, fixed in the world frame; graph "
            f"rule '{graph}': along the {pattern}, every third robot sees the leader and its "
            f"two neighbours follow it (all weights 1). Reference, timing, law, uncertainty "
            f"and delays of {src.name}. Written by `formation-ilc team {n}` "
            f"(formation_ilc/config/generate.py)."),
        "dt": data["dt"], "samples": data["samples"], "trials": data["trials"],
        "seed": data.get("seed", 0), "robots": n,
    }
    data.pop("formation", None)
    data.pop("graph", None)
    for key in head:
        data.pop(key, None)
    formation = {"frame": "world", "offsets": {
        i + 1: {"x": round(x, 9), "y": round(y, 9)} for i, (x, y) in enumerate(pos)}}
    graph_doc = {"leader": {r: 1.0 for r in roots},
                 "edges": [{"from": a, "to": b} for a, b in edges]}
    text = (f"# {name}: written by `formation-ilc team {n}`; edit freely.\n"
            + yaml.safe_dump(head, sort_keys=False, width=90)
            + yaml.safe_dump({"formation": formation, "graph": graph_doc}, sort_keys=False,
                             default_flow_style=None, width=90)
            + yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=90))
    scenario_from_text(text, f"{name} (generated)")
    return text
