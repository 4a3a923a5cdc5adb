"""Graph validation edges and the kernels' in-link table of a graph without edges."""

import dataclasses

import numpy as np
import pytest

from formation_ilc.core.topology import Graph


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
