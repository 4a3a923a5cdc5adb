"""Robot footprints and the clearance between them: will the learning transient crash?

The law knows nothing of the robots' size: early trials (u_0 = 0) leave robots behind and
the correction drives them across each other's paths. In the kinematic model robots pass
through each other; on real robots or in a physics engine that is a crash, and the
contact corrupts the memory learned from it. A run on a plant with bodies is checked
first against the batch simulator's prediction (``predict_clearance``).

A footprint is a rectangle of ``length`` x ``width`` [m] about the tracked point, its
centre ``offset`` [m] ahead of it along the heading (a skid-steer base tracked at its
turning point has its body ahead of or behind that point).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario

__all__ = ["Footprint", "clearance", "Clearance", "predict_clearance", "BODIES",
           "footprint_of"]


@dataclass(frozen=True)
class Footprint:
    """A rectangle length (along the heading) x width [m], its centre ``offset`` [m] ahead
    of the pose that the stack tracks."""

    length: float
    width: float
    offset: float = 0.0

    def discs(self, count: int = 2) -> tuple[tuple[float, ...], float]:
        """``count`` equal discs along the heading that cover the rectangle: their centres'
        offsets ahead of the tracked point [m] and their radius [m] (the safety filter's
        body, ``core.safety``). Two discs cover an elongated body far more tightly than one
        circle: a P3-DX 0.455 x 0.381 m in radius 0.222 m each instead of 0.296 m."""
        if count < 1:
            raise ValueError(f"discs: count >= 1, got {count}")
        piece = self.length / count
        offsets = tuple(self.offset - 0.5 * self.length + (k + 0.5) * piece
                        for k in range(count))
        return offsets, float(np.hypot(0.5 * piece, 0.5 * self.width))

    def corners(self, pose: NDArray[np.float64]) -> NDArray[np.float64]:
        """Corners of the footprint at ``pose`` (..., 3) -> (..., 4, 2), counter-clockwise."""
        p = np.asarray(pose, dtype=float)
        c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
        cx = p[..., 0] + self.offset * c
        cy = p[..., 1] + self.offset * s
        hl, hw = 0.5 * self.length, 0.5 * self.width
        local = np.array([[hl, hw], [-hl, hw], [-hl, -hw], [hl, -hw]])
        x = cx[..., None] + c[..., None] * local[:, 0] - s[..., None] * local[:, 1]
        y = cy[..., None] + s[..., None] * local[:, 0] + c[..., None] * local[:, 1]
        return np.stack([x, y], axis=-1)


#: bodies the clearance is measured for, by name: a Pioneer 3-DX (and the physics model of
#: its size) about its axle, the Husky about its turning point (docs/physics.md), and the
#: bases' presets (``formation_ilc.config.bases``)
BODIES = ("p3dx", "husky", "husky-imu", "turtlebot3", "turtlebot4", "jackal")
_OWN = {"p3dx": Footprint(0.455, 0.381, -0.045), "husky": Footprint(0.99, 0.67, 0.17),
        "husky-imu": Footprint(0.99, 0.67, 0.17)}


def footprint_of(name: str) -> Footprint:
    """The footprint of body ``name`` (one of BODIES); ValueError for another."""
    if name in _OWN:
        return _OWN[name]
    from formation_ilc.config.bases import base_preset

    return Footprint(*base_preset(name).size)


def _axes(corners: NDArray[np.float64]) -> NDArray[np.float64]:
    """The two edge normals of rectangles (..., 4, 2) -> (..., 2, 2), unit length."""
    e = np.stack([corners[..., 1, :] - corners[..., 0, :],
                  corners[..., 2, :] - corners[..., 1, :]], axis=-2)
    return e / np.linalg.norm(e, axis=-1, keepdims=True)


def _gap(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Signed separation of rectangles a, b (..., 4, 2) along their 4 edge normals:
    the largest gap between the projections (> 0: apart along that axis; the minus of the
    smallest overlap otherwise, the penetration depth). Shape (...,)."""
    axes = np.concatenate([_axes(a), _axes(b)], axis=-2)  # (..., 4, 2)
    pa = np.einsum("...kc,...jc->...kj", axes, a)  # (..., 4 axes, 4 corners)
    pb = np.einsum("...kc,...jc->...kj", axes, b)
    gap = np.maximum(pb.min(-1) - pa.max(-1), pa.min(-1) - pb.max(-1))
    return gap.max(-1)


