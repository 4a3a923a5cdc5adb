"""A search for the family member the safety filter slows most (docs/safety.md, "Judged on
families").

The figure searched is the learning's error through the filter over its error without it,
at one fixed trial (``ratio``): cold starts in the batch simulator (exact-arc model, the
member's noise and delays), through the P3-DX's filter (``model.safety.body_spec``, the
robots' motion estimated from their poses or told as commands) and without it.

Two stages, every draw from one seed (the same seed, the same members and the same
answer):

1. random: members of the families (``studies.families``: kind, seed, with or without the
   paper's noise) drawn at random, each the one that fits a P3-DX team;
2. local: from the worst few, a (1+1) evolution strategy over the generator's continuous
   parameters (``perturb``: the leader's speed, the formation's spacing, its periods and
   each robot's phase); a step whose member no longer fits (``families.fits``) is refused,
   a step that raises the ratio is kept, and the step size follows the one-fifth rule.

Pure numpy and the config and model layers: no ROS.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from formation_ilc.config.scenario import Scenario
from formation_ilc.model.safety import body_spec
from formation_ilc.model.simulate import simulate
from formation_ilc.studies.families import KINDS, family_data, fits, scenario_of

__all__ = ["Member", "perturb", "ratio", "search", "LOG_BOUND"]

#: the factors on speed, spacing and period stay within exp(+-LOG_BOUND) of the drawn ones
LOG_BOUND = 0.35
#: the first steps' sizes: on a log factor, and on a phase [rad]
STEP_LOG, STEP_PHASE = 0.08, 0.4


@dataclass
class Member:
    """One member judged: its family, seed and noise, the perturbation ``x`` of its drawn
    parameters (``perturb``), its data, and its errors at the judged trial through the
    filter (``safe``) and without it (``free``)."""

    kind: str
    seed: int
    noise: bool
    x: tuple[float, ...]
    data: dict[str, Any] = field(repr=False)
    safe: float
    free: float

    @property
    def ratio(self) -> float:
        return self.safe / self.free if self.free > 0 else math.inf

    @property
    def name(self) -> str:
        moved = "" if not any(self.x) else " (perturbed)"
        return f"{self.kind}-{self.seed}{' noisy' if self.noise else ''}{moved}"


def _robot_scales(data: dict[str, Any]) -> list[list[str]]:
    """For each robot, the names of the scales it alone uses (a scale two robots share
    keeps its phase)."""
    offsets = data["formation"]["offsets"]
    used: dict[str, int] = {}
    names = []
    for i in sorted(offsets):
        s = offsets[i].get("scale")
        own = [] if s is None else (s if isinstance(s, list) else [s])
        names.append(own)
        for name in own:
            used[name] = used.get(name, 0) + 1
    return [[nm for nm in own if used[nm] == 1] for own in names]


def perturb(data: dict[str, Any], x: Sequence[float]) -> dict[str, Any]:
    """A copy of member ``data`` with its continuous parameters moved by ``x``: the
    leader's speed (a lemniscate's amplitudes) by a factor exp(x[0]), the formation's
    spacing (every offset) by exp(x[1]), every scale's period by exp(x[2]), and robot i's
    own scales' phases by x[3 + i] [rad]. ``x`` of zeros gives the data unchanged."""
    out = copy.deepcopy(data)
    ref = out["reference"]
    if "speed" in ref:
        ref["speed"] = float(ref["speed"] * math.exp(x[0]))
    else:
        for key in ("x_amplitude", "y_amplitude"):
            ref[key] = float(ref[key] * math.exp(x[0]))
    for off in out["formation"]["offsets"].values():
        off["x"] = float(off["x"] * math.exp(x[1]))
        off["y"] = float(off["y"] * math.exp(x[1]))
    scales = out["formation"]["scales"]
    for sc in scales.values():
        if sc.get("period", 0.0) > 0:
            sc["period"] = float(sc["period"] * math.exp(x[2]))
    for i, own in enumerate(_robot_scales(out)):
        for name in own:
            scales[name]["phase"] = float(scales[name].get("phase", 0.0) + x[3 + i])
    return out


