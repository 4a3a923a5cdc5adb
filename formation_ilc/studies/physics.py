"""The learning law against the physics plant, in one process: studies and sim-to-real.

``run_physics`` runs a team's trials in lockstep against ``model.physics.PhysicsWorld``:
each sample, every robot's command from the law (``law.command`` for all robots at once,
links without delay, as ``simulate --no-delay``) is held for the sample while the engine
steps; after the trial, ``law.learn`` gives the next memory. It is what the physics node
and the robot nodes do over ROS, without the processes: the sim-to-real study of
docs/reproduction.md and the physics benchmark use it.

The plant stream of the scenario is drawn as the kinematic simulator draws it: the initial
shift places the robots and the output noise is added to the measured pose; the input
disturbance is not applied (the engine's own dynamics are the plant's disturbance).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario
from formation_ilc.core.estimate import BOX
from formation_ilc.core.law import command, learn
from formation_ilc.core.metrics import METRIC_COLUMNS
from formation_ilc.core.safety import CHANGED, OTHER_FIELDS, SafetySpec, filter_team
from formation_ilc.core.through import after_learning, learn_base, learning_code
from formation_ilc.model.footprint import Clearance, trial_clearance
from formation_ilc.model.physics import DEFAULT_RATE, POSE_SOURCES, PhysicsWorld, RobotModel
from formation_ilc.model.simulate import Problem, trial_errors

__all__ = ["POSE_SOURCES", "PhysicsResult", "run_physics"]


@dataclass
class PhysicsResult:
    """metrics : (K, len(METRIC_COLUMNS)), measured columns from the pose source, true_
    columns from the engine. contacts : per trial, seconds in contact per pair.
    clearance : per trial, the least footprint clearance of the true poses. tilt : per
    trial, the largest tilt of any robot [rad]. memory : after the last trial.
    seconds : wall time in the engine loop; samples : samples stepped.
    filtered : per trial, the commands the safety filter changed; limited : per trial,
    the commands the robots' own limits changed (after the filter); box_missed: below."""

    metrics: NDArray[np.float64]
    contacts: list[dict[str, float]] = field(default_factory=list)
    clearance: list[Clearance] = field(default_factory=list)
    tilt: list[float] = field(default_factory=list)
    memory: NDArray[np.float64] | None = None
    seconds: float = 0.0
    samples: int = 0
    xi: dict[int, NDArray[np.float64]] = field(default_factory=dict)
    filtered: list[int] = field(default_factory=list)
    limited: list[int] = field(default_factory=list)
    #: per trial, the poses that missed their box (``core.estimate``: a robot that did not
    #: move as it told, by more than the filter's bounds)
    box_missed: list[int] = field(default_factory=list)

    def column(self, name: str) -> NDArray[np.float64]:
        return self.metrics[:, METRIC_COLUMNS.index(name)]


