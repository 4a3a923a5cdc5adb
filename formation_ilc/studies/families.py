"""Families of formations nobody tuned: robots that cross, follow and swap.

The safety filter is judged on scenarios it never saw, not on the paper's two. Each
family draws a scenario from a seed: team size, spacing, speeds, periods, phases, graph
and delays at random, within what a Pioneer 3-DX-size team can fly (every drawn scenario
passes ``formation-ilc check --base p3dx``: its desired motion inside the base's limits
and its bodies kept apart by the filter's distance; a draw that does not is drawn again):

* ``crossing``: every robot oscillates on its own line through the formation's centre
  (lines spread over half a turn, phases staggered), while the leader drives straight;
  robots that are not graph neighbours pass close to each other;
* ``following``: a column behind the leader, 0.8 to 1.4 m apart, the spacing breathing,
  on a straight line, a circle or a figure eight: a robot follows another at the
  leader's speed;
* ``swapping``: two rows, left and right; each robot moves across to the other row
  (through the centre line, pairs at different times) while the team drives a circle.

Every scenario: 4 to 6 robots, dT = 0.2 s, 30 s trials, eased in from rest (``desired.ramp``)
so that it starts inside the acceleration limit; a random spanning tree from the leader
(Theorem 2 holds by construction); the paper's delays (or none); the paper's noise and
disturbances (or none; a noisy member is drawn 1.5 times as wide, as the filter keeps room
for the poses' error). Gains: the paper's law (9), gain 0.3 / gain' 0.6 for every robot,
which meet condition (20) and learn these teams in tens of trials without a filter.

``family(kind, seeds, ...)`` yields them; ``scenario_data`` gives the parsed form, which a
study may edit and ``scenario_from_data`` validates. Pure numpy and the config layer: no ROS.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import yaml

from formation_ilc.config.scenario import Scenario, scenario_from_data

__all__ = ["KINDS", "scenario_data", "draw", "family_scenario", "family", "DT", "SAMPLES"]

KINDS = ("crossing", "following", "swapping")
DT = 0.2
SAMPLES = 150
#: a member with the paper's noise is drawn this much wider
NOISY_ROOM = 1.5
#: the paper's uncertainty (Sec. IV.A), as paper-triangle3 writes it
_NOISE = {
    "initial_shift": [0.05, 0.05, "0.05 deg"],
    "disturbance": {"fixed": [{"amplitude": 0.01, "frequency": 0.02},
                              {"amplitude": "0.05 deg", "frequency": 0.02, "phase": "90 deg"}],
                    "uniform": [0.01, "0.1 deg"]},
    "noise": {"fixed": [{"amplitude": 0.025, "frequency": 0.03},
                        {"amplitude": 0.025, "frequency": 0.03},
                        {"amplitude": "0.1 deg", "frequency": 0.05, "phase": "90 deg"}],
              "uniform": [0.025, 0.025, "0.1 deg"]},
}


def _graph(rng: np.random.Generator, n: int) -> dict[str, Any]:
    """A random spanning tree rooted at the leader: one or two robots hear the leader,
    every other robot one robot already in the tree (Theorem 2's condition by
    construction), sometimes a second in-neighbour."""
    order = [int(x) + 1 for x in rng.permutation(n)]
    roots = order[:1 + int(rng.random() < 0.3)]
    edges = []
    for k, r in enumerate(order[len(roots):], start=len(roots)):
        parents = rng.choice(order[:k], size=1 + int(k > 1 and rng.random() < 0.25),
                             replace=False)
        edges += [{"from": int(p), "to": r} for p in parents]
    return {"leader": {r: 1.0 for r in roots}, "edges": edges}


def _crossing(rng: np.random.Generator, n: int) -> tuple[dict[str, Any], dict[str, Any]]:
    period = float(rng.uniform(28.0, 44.0))
    amp = rng.uniform(1.4, 2.2, n)
    base = rng.uniform(0.0, math.pi)
    scales, offsets = {}, {}
    for i in range(n):
        phi = base + math.pi * i / n + rng.uniform(-0.12, 0.12)
        psi = math.pi * i / n + rng.uniform(-0.1, 0.1) * math.pi / n
        scales[f"s{i + 1}"] = {"mean": 0.0, "amplitude": float(amp[i]), "period": period,
                               "phase": float(psi)}
        offsets[i + 1] = {"x": float(math.cos(phi)), "y": float(math.sin(phi)),
                          "scale": f"s{i + 1}"}
    speed = float(rng.uniform(0.2, 0.4))
    reference = {"kind": "unicycle", "speed": speed, "turn_radius": 0.0,
                 "start": [0.0, 0.0, 0.0]}
    return reference, {"frame": "leader", "scales": scales, "offsets": offsets}


def _following(rng: np.random.Generator, n: int) -> tuple[dict[str, Any], dict[str, Any]]:
    spacing = float(rng.uniform(0.8, 1.4))
    breathe = float(rng.uniform(0.0, 0.15))
    scales = {"col": {"mean": 1.0, "amplitude": breathe, "period": float(rng.uniform(15, 30)),
                      "phase": float(rng.uniform(0, 2 * math.pi))}}
    offsets = {i + 1: {"x": -spacing * (i + 1), "y": 0.0, "scale": "col"} for i in range(n)}
    speed = float(rng.uniform(0.2, 0.4))
    shape = rng.integers(3)
    if shape == 0:
        reference = {"kind": "unicycle", "speed": speed, "turn_radius": 0.0,
                     "start": [0.0, 0.0, 0.0]}
    elif shape == 1:
        reference = {"kind": "unicycle", "speed": speed,
                     "turn_radius": float(rng.choice([-1, 1]) * rng.uniform(2.5, 6.0)),
                     "start": [0.0, 0.0, 0.0]}
    else:  # a figure eight of period 30 s at about ``speed``
        period = SAMPLES * DT
        xa = speed * period / (2 * math.pi * 2.4)
        reference = {"kind": "lemniscate", "x_amplitude": float(xa),
                     "y_amplitude": float(xa * 1.3), "period": period}
    return reference, {"frame": "leader", "scales": scales, "offsets": offsets}


def _swapping(rng: np.random.Generator, n: int) -> tuple[dict[str, Any], dict[str, Any]]:
    period = float(rng.uniform(24.0, 40.0))
    half = float(rng.uniform(0.8, 1.4))     # each row this far from the centre line
    step = float(rng.uniform(1.4, 2.0))     # robots of a row this far apart
    left, right = (n + 1) // 2, n // 2
    # robot i keeps its place along the leader's heading and swings across to the other
    # row and back (``scale: [keep, swing]``); the right row staggered by half a step, so
    # that two robots swapping pass each other, at different times
    pts = [((k - (left - 1) / 2) * step, half) for k in range(left)]
    pts += [((k - (left - 1) / 2) * step + step / 2, -half) for k in range(right)]
    scales: dict[str, Any] = {"keep": {"mean": 1.0}}
    offsets = {}
    for i, (x, y) in enumerate(pts):
        psi = 2 * math.pi * i / n + rng.uniform(-0.1, 0.1)
        scales[f"s{i + 1}"] = {"mean": 0.0, "amplitude": 1.0, "period": period,
                               "phase": float(psi + math.pi / 2)}
        offsets[i + 1] = {"x": float(x), "y": float(y), "scale": ["keep", f"s{i + 1}"]}
    speed = float(rng.uniform(0.25, 0.4))
    reference = {"kind": "unicycle", "speed": speed,
                 "turn_radius": float(rng.choice([-1, 1]) * rng.uniform(3.0, 6.0)),
                 "start": [0.0, 0.0, 0.0]}
    return reference, {"frame": "leader", "scales": scales, "offsets": offsets}


_DRAW = {"crossing": _crossing, "following": _following, "swapping": _swapping}


def scenario_data(kind: str, seed: int, *, robots: int | None = None, noise: bool = False,
                  delay: bool = True, trials: int = 100) -> dict[str, Any]:
    """One drawn scenario of family ``kind`` as scenario-file data (not yet checked
    against a base: ``family_scenario`` does that)."""
    if kind not in KINDS:
        raise ValueError(f"family kind must be one of {', '.join(KINDS)}, got {kind!r}")
    rng = np.random.default_rng([KINDS.index(kind), seed])
    n = int(robots if robots is not None else rng.integers(4, 7))
    reference, formation = _DRAW[kind](rng, n)
    if noise:
        # poses off by up to 7 cm and jittering: the filter keeps more room (twice the
        # error between two robots, and the speeds it estimates from the poses), so a
        # noisy member is drawn half as wide again
        for off in formation["offsets"].values():
            off["x"] *= NOISY_ROOM
            off["y"] *= NOISY_ROOM
    data: dict[str, Any] = {
        "name": f"{kind}-{seed}",
        "description": f"family '{kind}', seed {seed}: {n} robots (formation_ilc.studies.families)",
        "dt": DT, "samples": SAMPLES, "trials": trials, "seed": int(seed), "robots": n,
        "desired": {"ramp": 5.0},
        "reference": reference,
        "formation": formation,
        "graph": _graph(rng, n),
        "law": {"kind": 9, "memory": "feedforward", "gain": 0.3, "gain_prime": 0.6,
                "gain_heading": "measured"},
        "delay": {"model": "paper" if delay else "none", "leader_link": bool(delay)},
    }
    if noise:
        data["uncertainty"] = _NOISE
    return data


def fits(sc: Scenario, body: str = "p3dx") -> bool:
    """Whether ``sc`` passes what ``check --base body`` asks of a team on bodies: every
    robot's desired motion inside the base's limits, its bodies kept apart by the filter's
    distance along the desired motion, and that motion let through the filter unchanged
    (for poses as noisy as the scenario's)."""
    from formation_ilc.model.safety import motion_fit

    return motion_fit(sc, body, sc.uncertainty).fits


def draw(kind: str, seed: int, *, name: str | None = None, **options: Any) -> Scenario:
    """The scenario of ``scenario_data(kind, seed, **options)``, named ``name`` (default
    ``KIND-SEED``), whether it fits a base or not. Its text is its data as YAML: it can be
    stretched in time (a time scale reads the text again) and written out as a file."""
    data = scenario_data(kind, seed, **options)
    data["name"] = name or f"{kind}-{seed}"
    return scenario_from_data(data, yaml.safe_dump(data, sort_keys=False),
                              f"<family {kind} {seed}>")


def family_scenario(kind: str, seed: int, *, robots: int | None = None, noise: bool = False,
                    delay: bool = True, trials: int = 100, body: str = "p3dx",
                    tries: int = 50) -> Scenario:
    """The scenario of family ``kind`` for ``seed`` that fits ``body`` robots (``fits``):
    the first of draws seed, seed + 10^6, seed + 2 10^6, ... that fits. ValueError when
    none of ``tries`` draws fits."""
    for k in range(tries):
        sc = draw(kind, seed + k * 1_000_000, robots=robots, noise=noise, delay=delay,
                  trials=trials, name=f"{kind}-{seed}")
        if fits(sc, body):
            return sc
    raise ValueError(f"no draw of family {kind} seed {seed} fits {body} robots in {tries} tries")


def family(kind: str, seeds: range | list[int], **options: Any) -> Iterator[Scenario]:
    """``family_scenario(kind, seed, **options)`` for each seed."""
    for seed in seeds:
        yield family_scenario(kind, seed, **options)
