"""An independent, per-sample reference of the formation law, for testing the core against.

Written straight from the paper (``/work/shared/reference/paper.md``) and the project's
documented choices (module docstring of ``formation_ilc/core/law.py``, README "Two readings of
the learning memory", ``docs/reproduction.md``, paper-notes 3, 4, 9, 11, 12). It shares no
code with ``formation_ilc`` (no kinematics, law, delay or simulator import): everything is
a plain loop over robots, links and samples, slow and readable on purpose, so that an error
in the core cannot cancel out against the same error here.

Notation (paper): robot i = 0..n-1 here, trial k, sample t = 0..T.

* eq. (1): xi(t+1) = xi(t) + dT [cos th (v + Dv), sin th (v + Dv), w + Dw],
  eta(t) = xi(t) + gamma(t) (output noise).
* link error e_ij(t) = (eta_i^d(t) - eta_j^d(t)) - (eta_i(t) - eta_j(t)) (eq. 7), leader
  error e_i(t) = eta_i^d(t) - eta_i(t) (eq. 6); every heading error wrapped to (-pi, pi]
  (paper-notes 4).
* Gamma_i = g_i [[cos th, sin th, 0], [0, 0, 1]] (Sec. IV.A), Gamma'_i likewise with g'_i.
* predictive term P_i(t+1) = sum_j a_ij e_ij,k(t+1) + a_i0 e_i,k(t+1), from the whole
  previous trial (no delay, paper-notes 9).
* current term (eq. 9/13 with eq. 10: nothing labelled <= 0 is used):
  law 9:  C_i(t) = sum_j a_ij e_ij(t - tau_ij) + a_i0 e_i(t - tau_i0)
  law 23: C_i(t) = sum_j a_ij [d_ij(t) - (eta_i(t) - eta_j(t - tau_ij))]
                   + a_i0 [eta_i^d(t - tau_i0) - eta_i(t)]
  law 22: C_i(t) = 0.
* memory (paper-notes 12): 'feedforward' m_{k+1} = m_k + Gamma P, applied u = m + Gamma' C;
  'literal' u_{k+1} = u_k + Gamma P + Gamma' C (the memory is the applied input).
* eq. (11): tau = floor((Rt - St + 0.5 dT) / dT), never negative.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np
from numpy.typing import NDArray

TWO_PI = 2.0 * math.pi


def wrap(a: float) -> float:
    """Angle wrapped to (-pi, pi] [rad].

    ``math.remainder`` gives a - 2 pi n with n the nearest integer, in [-pi, pi]; the one
    value outside the half-open interval, -pi, is moved to +pi.
    """
    r = math.remainder(float(a), TWO_PI)
    return math.pi if r <= -math.pi else r


def gain_matrix(g: float, theta: float) -> NDArray[np.float64]:
    """Gamma = g [[cos th, sin th, 0], [0, 0, 1]], shape (2, 3) (Sec. IV.A).

    The v-row projects the position error on the heading theta [rad]; the omega-row takes
    the heading error.
    """
    return g * np.array([[math.cos(theta), math.sin(theta), 0.0], [0.0, 0.0, 1.0]])


def error(desired: NDArray[np.float64], actual: NDArray[np.float64]) -> NDArray[np.float64]:
    """desired - actual for one output (x, y, theta), shape (3,); heading wrapped."""
    e = np.array([desired[0] - actual[0], desired[1] - actual[1], desired[2] - actual[2]])
    e[2] = wrap(e[2])
    return e


def link_error(des_i: NDArray[np.float64], des_j: NDArray[np.float64],
               eta_i: NDArray[np.float64], eta_j: NDArray[np.float64]) -> NDArray[np.float64]:
    """e_ij = (eta_i^d - eta_j^d) - (eta_i - eta_j), shape (3,); heading wrapped once.

    The relative desired heading and the relative measured heading are subtracted first
    and only the result is wrapped (wrapping each part would give the same angle mod 2 pi).
    """
    return error(np.asarray(des_i) - np.asarray(des_j), np.asarray(eta_i) - np.asarray(eta_j))


@dataclass(frozen=True)
class Setup:
    """What the law of a whole team needs, in the paper's own terms.

    dt : sample time dT [s].
    adjacency : shape (n, n); a_ij > 0 if robot i receives from robot j.
    leader : shape (n,); a_i0 > 0 if robot i receives the reference.
    gain, gain_prime : shape (n,); g_i of Gamma_i and g'_i of Gamma'_i.
    eta_d : shape (n, T+1, 3) [m, m, rad]; desired outputs eta_i^d(t).
    law : 9, 22 or 23.
    memory : 'feedforward' or 'literal'.
    heading : 'measured' (Gamma and Gamma' take the measured heading Ytheta_i(t)) or
        'desired' (they take theta_i^d(t)).
    """

    dt: float
    adjacency: NDArray[np.float64]
    leader: NDArray[np.float64]
    gain: NDArray[np.float64]
    gain_prime: NDArray[np.float64]
    eta_d: NDArray[np.float64]
    law: int
    memory: str
    heading: str

    @property
    def n(self) -> int:
        return int(self.eta_d.shape[0])

    @property
    def samples(self) -> int:
        return int(self.eta_d.shape[1] - 1)

    def senders(self, i: int) -> list[int]:
        """Robots j with a_ij > 0, i.e. robot i's neighbour set N_i."""
        return [j for j in range(self.n) if self.adjacency[i, j] > 0]

    def gain_heading(self, i: int, t: int, eta_i: NDArray[np.float64]) -> float:
        """The heading in Gamma_i(t), Gamma'_i(t) [rad]; eta_i : shape (T+1, 3)."""
        if self.heading == "measured":
            return float(eta_i[t][2])
        if self.heading == "desired":
            return float(self.eta_d[i, t, 2])
        raise ValueError(f"unknown gain heading {self.heading!r}")


def predictive_term(setup: Setup, i: int, t: int,
                    eta: NDArray[np.float64]) -> NDArray[np.float64]:
    """P_i(t+1) = sum_j a_ij e_ij,k(t+1) + a_i0 e_i,k(t+1), shape (3,).

    eta : shape (n, T+1, 3), every robot's measured outputs of trial k (the neighbours'
    whole trajectories, paper-notes 9).
    """
    d = setup.eta_d
    p = np.zeros(3)
    for j in setup.senders(i):
        p += setup.adjacency[i, j] * link_error(d[i, t + 1], d[j, t + 1], eta[i, t + 1],
                                                eta[j, t + 1])
    if setup.leader[i] > 0:
        p += setup.leader[i] * error(d[i, t + 1], eta[i, t + 1])
    return p


def current_term(setup: Setup, i: int, t: int, own: NDArray[np.float64],
                 received: dict[int, tuple[int, NDArray[np.float64]]],
                 leader_label: int) -> NDArray[np.float64]:
    """C_i(t) of the running trial, shape (3,).

    own : shape (T+1, 3), robot i's own measured outputs; only samples <= t are read.
    received : {j: (s, eta_j(s))}, the output of each neighbour j as it arrived at t,
        labelled s = t - tau_ij(t).
    leader_label : s0 = t - tau_i0(t), the label of the reference as it arrived.
    Eq. (10): a term whose label is <= 0 is zero. The code documents the same gate for
    law (23) (law.py: "eq. 10: zero for index <= 0"), which the paper's (23) does not
    spell out; the reference follows the documented choice.
    """
    c = np.zeros(3)
    if setup.law == 22:
        return c
    d = setup.eta_d
    for j in setup.senders(i):
        if j not in received:
            continue
        s, eta_j = received[j]
        if s < 1:
            continue
        if setup.law == 9:
            # own output and neighbour output paired at the same, delayed, sample
            e = link_error(d[i, s], d[j, s], own[s], eta_j)
        else:
            # law 23: d_ij(t) - (eta_i(t) - eta_j(t - tau)); the delay is ignored
            e = link_error(d[i, t], d[j, t], own[t], eta_j)
        c += setup.adjacency[i, j] * e
    s0 = leader_label
    if setup.leader[i] > 0 and s0 >= 1:
        own_at = s0 if setup.law == 9 else t
        c += setup.leader[i] * error(d[i, s0], own[own_at])
    return c


def command(setup: Setup, i: int, t: int, memory_t: NDArray[np.float64],
            own: NDArray[np.float64], received: dict[int, tuple[int, NDArray[np.float64]]],
            leader_label: int) -> NDArray[np.float64]:
    """u_i(t) = m_i(t) + Gamma'_i(t) C_i(t), shape (2,) [m/s, rad/s].

    memory_t : shape (2,), the memory at t (the feed-forward, or in the literal reading
    the input learned from the last trial). Other arguments as in ``current_term``.
    """
    c = current_term(setup, i, t, own, received, leader_label)
    th = setup.gain_heading(i, t, own)
    return np.asarray(memory_t, dtype=float) + gain_matrix(setup.gain_prime[i], th) @ c


def learn(setup: Setup, i: int, memory: NDArray[np.float64], applied: NDArray[np.float64],
          eta: NDArray[np.float64]) -> NDArray[np.float64]:
    """Robot i's memory for trial k+1, shape (T, 2).

    memory, applied : shape (T, 2), the memory used and the inputs applied in trial k.
    eta : shape (n, T+1, 3), every robot's measured outputs of trial k.
    feedforward: m_{k+1}(t) = m_k(t) + Gamma_i,k(t) P_i(t+1).
    literal:     u_{k+1}(t) = u_k(t) + Gamma_i,k(t) P_i(t+1) (+ Gamma' C in the next trial),
                 where u_k is what was applied. Law 22 applies its memory, so both agree.
    Gamma_i,k(t) takes the heading at t (not t+1) of trial k.
    """
    if setup.memory == "literal":
        base = np.asarray(applied, dtype=float)
    elif setup.memory == "feedforward":
        base = np.asarray(memory, dtype=float)
    else:
        raise ValueError(f"unknown memory reading {setup.memory!r}")
    out = np.empty((setup.samples, 2))
    for t in range(setup.samples):
        th = setup.gain_heading(i, t, eta[i])
        out[t] = base[t] + gain_matrix(setup.gain[i], th) @ predictive_term(setup, i, t, eta)
    return out


def plant_step(xi: NDArray[np.float64], u: NDArray[np.float64], dist: NDArray[np.float64],
               dt: float) -> NDArray[np.float64]:
    """Eq. (1) for one robot: state (x, y, theta) at t+1, shape (3,).

    xi : (3,) [m, m, rad]; u, dist : (2,) [m/s, rad/s], the disturbance adds to the input.
    """
    v = u[0] + dist[0]
    return np.array([xi[0] + dt * math.cos(xi[2]) * v,
                     xi[1] + dt * math.sin(xi[2]) * v,
                     xi[2] + dt * (u[1] + dist[1])])


def trial(setup: Setup, memory: NDArray[np.float64], xi0: NDArray[np.float64],
          dist: NDArray[np.float64], noise: NDArray[np.float64], tau: NDArray[np.int64],
          tau0: NDArray[np.int64]) -> tuple[NDArray[np.float64], ...]:
    """One trial of the team; returns (xi, eta, u, next memory).

    memory : shape (n, T, 2); xi0 : shape (n, 3); dist : shape (n, T, 2);
    noise : shape (n, T+1, 3); tau : shape (n, n, T+1), tau[i, j, t] the delay in samples
    of the link j -> i at sample t; tau0 : shape (n, T+1), the leader link's.
    xi, eta : shape (n, T+1, 3); u : shape (n, T, 2).
    A link delivers at sample t the sender's output labelled t - tau (eq. 9).
    """
    n, n_t = setup.n, setup.samples
    xi = np.zeros((n, n_t + 1, 3))
    eta = np.zeros((n, n_t + 1, 3))
    u = np.zeros((n, n_t, 2))
    xi[:, 0] = xi0
    for t in range(n_t + 1):
        for i in range(n):
            eta[i, t] = xi[i, t] + noise[i, t]
        if t == n_t:
            break
        for i in range(n):
            received = {}
            for j in setup.senders(i):
                s = t - int(tau[i, j, t])
                if s >= 0:
                    received[j] = (s, eta[j, s].copy())
            own = np.full((n_t + 1, 3), np.nan)
            own[: t + 1] = eta[i, : t + 1]  # a robot knows only its past
            u[i, t] = command(setup, i, t, memory[i, t], own, received, t - int(tau0[i, t]))
        for i in range(n):
            xi[i, t + 1] = plant_step(xi[i, t], u[i, t], dist[i, t], setup.dt)
    nxt = np.stack([learn(setup, i, memory[i], u[i], eta) for i in range(n)])
    return xi, eta, u, nxt


def trial_metrics(setup: Setup, xi: NDArray[np.float64],
                  eta: NDArray[np.float64]) -> NDArray[np.float64]:
    """The per-trial errors of docs/reproduction.md "Metrics", over robots and t in [1, T].

    Returns (max position error, max heading error, the same two for the true state,
    rms position error, max formation position error |e_ij|) [m, rad, m, rad, m, m].
    """
    d = setup.eta_d
    n, n_t = setup.n, setup.samples
    pos, head, tpos, thead, sq, form = [], [], [], [], [], [0.0]
    for i in range(n):
        for t in range(1, n_t + 1):
            pos.append(math.hypot(d[i, t, 0] - eta[i, t, 0], d[i, t, 1] - eta[i, t, 1]))
            head.append(abs(wrap(d[i, t, 2] - eta[i, t, 2])))
            tpos.append(math.hypot(d[i, t, 0] - xi[i, t, 0], d[i, t, 1] - xi[i, t, 1]))
            thead.append(abs(wrap(d[i, t, 2] - xi[i, t, 2])))
            sq.append(pos[-1] ** 2)
            for j in setup.senders(i):
                e = link_error(d[i, t], d[j, t], eta[i, t], eta[j, t])
                form.append(math.hypot(e[0], e[1]))
    return np.array([max(pos), max(head), max(tpos), max(thead), math.sqrt(sum(sq) / len(sq)),
                     max(form)])


def measure_delay(receive_time: float, send_time: float, dt: float) -> int:
    """Eq. (11) evaluated exactly (rational arithmetic on the given floats), never < 0."""
    x = (Fraction(receive_time) - Fraction(send_time) + Fraction(dt) / 2) / Fraction(dt)
    return max(0, math.floor(x))


def measure_delay_ns(receive_ns: int, send_ns: int, dt_ns: int) -> int:
    """Eq. (11) on integer nanoseconds: floor((2 (Rt - St) + dT) / (2 dT)), never < 0."""
    return max(0, (2 * (receive_ns - send_ns) + dt_ns) // (2 * dt_ns))