def run_physics(sc: Scenario, model: RobotModel, trials: int, *,
                memory: NDArray[np.float64] | None = None, pose: str = "truth",
                rate: float = DEFAULT_RATE, collide: bool = True, first_trial: int = 0,
                keep: tuple[int, ...] = (),
                progress: Callable[[int, NDArray[np.float64]], None] | None = None,
                safety: SafetySpec | None = None) -> PhysicsResult:
    """``trials`` trials of ``sc`` on ``model`` robots from ``memory`` (N, T, 2) (default
    u_0 = 0). ``sc``'s 'auto' headings read as 'arc' (a physics robot drives arcs).
    keep : trials whose true trajectories (N, T+1, 3) are returned in ``xi``.
    safety : the filter between each robot's learned command and its body (``core.safety``,
    each robot hearing every other robot's measured pose of the sample), learned through
    as the batch simulator does (``simulate(safety=...)``)."""
    if pose not in POSE_SOURCES:
        raise ValueError(f"pose must be one of {', '.join(POSE_SOURCES)}, got {pose!r}")
    sc = sc.for_plant("physics")
    pb = Problem.from_scenario(sc, "arc")
    n, n_t, n_l = pb.n, pb.samples, pb.src.shape[1]
    mem = np.zeros((n, n_t, 2)) if memory is None else np.array(memory, dtype=float)
    if mem.shape != (n, n_t, 2):
        raise ValueError(f"memory must have shape {(n, n_t, 2)}, got {mem.shape}")
    nxt = np.empty_like(mem)
    xi = np.empty((n, n_t + 1, 3))
    eta = np.empty_like(xi)
    u = np.empty((n, n_t, 2))
    nb_eta = np.zeros((n, n_l, 3))
    nb_s = np.full((n, n_l), -1, dtype=np.int64)
    lead_s = np.zeros(n, dtype=np.int64)
    nb_full = np.zeros((n, n_l, n_t + 1, 3))
    valid = pb.src >= 0
    src = np.where(valid, pb.src, 0)
    res = PhysicsResult(metrics=np.empty((trials, len(METRIC_COLUMNS))))
    row = np.empty(6)
    sf: tuple[Any, ...] = ()
    if safety is not None:
        params, mode = safety.params(), learning_code(safety.learning)
        nominal = np.zeros((n, n_t, 2))
        flags = np.zeros((n, n_t), dtype=np.int64)
        prev = np.zeros((n, 2))
        others, ages, boxes = np.zeros((n, OTHER_FIELDS)), np.zeros(n), np.zeros((n, BOX))
        base = np.zeros((n, n_t, 2))
        sf = (params, nominal, flags, prev, others, ages, boxes)
    with PhysicsWorld(model, n, pb.dt, rate=rate, collide=collide) as world:
        for i in range(trials):
            k = first_trial + i
            shift, _, noise = sc.uncertainty.draw_plant(sc.seed, k, n, n_t)
            world.place(pb.eta_d[:, 0] + shift)
            t0 = time.perf_counter()
            tilt, missed = _drive_trial(world, pb, mem, noise, pose, (xi, eta, u),
                                        (nb_eta, nb_s, lead_s, valid, src), safety, sf)
            res.seconds += time.perf_counter() - t0
            res.samples += n_t
            nb_full[:] = eta[src]
            start = mem
            if safety is not None:
                learn_base.jit(mode, mem, nominal, u, flags, base)
                start = base
            learn.jit(pb.law, pb.memory, start, u, eta, pb.eta_d, nb_full, pb.src, pb.weight,
                      pb.eta_d, pb.leader, pb.gain, pb.heading, nxt)
            if safety is not None:
                after_learning.jit(mode, pb.dt, mem, flags, nxt)
            mem, nxt = nxt, mem
            trial_errors.jit(eta, xi, pb.eta_d, pb.src, pb.weight, row)
            changed = int(np.count_nonzero(flags & CHANGED)) if safety is not None else 0
            _note_trial(res, i, k, world, model, xi, row, changed, tilt, missed)
            if k in keep:
                res.xi[k] = xi.copy()
            if progress is not None:
                progress(k, res.metrics[i].copy())
    res.memory = mem
    return res


def _drive_trial(world: PhysicsWorld, pb: Problem, mem: NDArray[np.float64],
                 noise: NDArray[np.float64], pose: str, out: tuple[NDArray[np.float64], ...],
                 links: tuple[NDArray[Any], ...], safety: SafetySpec | None,
                 sf: tuple[Any, ...]) -> tuple[float, int]:
    """One trial driven in ``world``: the true and measured poses and the commands into
    ``out`` (xi, eta, u), the law's command through the filter (``sf``: its arrays) at each
    sample; returns the largest tilt and how many poses missed their box."""
    xi, eta, u = out
    nb_eta, nb_s, lead_s, valid, src = links
    n_t = pb.samples
    if safety is not None:
        params, nominal, flags, prev, others, ages, boxes = sf
    tilt = 0.0
    missed = 0
    if safety is not None:
        prev[:] = 0.0
    for t in range(n_t + 1):
        xi[:, t] = world.truth()
        measured = xi[:, t] if pose == "truth" else world.odom
        eta[:, t] = measured + noise[:, t]
        if t == n_t:
            break
        nb_eta[:] = eta[src, t]
        nb_s[:] = np.where(valid, t, -1)
        lead_s[:] = t
        command.jit(t, pb.law, mem[:, t], eta, pb.eta_d, nb_eta, nb_s, pb.src,
                    pb.weight, pb.eta_d, lead_s, pb.leader, pb.gain_prime, pb.heading,
                    u[:, t])
        if safety is not None:
            missed += filter_team.jit(t, u, eta, prev, 0.0, params, safety.window,
                                      nominal, flags, others, ages, boxes)
        world.step(u[:, t])
        tilt = max(tilt, float(world.tilt().max()))
    return tilt, missed


def _note_trial(res: PhysicsResult, i: int, k: int, world: PhysicsWorld, model: RobotModel,
                xi: NDArray[np.float64], row: NDArray[np.float64], changed: int, tilt: float,
                missed: int) -> None:
    """Trial ``k``'s (the i-th run) metrics row and what else it leaves in ``res``."""
    contacts = world.contacts()
    res.metrics[i, 0] = k
    res.metrics[i, 1:7] = row
    res.metrics[i, 7] = changed
    res.metrics[i, 8] = len(contacts)
    res.filtered.append(int(res.metrics[i, 7]))
    res.limited.append(world.limited)
    res.box_missed.append(missed)
    res.contacts.append(contacts)
    res.clearance.append(trial_clearance(k, xi, model.footprint))
    res.tilt.append(tilt)
