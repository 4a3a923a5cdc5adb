import dataclasses

import numpy as np
import pytest

from formation_ilc.core.topology import Graph, SpanningTreeError, laplacian, unreachable_robots
from formation_ilc.model.checks import condition20


def paper_tree() -> Graph:
    # v0 -> {1, 4}, 1 -> {2, 6}, 4 -> {3, 5} (paper-notes 11)
    return Graph.from_edges(6, [(2, 1, 1), (6, 1, 1), (3, 4, 1), (5, 4, 1)], {1: 1, 4: 1})


def test_laplacian_rows_sum_to_zero_and_diagonal_is_in_degree():
    a = np.array([[0, 1, 2], [0, 0, 0], [3, 0, 0]], dtype=float)
    lap = laplacian(a)
    np.testing.assert_allclose(lap.sum(axis=1), 0)
    np.testing.assert_allclose(np.diag(lap), [3, 0, 3])
    assert lap[0, 2] == -2


def test_xi_is_laplacian_plus_omega():
    g = paper_tree()
    np.testing.assert_allclose(g.xi, g.laplacian + np.diag(g.leader))
    assert g.neighbours(1) == [0]
    src, w = g.in_links()
    assert src.shape == (6, 1) and src[0, 0] == -1 and src[1, 0] == 0 and w[1, 0] == 1


def test_condition20_matches_paper_values():
    g = paper_tree()
    gain = np.full(6, 0.08)
    # with dT left out of B, the paper's 0.9783 (paper-notes 11)
    assert condition20(g, gain, 0.1, include_dt=False) == pytest.approx(0.978306, abs=1e-6)
    with_dt = condition20(g, gain, 0.1)
    assert 0.992 <= with_dt < 1.0


def test_chain_is_worse_than_relay_tree():
    chain = Graph.from_edges(6, [(i + 1, i, 1) for i in range(1, 6)], {1: 1})
    assert condition20(chain, np.full(6, 0.08), 1.0) > condition20(paper_tree(),
                                                                   np.full(6, 0.08), 1.0)


def test_spanning_tree_refused_and_names_robots():
    # robots 3 and 4 only listen to each other: the leader never reaches them
    g = Graph.from_edges(4, [(2, 1, 1), (3, 4, 1), (4, 3, 1)], {1: 1})
    assert unreachable_robots(g.adjacency, g.leader) == [2, 3]
    with pytest.raises(SpanningTreeError, match=r"robot\(s\) 3, 4"):
        g.check_spanning_tree()
    paper_tree().check_spanning_tree()


def test_spanning_tree_implies_nonsingular_xi():
    # Theorem 2's contrapositive: without a spanning tree, L + Omega is singular
    bad = Graph.from_edges(3, [(2, 1, 1)], {1: 1})
    assert abs(np.linalg.det(bad.xi)) < 1e-12
    assert abs(np.linalg.det(paper_tree().xi)) > 1e-6


def test_graph_rejects_self_loops_and_negative_weights():
    with pytest.raises(ValueError):
        Graph(np.eye(2), np.ones(2))
    with pytest.raises(ValueError):
        Graph(-np.ones((2, 2)) + np.eye(2), np.ones(2))


# ----------------------------------------------------------------------------------------
# Graph validation edges and the kernels' in-link table of a graph without edges.

def test_non_square_adjacency_is_refused_before_the_leader_shape():
    with pytest.raises(ValueError, match=r"adjacency must be square, got shape \(2, 3\)"):
        Graph(np.zeros((2, 3)), np.ones(2))
    with pytest.raises(ValueError, match="adjacency must be square"):
        Graph(np.zeros(3), np.ones(3))


def test_negative_leader_weight_is_refused():
    with pytest.raises(ValueError, match="non-negative"):
        Graph(np.zeros((2, 2)), np.array([1.0, -0.5]))


def test_in_links_of_a_graph_without_edges_have_one_padded_column():
    g = Graph(np.zeros((3, 3)), np.ones(3))
    src, w = g.in_links()
    assert src.shape == (3, 1) and (src == -1).all() and not w.any()
    g.check_spanning_tree()


def test_graph_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        Graph(np.zeros((1, 1)), np.ones(1)).leader = np.zeros(1)  # type: ignore[misc]