def _point_segment(p: NDArray[np.float64], a: NDArray[np.float64],
                   b: NDArray[np.float64]) -> NDArray[np.float64]:
    ab = b - a
    t = np.clip(np.einsum("...c,...c->...", p - a, ab) /
                np.maximum(np.einsum("...c,...c->...", ab, ab), 1e-300), 0.0, 1.0)
    d = p - (a + t[..., None] * ab)
    return np.sqrt(np.einsum("...c,...c->...", d, d))


def _distance(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Euclidean distance between disjoint convex polygons (..., 4, 2): the least distance
    from a corner of one to an edge of the other."""
    best = np.full(a.shape[:-2], np.inf)
    for p, q in ((a, b), (b, a)):
        for i in range(4):
            for j in range(4):
                d = _point_segment(p[..., i, :], q[..., j, :], q[..., (j + 1) % 4, :])
                best = np.minimum(best, d)
    return best


def clearance(xi: NDArray[np.float64], fp: Footprint) -> NDArray[np.float64]:
    """Clearance [m] between the footprints of every pair of robots at every sample.

    xi : shape (N, T+1, 3), poses of the tracked points. Returns shape (P, T+1) for the
    P = N (N-1) / 2 pairs (i < j, in ``np.triu_indices`` order): the distance between the
    two rectangles when apart, minus the penetration depth (the least overlap along an
    edge normal) when they overlap.
    """
    n = xi.shape[0]
    i, j = np.triu_indices(n, 1)
    c = fp.corners(xi)  # (N, T+1, 4, 2)
    a, b = c[i], c[j]
    gap = _gap(a, b)
    out = gap.copy()
    apart = gap > 0
    if apart.any():
        out[apart] = _distance(a[apart], b[apart])
    return out


@dataclass(frozen=True)
class Clearance:
    """The least clearance of one trial: value [m] (< 0: the footprints overlap by that
    much), which robots (1-based) and when (sample), and how many samples overlap."""

    trial: int
    value: float
    robots: tuple[int, int]
    sample: int
    overlapping: int

    def line(self, dt: float) -> str:
        """One line for a user."""
        i, j = self.robots
        if self.value >= 0:
            return (f"trial {self.trial}: least clearance {self.value:.3f} m (robots {i} and "
                    f"{j} at t = {self.sample * dt:.1f} s)")
        return (f"trial {self.trial}: robots {i} and {j} overlap by {-self.value:.3f} m at "
                f"t = {self.sample * dt:.1f} s ({self.overlapping} samples with an overlap)")


def trial_clearance(trial: int, xi: NDArray[np.float64], fp: Footprint) -> Clearance:
    """The least clearance of one trial's true poses xi (N, T+1, 3)."""
    n = xi.shape[0]
    if n < 2:
        return Clearance(trial, float("inf"), (1, 1), 0, 0)
    c = clearance(xi, fp)
    p, t = np.unravel_index(int(np.argmin(c)), c.shape)
    i, j = np.triu_indices(n, 1)
    return Clearance(trial, float(c[p, t]), (int(i[p]) + 1, int(j[p]) + 1), int(t),
                     int((c.min(axis=0) < 0).sum()))


def predict_clearance(sc: Scenario, fp: Footprint, trials: int,
                      memory: NDArray[np.float64] | None = None, plant: str = "arc",
                      first_trial: int = 0, safety: Any = None,
                      as_run: bool = False) -> list[Clearance]:
    """The batch simulator's prediction of a run: ``trials`` trials from ``memory``
    (default u_0 = 0), through the safety filter ``safety`` (``core.safety.SafetySpec``;
    None: none), and each trial's least clearance. Without noise or delay; with
    ``as_run``, with ``sc``'s own noise and delays and seed: the draws of the run itself,
    trial for trial (the stack draws what the batch simulator draws)."""
    from formation_ilc.model.simulate import simulate

    run = (sc.with_options(trials=trials) if as_run
           else sc.with_options(noise=False, delay=False, trials=trials))
    out: list[Clearance] = []

    def on_data(k: int, xi: NDArray[np.float64], *rest: object) -> None:
        out.append(trial_clearance(k, xi, fp))

    simulate(run, initial_memory=memory, on_trial_data=on_data, plant=plant,
             first_trial=first_trial, store_metrics=False, safety=safety)
    return out


def first_overlap(found: Iterable[Clearance]) -> Clearance | None:
    """The first trial whose footprints overlap, or None."""
    return next((c for c in found if c.value < 0), None)
