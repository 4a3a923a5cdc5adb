"""What the formation should be, sample by sample: the quantities the live view and the
recording show besides the measured poses. Free of ROS; ``msgs_schema`` makes them messages
and ``formation_ilc.nodes.observer`` publishes them.

Per robot i and sample s: the desired pose eta_d[i, s] (known before the run), the position
tracking error |p_d - p| [m] and the heading error wrap(theta_d - theta) [rad] of the
measured pose (the quantities of ``formation_ilc.model.simulate.trial_errors``, per sample,
computed the same way); per robot and trial their largest magnitudes over samples 1..T, as
the metrics take them (the largest over robots is the metrics row's). For the 3D view, the
formation's outline (the desired positions joined around their centre) and the graph's
links, at a marker sample. And the run's parameters as a viewer's parameters panel lists
them (``run_parameters``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.runconfig import RunConfig
from formation_ilc.core.names import LEADER_NODE, absolute

__all__ = ["TrackingView", "TrialPeak", "outline_order", "graph_links", "marker_every",
           "run_parameters"]


def run_parameters(cfg: RunConfig, namespace: str, names: Iterable[str] = ()
                   ) -> dict[str, Any]:
    """The parameters that configure the run, named as foxglove_bridge names a node's
    (``/formation/virtual_leader.seed``): the leader's (``RunConfig.to_params``, which the
    leader publishes to every node in the latched configuration). ``names``: only these
    (none: all); a name the run has not is left out."""
    leader = absolute(LEADER_NODE, namespace)
    every = {f"{leader}.{k}": v for k, v in cfg.to_params(cfg.scenario_param).items()}
    wanted = list(names)
    return every if not wanted else {n: every[n] for n in wanted if n in every}


def outline_order(eta_d0: NDArray[np.float64]) -> list[int]:
    """Robot indices in the order that joins their desired positions (N, >=2) into the
    formation's outline: by angle around the centroid (a hexagon's robots in ring order)."""
    p = np.asarray(eta_d0, dtype=float)[:, :2]
    c = p.mean(axis=0)
    ang = np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0])
    return [int(i) for i in np.argsort(ang, kind="stable")]


def graph_links(src: NDArray[np.int64]) -> list[tuple[int, int]]:
    """The graph's robot-to-robot links (sender j, receiver i) of a padded in-link table
    (``Graph.in_links``: -1 pads)."""
    return [(int(j), i) for i in range(src.shape[0]) for j in src[i] if j >= 0]


def marker_every(dt: float, period: float = 0.5) -> int:
    """Markers every this many samples: about every ``period`` seconds of run time (a
    sample's every marker would cost more than it shows)."""
    return max(1, round(period / dt)) if dt > 0 else 1


@dataclass
class TrialPeak:
    """The largest errors of one robot in one slot so far, and the samples seen (a sample
    the plant sent again counts once)."""

    position: float = 0.0
    heading: float = 0.0
    seen: set[int] = field(default_factory=set)


@dataclass
class TrackingView:
    """Tracking errors of measured poses against ``eta_d`` (N, T+1, 3), and the latest
    positions of a marker sample until the whole team's are in."""

    eta_d: NDArray[np.float64]
    every: int = 1
    peaks: dict[tuple[int, int], TrialPeak] = field(default_factory=dict)
    pending: dict[tuple[int, int], dict[int, tuple[float, float]]] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.eta_d.shape[0])

    @property
    def samples(self) -> int:
        return int(self.eta_d.shape[1] - 1)

    def error(self, r: int, s: int, eta: NDArray[np.float64]) -> tuple[float, float]:
        """(position error [m], heading error wrapped to (-pi, pi] [rad]) of robot r's pose
        ``eta`` (x, y, theta) at sample s; ValueError if s is not a sample of a trial."""
        if not 0 <= s <= self.samples or not 0 <= r < self.n:
            raise ValueError(f"robot {r} sample {s} outside the trial")
        d = self.eta_d[r, s]
        ex, ey = float(d[0]) - float(eta[0]), float(d[1]) - float(eta[1])
        pos = math.sqrt(ex * ex + ey * ey)
        h = float(d[2]) - float(eta[2])
        head = h - 2.0 * math.pi * math.ceil((h - math.pi) / (2.0 * math.pi))  # wrap_angle
        return pos, head

    def observe(self, slot: int, r: int, s: int, eta: NDArray[np.float64]
                ) -> tuple[float, float]:
        """The error of one measured pose, counted toward its slot's peaks (sample 0, the
        initial condition, counts as seen but not toward the peaks, as in the metrics)."""
        pos, head = self.error(r, s, eta)
        pk = self.peaks.setdefault((slot, r), TrialPeak())
        if s > 0:
            pk.position = max(pk.position, pos)
            pk.heading = max(pk.heading, abs(head))
        pk.seen.add(s)
        return pos, head

    def trial_peaks(self, slot: int) -> list[TrialPeak] | None:
        """Each robot's peaks of a slot whose every sample of every robot was seen (removed
        from the view), else None (nothing removed)."""
        got = [self.peaks.get((slot, r)) for r in range(self.n)]
        if any(p is None or len(p.seen) < self.samples + 1 for p in got):
            return None
        for r in range(self.n):
            del self.peaks[(slot, r)]
        return [p for p in got if p is not None]

    def whole_trial_peaks(self, eta: NDArray[np.float64]) -> list[TrialPeak]:
        """Each robot's peaks of a whole trial's measured outputs ``eta`` (N, T+1, 3) at
        once, as :meth:`observe` of every sample then :meth:`trial_peaks` give them."""
        d = self.eta_d - np.asarray(eta, dtype=float)
        pos = np.sqrt(d[:, 1:, 0] ** 2 + d[:, 1:, 1] ** 2).max(axis=1)
        h = d[:, 1:, 2]
        head = np.abs(h - 2.0 * np.pi * np.ceil((h - np.pi) / (2.0 * np.pi))).max(axis=1)
        every = set(range(self.samples + 1))
        return [TrialPeak(float(p), float(a), set(every)) for p, a in zip(pos, head, strict=True)]

    def forget(self, slot: int) -> None:
        """Drop what is kept of a slot (aborted, or ended without every sample)."""
        for key in [k for k in self.peaks if k[0] <= slot]:
            del self.peaks[key]
        for key in [k for k in self.pending if k[0] <= slot]:
            del self.pending[key]

    def position(self, slot: int, r: int, s: int, eta: NDArray[np.float64]
                 ) -> dict[int, tuple[float, float]] | None:
        """Robot r's position at a marker sample; every robot's positions (index -> (x, y))
        once the team's are in (then forgotten), else None."""
        if s % self.every and s != self.samples:
            return None
        got = self.pending.setdefault((slot, s), {})
        got[r] = (float(eta[0]), float(eta[1]))
        if len(got) < self.n:
            if len(self.pending) > 64:  # a robot that never reports: keep the newest only
                for key in sorted(self.pending)[:-32]:
                    del self.pending[key]
            return None
        del self.pending[(slot, s)]
        return got