def ratio(sc: Scenario, trial: int, motion: str = "poses") -> tuple[float, float]:
    """``sc``'s error at trial ``trial`` (0-based) from a cold start, through the P3-DX's
    filter with ``motion`` and without it: (filtered, free) [m]."""
    spec = body_spec("p3dx", sc.dt, sc.uncertainty, motion=motion)
    safe = simulate(sc, trial + 1, plant="arc", safety=spec).column("max_position_error")
    free = simulate(sc, trial + 1, plant="arc").column("max_position_error")
    return float(safe[trial]), float(free[trial])


def _judge(kind: str, seed: int, noise: bool, x: tuple[float, ...], data: dict[str, Any],
           sc: Scenario, trial: int, motion: str) -> Member:
    safe, free = ratio(sc, trial, motion)
    return Member(kind, seed, noise, x, data, safe, free)


def search(*, seed: int = 0, trial: int = 30, motion: str = "poses",
           kinds: Sequence[str] = KINDS, random_budget: int = 40, local_budget: int = 60,
           starts: int = 3, noise_share: float = 0.5,
           progress: Callable[[str], None] | None = None) -> list[Member]:
    """The members judged, worst (largest ``ratio``) first: ``random_budget`` random
    members, then ``local_budget`` steps of the local search shared by the ``starts``
    worst of them (a refused step, one that does not fit, counts). Deterministic for
    ``seed``."""
    say = progress or (lambda line: None)
    rng = np.random.default_rng([52, seed])
    judged: list[Member] = []
    for k in range(random_budget):
        kind = str(kinds[int(rng.integers(len(kinds)))])
        mseed = int(rng.integers(0, 1_000_000))
        noise = bool(rng.random() < noise_share)
        try:
            data, sc = family_data(kind, mseed, noise=noise, trials=trial + 1)
        except ValueError:
            say(f"random {k + 1}/{random_budget}: {kind}-{mseed}: no draw fits")
            continue
        m = _judge(kind, mseed, noise, (0.0,) * (3 + sc.n), data, sc, trial, motion)
        judged.append(m)
        say(f"random {k + 1}/{random_budget}: {m.name:<24} {m.safe:7.3f} / {m.free:7.3f} m"
            f"  ratio {m.ratio:6.2f}")
    judged.sort(key=lambda m: -m.ratio)
    tops = judged[:starts]
    for j, start in enumerate(tops):
        budget = local_budget // len(tops) + (j < local_budget % len(tops))
        base = family_data(start.kind, start.seed, noise=start.noise, trials=trial + 1)[0]
        best = start
        x = np.zeros(len(start.x))
        sigma = 1.0
        scale = np.array([STEP_LOG] * 3 + [STEP_PHASE] * (len(x) - 3))
        for k in range(budget):
            step = x + sigma * scale * rng.standard_normal(len(x))
            step[:3] = np.clip(step[:3], -LOG_BOUND, LOG_BOUND)
            trial_x = tuple(float(v) for v in step)
            data = perturb(base, trial_x)
            data["name"] = f"{start.kind}-{start.seed}-worst"
            sc = scenario_of(data, "<search>")
            if not fits(sc):
                sigma *= math.exp(-0.25)
                say(f"local {start.name} {k + 1}/{budget}: does not fit (step {sigma:.2f})")
                continue
            m = _judge(start.kind, start.seed, start.noise, trial_x, data, sc, trial, motion)
            judged.append(m)
            if m.ratio > best.ratio:
                best, x = m, step
                sigma = min(4.0, sigma * math.exp(1.0))
            else:
                sigma *= math.exp(-0.25)
            say(f"local {start.name} {k + 1}/{budget}: {m.safe:7.3f} / {m.free:7.3f} m "
                f"ratio {m.ratio:6.2f} (best {best.ratio:.2f}, step {sigma:.2f})")
    judged.sort(key=lambda m: -m.ratio)
    return judged
