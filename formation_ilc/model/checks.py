"""Checks a user can run before a run: Theorem 2, condition (20), and the lifted heading map.

Condition (20) is pointwise in time. Whether the errors actually shrink from trial to trial
without huge transients depends on the whole-trial (lifted) map of the heading channel,
which is linear: theta(t+1) = theta(t) + dT (omega(t) + Domega(t)), and the law's heading
row only sees heading errors (paper-notes 13).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from formation_ilc.config.scenario import Scenario
from formation_ilc.core.law import law_code
from formation_ilc.core.topology import Graph, unreachable_robots

__all__ = ["condition20", "HeadingMap", "heading_map", "CheckReport", "check_scenario",
           "check_bytes"]

#: largest lifted map (robots x samples) the check builds; beyond, it is skipped
LIFTED_LIMIT = 3600


def condition20(graph: Graph, gain: NDArray[np.float64], dt: float,
                include_dt: bool = True) -> float:
    """||I_2n - ((L + Omega) kron I_2) Gamma B||_2 for the heading-aligned gain.

    With Gamma_i = g_i [[cos th, sin th, 0], [0, 0, 1]] and B as in eq. (3), Gamma_i B_i =
    g_i dT I_2 exactly, so the value is ||I_n - (L + Omega) diag(g) dT||_2 at every t.
    ``include_dt=False`` leaves dT out of B, which is how the paper's 0.9783 comes out
    (paper-notes 11).
    """
    g = np.asarray(gain, dtype=float) * (dt if include_dt else 1.0)
    m = np.eye(graph.n) - graph.xi @ np.diag(g)
    return float(np.linalg.norm(m, 2))


def _norm2(m: NDArray[np.float64], iters: int = 60, seed: int = 0) -> float:
    """Largest singular value by power iteration on M^T M (cheaper than an SVD)."""
    v0 = np.random.default_rng(seed).standard_normal(m.shape[1])
    v: NDArray[np.float64] = np.asarray(v0 / np.linalg.norm(v0), dtype=float)
    s = 0.0
    for _ in range(iters):
        w = m.T @ (m @ v)
        nw = float(np.linalg.norm(w))
        if nw == 0.0:
            return 0.0
        s_new = float(np.sqrt(nw))
        v = np.asarray(w / nw, dtype=float)
        if abs(s_new - s) <= 1e-10 * s_new:
            return float(s_new)
        s = s_new
    return float(s)


@dataclass(frozen=True)
class HeadingMap:
    """The lifted trial-to-trial map of the heading memory error, mu_{k+1} = M mu_k.

    norm : ||M||_2 (< 1 means the error shrinks every trial).
    spectral_radius : rho(M) (< 1 means it converges eventually).
    growth : max over k in ``powers`` of ||M^k||_2, the worst transient amplification.
    initial_growth : the same for the error the run starts from (u_0 = 0).
    """

    norm: float
    spectral_radius: float
    growth: float
    growth_trial: int
    initial_growth: float
    powers: tuple[int, ...]
    norms: tuple[float, ...]

    def verdict(self, literal: bool = False, law: int = 9) -> str:
        if self.spectral_radius >= 1.0:
            return ("will not converge: the heading memory error grows from trial to trial "
                    f"(spectral radius {self.spectral_radius:.6f} >= 1)")
        if self.norm < 1.0:
            return ("converges monotonically: the heading error shrinks every trial "
                    f"(lifted norm {self.norm:.6f} < 1)")
        if self.growth < 10.0:
            return (f"converges, with a mild transient: errors may grow up to "
                    f"x{self.growth:.3g} before they shrink")
        if literal:
            advice = ("memory 'feedforward' (paper-notes 12), a smaller gain_prime, or a "
                      "graph with shorter paths from the leader")
        elif law == 22:
            advice = "law 9 (its current term damps the transient), or shorter graph paths"
        else:
            advice = "a smaller gain_prime, or a graph with shorter paths from the leader"
        return (f"converges only in the long run: before it does, the heading error can grow "
                f"up to x{self.growth:.3g} (around trial {self.growth_trial}); expect large, "
                f"long transients. Consider {advice}")


def heading_map(sc: Scenario, trials: int | None = None,
                early_stop: bool = False, stop_above: float | None = None
                ) -> HeadingMap | None:
    """Build the lifted heading map of a scenario, with delays at their expected value.

    The current term's delay enters as the mean operator sum_d P(tau = d) K ê(t - d).
    Returns None when robots x samples exceeds LIFTED_LIMIT.
    ``early_stop`` stops squaring once ||M^k|| < 1: then ||M^2k|| <= ||M^k||^2 < 1, so no
    later power of two can raise ``growth`` (what ``tune`` and ``sweep`` use; it saves the
    large matrix products of a long horizon). ``stop_above`` stops as soon as a norm exceeds
    it: ``growth`` is then a lower bound, enough to reject a candidate.
    """
    n, n_t, dt = sc.n, sc.samples, sc.dt
    if n * n_t > LIFTED_LIMIT:
        return None
    law = law_code(sc.law.kind)
    g = np.asarray(sc.law.gain, dtype=float)
    gp = np.asarray(sc.law.gain_prime, dtype=float)
    adj = sc.graph.adjacency
    lead = sc.graph.leader
    unc = sc.uncertainty
    pmf = unc.delay.pmf()
    pmf_lead = pmf if unc.delay_leader else {0: 1.0}
    deg = adj.sum(axis=1)
    size = n * n_t
    # unit impulses in mu(t), robot r: column t * n + r
    e = np.zeros((n_t + 1, n, size))
    cur = np.zeros((n_t, n, size))
    for t in range(n_t):
        c = np.zeros((n, size))
        if law != 22:
            for d, p in pmf.items():
                s = t - d
                if s >= 1:
                    own = e[s] if law == 9 else e[t]
                    c += p * (deg[:, None] * own - adj @ e[s])
            for d, p in pmf_lead.items():
                s = t - d
                if s >= 1:
                    c += p * lead[:, None] * (e[s] if law == 9 else e[t])
        cur[t] = c
        e[t + 1] = e[t] - dt * gp[:, None] * c
        e[t + 1, :, t * n: (t + 1) * n] += dt * np.eye(n)
    xi = sc.graph.xi
    m = np.eye(size)
    for t in range(n_t):
        rows = slice(t * n, (t + 1) * n)
        m[rows] -= g[:, None] * (xi @ e[t + 1])
        if sc.law.memory == "literal" and law != 22:
            m[rows] -= gp[:, None] * cur[t]
    # M is block lower triangular in time: its eigenvalues are those of the diagonal blocks
    blocks = [m[t * n:(t + 1) * n, t * n:(t + 1) * n] for t in range(n_t)]
    rho = max(float(np.max(np.abs(np.linalg.eigvals(b)))) for b in blocks)
    k_max = sc.trials if trials is None else trials
    mu0 = np.zeros(size)  # u_0 = 0: the memory error is omega_d itself
    mu0[:] = sc.desired.u[:, :, 1].T.reshape(-1)
    powers, norms = [], []
    pk = m.copy()
    k = 1
    best, best_k, init_best = 0.0, 1, 0.0
    while k <= max(1, k_max):
        nk = _norm2(pk)
        powers.append(k)
        norms.append(nk)
        if nk > best:
            best, best_k = nk, k
        if np.linalg.norm(mu0) > 0:
            init_best = max(init_best, float(np.linalg.norm(pk @ mu0) / np.linalg.norm(mu0)))
        if (early_stop and nk < 1.0) or (stop_above is not None and nk > stop_above):
            break
        pk = pk @ pk
        k *= 2
    return HeadingMap(norm=norms[0], spectral_radius=rho, growth=best, growth_trial=best_k,
                      initial_growth=init_best, powers=tuple(powers), norms=tuple(norms))


@dataclass(frozen=True)
class CheckReport:
    spanning_tree: bool
    unreachable: tuple[int, ...]
    cond20: float
    cond20_paper: float
    heading: HeadingMap | None

    def lines(self, sc: Scenario) -> list[str]:
        out = [f"scenario {sc.name}: {sc.n} robots, T = {sc.samples} samples of {sc.dt} s, "
               f"law ({sc.law.kind}), memory {sc.law.memory}"]
        if self.spanning_tree:
            out.append("Theorem 2: the graph with the leader has a spanning tree: ok")
        else:
            names = ", ".join(str(i + 1) for i in self.unreachable)
            out.append(f"Theorem 2: NO spanning tree: the leader cannot reach robot(s) {names}")
        ok = "holds" if self.cond20 < 1 else "FAILS"
        out.append(f"condition (20): ||I - (L+Omega)(x)I2 Gamma B|| = {self.cond20:.6f} "
                   f"({ok}, B with dT as in eq. 3)")
        out.append(f"                with dT left out of B as the paper computed it: "
                   f"{self.cond20_paper:.6f}")
        if self.heading is None:
            out.append(f"lifted heading map: skipped (robots x samples > {LIFTED_LIMIT})")
        else:
            h = self.heading
            out.append(f"lifted heading map (expected delays): norm {h.norm:.6f}, spectral "
                       f"radius {h.spectral_radius:.6f}, max ||M^k|| = {h.growth:.4g} at "
                       f"k = {h.growth_trial}; growth of the start error x{h.initial_growth:.4g}")
            literal = sc.law.memory == "literal" and sc.law.kind != 22
            out.append(f"verdict: {h.verdict(literal, sc.law.kind)}")
            out.append("         (linear analysis of the heading channel from the desired "
                       "trajectory; errors near pi, e.g. a first trial from u = 0, can leave "
                       "its range: the literal reading may then stall, see "
                       "docs/reproduction.md)")
        return out


def check_bytes(sc: Scenario) -> int:
    """Peak memory [bytes] of ``check_scenario`` beyond the loaded scenario: the lifted map
    and its powers, about 5 matrices of (robots x samples)^2 (measured peak RSS: 41 bytes per
    entry at 1800 and 3600), nothing when the map is skipped (LIFTED_LIMIT), and the graph's
    robots x robots matrices."""
    size = sc.n * sc.samples
    return (48 * size * size if size <= LIFTED_LIMIT else 0) + 64 * sc.n * sc.n


def check_scenario(sc: Scenario, trials: int | None = None) -> CheckReport:
    bad = unreachable_robots(sc.graph.adjacency, sc.graph.leader)
    g = np.asarray(sc.law.gain, dtype=float)
    hm = heading_map(sc, trials) if not bad else None
    return CheckReport(spanning_tree=not bad, unreachable=tuple(bad),
                       cond20=condition20(sc.graph, g, sc.dt),
                       cond20_paper=condition20(sc.graph, g, sc.dt, include_dt=False),
                       heading=hm)
