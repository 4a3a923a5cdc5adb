"""The distributed learning law: eq. (9)/(13) and the comparison laws (22) and (23).

This module is the only implementation of the law. The batch simulator calls it for all
robots at once; the robot node calls it for one robot (R = 1). Both functions take a batch
of R robots and are compiled by numba; ``command.py_func`` / ``learn.py_func`` are the
same code run by the Python interpreter.

Terms, for robot i, trial k+1, sample t (paper notation):

* predictive term, learned between trials from trial k (whole trajectories, no delay):
  P_i(t+1) = sum_j a_ij e_ij,k(t+1) + a_i0 e_i,k(t+1)
* current term, applied during trial k+1 from delayed data (eq. 10: zero for index <= 0):
  law 9:  C_i(t) = sum_j a_ij e_ij(t - tau_ij) + a_i0 e_i(t - tau_i0)
          (own output and neighbour output paired at the same, delayed, sample)
  law 23: C_i(t) = sum_j a_ij [d_ij(t) - (eta_i(t) - eta_j(t - tau_ij))]
          + a_i0 [eta_i^d(t - tau_i0) - eta_i(t)]   (the delay is ignored)
  law 22: C_i(t) = 0
* gains Gamma = g [[cos th, sin th, 0], [0, 0, 1]] (the paper's), Gamma' likewise with g'.

Memory (paper-notes 12):

* ``feedforward`` (default): the memory holds the feed-forward m_{k+1} = m_k + Gamma P; the
  current term is feedback on top of it, u_{k+1} = m_{k+1} + Gamma' C.
* ``literal``: the memory holds the applied input, u_{k+1} = u_k + Gamma P + Gamma' C, so
  every trial's current term is carried into all later trials.

Heading errors are wrapped to (-pi, pi] (paper-notes 4).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from formation_ilc.core._jit import njit
from formation_ilc.core.kinematics import wrap_angle

__all__ = [
    "LAWS",
    "MEMORY_MODES",
    "HEADING_SOURCES",
    "law_code",
    "memory_code",
    "heading_code",
    "command",
    "learn",
    "command_trig",
    "learn_trig",
    "heading_trig",
    "link_error",
]

LAWS = (9, 22, 23)
MEMORY_MODES = ("feedforward", "literal")
HEADING_SOURCES = ("measured", "desired")
FEEDFORWARD, LITERAL = 0, 1
MEASURED, DESIRED = 0, 1


def law_code(law: int | str) -> int:
    value = int(law)
    if value not in LAWS:
        raise ValueError(f"law must be one of {LAWS}, got {law!r}")
    return value


def memory_code(memory: str) -> int:
    if memory not in MEMORY_MODES:
        raise ValueError(f"memory must be one of {MEMORY_MODES}, got {memory!r}")
    return MEMORY_MODES.index(memory)


def heading_code(source: str) -> int:
    if source not in HEADING_SOURCES:
        raise ValueError(f"gain heading must be one of {HEADING_SOURCES}, got {source!r}")
    return HEADING_SOURCES.index(source)


@njit(cache=True)
def link_error(des_own: NDArray[np.float64], des_src: NDArray[np.float64],
               own: NDArray[np.float64], src: NDArray[np.float64], c: int) -> float:
    """Component c of e_ij = (eta_i^d - eta_j^d) - (eta_i - eta_j); heading wrapped."""
    e = (des_own[c] - des_src[c]) - (own[c] - src[c])
    if c == 2:
        e = wrap_angle(e)
    return e


@njit(cache=True)
def heading_trig(heading_source: int, eta_own: NDArray[np.float64],
                 eta_d_own: NDArray[np.float64], t0: int, t1: int, out: NDArray[np.float64],
                 first: int) -> None:
    """cos and sin of the heading in the gains (th of Gamma, Gamma') at samples t0..t1-1:
    out[r, t - first] = (cos th, sin th), th = eta_own[r, t, 2] (measured) or
    eta_d_own[r, t, 2].

    The batch simulator computes them once per sample (first = 0) for ``command_trig`` and
    keeps them for ``learn_trig`` (the same th at the same t): one cos/sin pair fewer per
    robot and sample.
    """
    for r in range(eta_own.shape[0]):
        for t in range(t0, t1):
            th = eta_own[r, t, 2] if heading_source == MEASURED else eta_d_own[r, t, 2]
            out[r, t - first, 0] = np.cos(th)
            out[r, t - first, 1] = np.sin(th)


@njit(cache=True)
def command(
    t: int,
    law: int,
    memory_t: NDArray[np.float64],
    eta_own: NDArray[np.float64],
    eta_d_own: NDArray[np.float64],
    nb_eta: NDArray[np.float64],
    nb_sample: NDArray[np.int64],
    nb_src: NDArray[np.int64],
    nb_weight: NDArray[np.float64],
    eta_d_all: NDArray[np.float64],
    lead_sample: NDArray[np.int64],
    lead_weight: NDArray[np.float64],
    gain_prime: NDArray[np.float64],
    heading_source: int,
    out: NDArray[np.float64],
) -> None:
    """Input u(t) of R robots at sample t of the current trial, written into ``out``.

    t : sample index, 0 <= t < T.
    law : 9, 22 or 23.
    memory_t : shape (R, 2), the memory at t (feed-forward, or last applied input).
    eta_own : shape (R, T+1, 3), each robot's own measured outputs; samples <= t are used.
    eta_d_own : shape (R, T+1, 3), each robot's desired outputs.
    nb_eta : shape (R, L, 3), neighbour outputs as received at t (labelled nb_sample).
    nb_sample : shape (R, L), sample label s = t - tau of each received output; s < 1
        means nothing usable (eq. 10).
    nb_src : shape (R, L), neighbour robot index into eta_d_all, -1 for padding.
    nb_weight : shape (R, L), a_ij.
    eta_d_all : shape (N, T+1, 3), desired outputs of all robots.
    lead_sample : shape (R,), sample label of the reference as received (t - tau_i0).
    lead_weight : shape (R,), a_i0.
    gain_prime : shape (R,), scalar g' of Gamma'.
    heading_source : 0 measured heading eta_i(t) in Gamma', 1 desired heading.
    out : shape (R, 2) [m/s, rad/s].
    """
    trig = np.empty((memory_t.shape[0], 1, 2))
    heading_trig(heading_source, eta_own, eta_d_own, t, t + 1, trig, t)
    command_trig(t, 0, law, memory_t[:, None, :], eta_own, eta_d_own, nb_eta, nb_sample,
                 nb_src, nb_weight, eta_d_all, lead_sample, lead_weight, gain_prime, trig,
                 out[:, None, :])


@njit(cache=True)
def command_trig(
    t: int,
    k: int,
    law: int,
    memory: NDArray[np.float64],
    eta_own: NDArray[np.float64],
    eta_d_own: NDArray[np.float64],
    nb_eta: NDArray[np.float64],
    nb_sample: NDArray[np.int64],
    nb_src: NDArray[np.int64],
    nb_weight: NDArray[np.float64],
    eta_d_all: NDArray[np.float64],
    lead_sample: NDArray[np.int64],
    lead_weight: NDArray[np.float64],
    gain_prime: NDArray[np.float64],
    trig: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """``command`` with the gain heading's cos and sin given, every per-sample array read
    or written at column k: memory[:, k] is ``command``'s memory_t, trig[:, k] the cos and
    sin of the heading at t (``heading_trig``), out[:, k] its out. The simulator passes its
    whole arrays and k = t (no views per sample). Arguments otherwise as ``command``."""
    n_links = nb_src.shape[1]
    for r in range(memory.shape[0]):
        out[r, k, 0] = memory[r, k, 0]
        out[r, k, 1] = memory[r, k, 1]
        if law == 22:
            continue
        # three scalars, not an array: no allocation per robot and sample
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for ell in range(n_links):
            j = nb_src[r, ell]
            s = nb_sample[r, ell]
            w = nb_weight[r, ell]
            if j < 0 or w == 0.0 or s < 1:
                continue
            own_at = s if law == 9 else t
            a0 += w * link_error(eta_d_own[r, own_at], eta_d_all[j, own_at],
                                 eta_own[r, own_at], nb_eta[r, ell], 0)
            a1 += w * link_error(eta_d_own[r, own_at], eta_d_all[j, own_at],
                                 eta_own[r, own_at], nb_eta[r, ell], 1)
            a2 += w * link_error(eta_d_own[r, own_at], eta_d_all[j, own_at],
                                 eta_own[r, own_at], nb_eta[r, ell], 2)
        s0 = lead_sample[r]
        w0 = lead_weight[r]
        if w0 != 0.0 and s0 >= 1:
            own_at = s0 if law == 9 else t
            a0 += w0 * (eta_d_own[r, s0, 0] - eta_own[r, own_at, 0])
            a1 += w0 * (eta_d_own[r, s0, 1] - eta_own[r, own_at, 1])
            a2 += w0 * wrap_angle(eta_d_own[r, s0, 2] - eta_own[r, own_at, 2])
        # out += g' [[cos th, sin th, 0], [0, 0, 1]] (a0, a1, a2)
        out[r, k, 0] += gain_prime[r] * (trig[r, k, 0] * a0 + trig[r, k, 1] * a1)
        out[r, k, 1] += gain_prime[r] * a2


@njit(cache=True)
def learn(
    law: int,
    memory_mode: int,
    memory: NDArray[np.float64],
    applied: NDArray[np.float64],
    eta_own: NDArray[np.float64],
    eta_d_own: NDArray[np.float64],
    nb_eta: NDArray[np.float64],
    nb_src: NDArray[np.int64],
    nb_weight: NDArray[np.float64],
    eta_d_all: NDArray[np.float64],
    lead_weight: NDArray[np.float64],
    gain: NDArray[np.float64],
    heading_source: int,
    out: NDArray[np.float64],
) -> None:
    """Memory for the next trial from the whole trial just run, written into ``out``.

    memory : shape (R, T, 2), the memory used in this trial.
    applied : shape (R, T, 2), the inputs applied in this trial.
    eta_own : shape (R, T+1, 3), own measured outputs of this trial.
    nb_eta : shape (R, L, T+1, 3), neighbours' measured outputs of this trial
        (their whole trajectories, paper-notes 9).
    gain : shape (R,), scalar g of Gamma.
    out : shape (R, T, 2); may be ``memory`` itself.
    Other arguments as in ``command``.
    """
    n_t = memory.shape[1]
    trig = np.empty((memory.shape[0], n_t, 2))
    heading_trig(heading_source, eta_own, eta_d_own, 0, n_t, trig, 0)
    learn_trig(law, memory_mode, memory, applied, eta_own, eta_d_own, nb_eta, nb_src, nb_weight,
               eta_d_all, lead_weight, gain, trig, out)


@njit(cache=True)
def learn_trig(
    law: int,
    memory_mode: int,
    memory: NDArray[np.float64],
    applied: NDArray[np.float64],
    eta_own: NDArray[np.float64],
    eta_d_own: NDArray[np.float64],
    nb_eta: NDArray[np.float64],
    nb_src: NDArray[np.int64],
    nb_weight: NDArray[np.float64],
    eta_d_all: NDArray[np.float64],
    lead_weight: NDArray[np.float64],
    gain: NDArray[np.float64],
    trig: NDArray[np.float64],
    out: NDArray[np.float64],
) -> None:
    """``learn`` with the gain heading's cos and sin given: trig, shape (R, >= T, 2), as
    ``heading_trig`` computes them. Arguments otherwise as ``learn``."""
    n_t = memory.shape[1]
    n_links = nb_src.shape[1]
    for r in range(memory.shape[0]):
        for t in range(n_t):
            p0 = 0.0
            p1 = 0.0
            p2 = 0.0
            for ell in range(n_links):
                j = nb_src[r, ell]
                w = nb_weight[r, ell]
                if j < 0 or w == 0.0:
                    continue
                p0 += w * link_error(eta_d_own[r, t + 1], eta_d_all[j, t + 1],
                                     eta_own[r, t + 1], nb_eta[r, ell, t + 1], 0)
                p1 += w * link_error(eta_d_own[r, t + 1], eta_d_all[j, t + 1],
                                     eta_own[r, t + 1], nb_eta[r, ell, t + 1], 1)
                p2 += w * link_error(eta_d_own[r, t + 1], eta_d_all[j, t + 1],
                                     eta_own[r, t + 1], nb_eta[r, ell, t + 1], 2)
            w0 = lead_weight[r]
            if w0 != 0.0:
                p0 += w0 * (eta_d_own[r, t + 1, 0] - eta_own[r, t + 1, 0])
                p1 += w0 * (eta_d_own[r, t + 1, 1] - eta_own[r, t + 1, 1])
                p2 += w0 * wrap_angle(eta_d_own[r, t + 1, 2] - eta_own[r, t + 1, 2])
            if memory_mode == LITERAL and law != 22:
                b0 = applied[r, t, 0]
                b1 = applied[r, t, 1]
            else:
                b0 = memory[r, t, 0]
                b1 = memory[r, t, 1]
            g = gain[r]
            out[r, t, 0] = b0 + g * (trig[r, t, 0] * p0 + trig[r, t, 1] * p1)
            out[r, t, 1] = b1 + g * p2
