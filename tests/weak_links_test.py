"""A campaign's weak links (``edge_graph.without_weak_links``): an edge far weaker than the campaign's typical edge
joins scans only where stronger edges join them too; the scans it alone carried lose their poses."""

import numpy as np

from rpmnet_jax.multiway import edge_graph
from rpmnet_jax.pair_edges.edges import Edge


def _edge(i, j, balanced):
    return Edge(i, j, np.eye(4), balanced, 0.0, np.eye(6), 0.0, "classical", balanced_fitness=balanced)


def _poses(n):
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.arange(n)
    return poses


def test_weak_bar_is_a_share_of_the_median():
    edges = [_edge(0, 1, 0.8), _edge(1, 2, 0.9), _edge(2, 3, 0.2)]
    assert edge_graph.weak_bar(edges) == edge_graph.WEAK_LINK * 0.8
    assert edge_graph.weak_bar([]) == 0.0


def test_a_weak_bridge_leaves_the_smaller_part_unplaced():
    # 0-1-2 strong, 3-4 strong, joined only by the weak (2, 3)
    kept = [_edge(0, 1, 0.8), _edge(1, 2, 0.8), _edge(2, 3, 0.2), _edge(3, 4, 0.8)]
    poses, stay, off = edge_graph.without_weak_links(5, _poses(5), kept, 0.4)
    assert np.isfinite(poses[:3, 0, 0]).all() and np.isnan(poses[3:, 0, 0]).all()
    np.testing.assert_array_equal(poses[:3], _poses(5)[:3])  # the part keeps its solved poses
    assert [(e.source, e.target) for e in stay] == [(0, 1), (1, 2)]
    assert [(e.source, e.target) for e in off] == [(2, 3)]  # the link; (3, 4) is off the part, not rejected


def test_a_weak_edge_inside_a_strong_part_stays():
    # (0, 2) is weak but 0 and 2 are joined by strong edges: a loop, not a link
    kept = [_edge(0, 1, 0.8), _edge(1, 2, 0.8), _edge(0, 2, 0.2)]
    poses, stay, off = edge_graph.without_weak_links(3, _poses(3), kept, 0.4)
    assert np.isfinite(poses[:, 0, 0]).all() and len(stay) == 3 and off == []


def test_unplaced_scans_stay_unplaced_and_the_largest_part_wins():
    poses = _poses(6)
    poses[5] = np.nan
    # a strong pair 0-1 weakly linked to the strong chain 2-3-4: the chain has more scans
    kept = [_edge(0, 1, 0.9), _edge(1, 2, 0.1), _edge(2, 3, 0.9), _edge(3, 4, 0.9)]
    out, stay, off = edge_graph.without_weak_links(6, poses, kept, 0.4)
    assert np.flatnonzero(np.isfinite(out[:, 0, 0])).tolist() == [2, 3, 4]
    assert [(e.source, e.target) for e in off] == [(1, 2)]


def test_strong_parts_use_the_edges_at_the_bar():
    labels = edge_graph.strong_parts(4, [_edge(0, 1, 0.5), _edge(1, 2, 0.49), _edge(2, 3, 0.6)], 0.5)
    assert labels[0] == labels[1] != labels[2] == labels[3]
