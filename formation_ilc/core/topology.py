"""Communication graph: Laplacian, leader weights and the spanning-tree check of Theorem 2.

Robots are numbered 1..n in user-facing text (as in the paper) and 0..n-1 in arrays.
``adjacency[i, j] = a_ij > 0`` means robot i *receives* from robot j (edge (v_i, v_j) of the
paper: information flows from j to i). ``leader[i] = a_i0 > 0`` means robot i hears the
virtual leader v_0.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Graph", "SpanningTreeError", "laplacian", "unreachable_robots"]


class SpanningTreeError(ValueError):
    """The graph with the leader has no spanning tree rooted at the leader (Theorem 2)."""

    def __init__(self, unreachable: list[int]):
        self.unreachable = unreachable
        names = ", ".join(str(i + 1) for i in unreachable)
        super().__init__(
            f"the graph with the virtual leader has no spanning tree: the leader cannot reach "
            f"robot(s) {names}. Theorem 2: no gain can satisfy condition (20); give one of them "
            f"a leader weight or an in-edge from a robot the leader reaches."
        )


def laplacian(adjacency: NDArray[np.float64]) -> NDArray[np.float64]:
    """L_A = Delta_A - A, with Delta_A the diagonal of row sums (in-degrees).

    adjacency : ndarray, shape (n, n), a_ij >= 0, zero diagonal.
    """
    a = np.asarray(adjacency, dtype=float)
    return np.diag(a.sum(axis=1)) - a


def unreachable_robots(adjacency: NDArray[np.float64], leader: NDArray[np.float64]) -> list[int]:
    """Robots (0-based) that no directed path from the leader reaches.

    Information flows from j to i when a_ij > 0, so a breadth-first search from the leader
    walks the edges j -> i.
    """
    a = np.asarray(adjacency, dtype=float)
    n = a.shape[0]
    seen = np.asarray(leader, dtype=float) > 0
    queue = deque(int(i) for i in np.flatnonzero(seen))
    while queue:
        j = queue.popleft()
        for i in np.flatnonzero(a[:, j] > 0):
            if not seen[i]:
                seen[i] = True
                queue.append(int(i))
    return [i for i in range(n) if not seen[i]]


@dataclass(frozen=True)
class Graph:
    """Weighted digraph of n robots plus the virtual leader.

    adjacency : ndarray, shape (n, n); a_ij > 0 if robot i receives from robot j.
    leader : ndarray, shape (n,); a_i0 > 0 if robot i receives the reference.
    """

    adjacency: NDArray[np.float64]
    leader: NDArray[np.float64]

    def __post_init__(self) -> None:
        a = np.asarray(self.adjacency, dtype=float)
        w = np.asarray(self.leader, dtype=float)
        if a.ndim != 2 or a.shape[0] != a.shape[1]:
            raise ValueError(f"adjacency must be square, got shape {a.shape}")
        if w.shape != (a.shape[0],):
            raise ValueError(f"leader weights must have shape ({a.shape[0]},), got {w.shape}")
        if (a < 0).any() or (w < 0).any():
            raise ValueError("weights must be non-negative")
        if np.any(np.diag(a) != 0):
            raise ValueError("a robot cannot be its own neighbour (non-zero diagonal)")
        object.__setattr__(self, "adjacency", a)
        object.__setattr__(self, "leader", w)

    @classmethod
    def from_edges(
        cls, n: int, edges: list[tuple[int, int, float]], leader: dict[int, float]
    ) -> Graph:
        """Build from 1-based edges ``(receiver, sender, weight)`` and ``{robot: a_i0}``."""
        a = np.zeros((n, n))
        for i, j, w in edges:
            a[i - 1, j - 1] = w
        lw = np.zeros(n)
        for i, w in leader.items():
            lw[i - 1] = w
        return cls(a, lw)

    @property
    def n(self) -> int:
        return int(self.adjacency.shape[0])

    @property
    def laplacian(self) -> NDArray[np.float64]:
        return laplacian(self.adjacency)

    @property
    def omega(self) -> NDArray[np.float64]:
        """Omega = diag(a_10, ..., a_n0)."""
        return np.diag(self.leader)

    @property
    def xi(self) -> NDArray[np.float64]:
        """L_A + Omega, shape (n, n). The paper's Xi is this kron I_2."""
        return self.laplacian + self.omega

    def neighbours(self, i: int) -> list[int]:
        """0-based senders robot i listens to, in ascending order."""
        return [int(j) for j in np.flatnonzero(self.adjacency[i] > 0)]

    def in_links(self) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """Padded in-link table for the kernels.

        Returns src, shape (n, L) with -1 padding, and weights, shape (n, L), with
        L the largest in-degree (at least 1).
        """
        lists = [self.neighbours(i) for i in range(self.n)]
        width = max(1, max(len(x) for x in lists))
        src = -np.ones((self.n, width), dtype=np.int64)
        w = np.zeros((self.n, width))
        for i, js in enumerate(lists):
            src[i, : len(js)] = js
            w[i, : len(js)] = self.adjacency[i, js]
        return src, w

    def check_spanning_tree(self) -> None:
        """Raise SpanningTreeError naming the robots the leader cannot reach."""
        bad = unreachable_robots(self.adjacency, self.leader)
        if bad:
            raise SpanningTreeError(bad)
