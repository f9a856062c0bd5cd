"""Step 3b's pieces: which placed scans stand near each other, and which kept edge the conflicts point at."""

from typing import NamedTuple

import numpy as np

from rpmnet_jax.multiway import conflicts


class _Edge(NamedTuple):
    source: int
    target: int


def _at(*xyz):
    poses = np.tile(np.eye(4), (len(xyz), 1, 1))
    poses[:, :3, 3] = xyz
    return poses


def test_near_placed_pairs_by_their_sensors():
    poses = _at((0, 0, 0), (5, 0, 0), (30, 0, 0), (31, 0, 0))
    poses[2] = np.nan  # unplaced
    sensors = [np.zeros(3), np.zeros(3), np.zeros(3), np.array([-24.0, 0, 0])]  # scan 3's sensor at x = 7
    assert conflicts.near_placed(poses, sensors, 6.0) == [(0, 1), (1, 3)]
    assert conflicts.near_placed(poses, [np.zeros(3), None, None, None], 6.0) == []


def test_the_edge_every_conflict_crosses_is_the_suspect():
    # two chains 0-1-2-3 and 4-5-6 joined by the edge (3, 4): every conflict between them crosses it
    kept = [_Edge(0, 1), _Edge(1, 2), _Edge(2, 3), _Edge(3, 4), _Edge(4, 5), _Edge(5, 6)]
    weights = [0.9, 0.9, 0.9, 0.95, 0.9, 0.9]  # the join weighs most: the count decides, not the weight
    assert conflicts.suspects(7, kept, weights, [(2, 4), (3, 5), (3, 6)]) == [3]
    # conflicts that the edges (2, 3) and (3, 4) explain alike (3 each): both, the least trusted first
    assert conflicts.suspects(7, kept, [0.9, 0.9, 0.9, 0.3, 0.9, 0.9], [(1, 5), (2, 6), (0, 4)]) == [3, 2]
    assert conflicts.suspects(7, kept, [0.9, 0.9, 0.5, 0.9, 0.9, 0.9], [(1, 5), (2, 6), (0, 4)]) == [2, 3]


def test_a_cycle_edge_outside_the_tree_is_never_the_suspect():
    kept = [_Edge(0, 1), _Edge(1, 2), _Edge(0, 2), _Edge(2, 3)]
    weights = [0.9, 0.9, 0.1, 0.8]  # (0, 2) is the cycle's lightest edge: off the maximum spanning tree
    assert conflicts.suspects(4, kept, weights, [(0, 3)]) == [3]  # one conflict: its path's lightest edge


def test_no_conflict_joined_gives_none():
    kept = [_Edge(0, 1), _Edge(2, 3)]
    assert conflicts.suspects(5, kept, [1.0, 1.0], []) == []
    assert conflicts.suspects(5, kept, [1.0, 1.0], [(0, 2)]) == []  # different trees of the forest
    assert conflicts.suspects(5, kept, [1.0, 1.0], [(0, 4)]) == []  # scan 4 has no edge


def test_a_conflict_is_judged_at_the_bar_of_composed_poses_not_at_an_answers():
    """A room station slid from its true place along the other's x axis: once more than 1.5% of it lies in the other's
    free space the slide is no edge (one registration's answer, ``visibility.MAX_FREE_SPACE_SHARE``), but only past
    ``conflicts.MAX_SHARE`` (4%) is it a conflict of placed scans (poses composed through the graph carry a group's
    drift)."""
    from types import SimpleNamespace

    from rpmnet_jax.geometry import sampling, visibility
    from rpmnet_jax.multiway import edge_graph, scan_alignment
    from rpmnet_jax.simulation import rooms

    voxel = 0.05
    a, b = rooms.stations(0)[:2]
    points = [sampling.voxel_downsample(s.points, None, voxel)[0] for s in (a, b)]
    free = edge_graph.FreeSpace(points, [np.zeros(3), np.zeros(3)], voxel)
    run = SimpleNamespace(prepared=SimpleNamespace(sensors=free.sensors), conflict_reach=20.0, visible=free)
    found = {}
    for d in np.arange(0.0, 4.0, 0.01):
        slid = _at((d, 0.0, 0.0))[0] @ np.linalg.inv(b.pose) @ a.pose  # a's frame → b's, slid by d
        share = visibility.violation(points[0], free.image(0), points[1], free.image(1), slid, free.margin)
        kind = ("between" if visibility.MAX_FREE_SPACE_SHARE < share <= conflicts.MAX_SHARE
                else "beyond" if share > conflicts.MAX_SHARE else None)
        found.setdefault(kind, slid)
        if "beyond" in found:
            break
    assert "between" in found and "beyond" in found, found.keys()
    poses = np.stack([found["between"], np.eye(4)])  # scan 0 placed at the slide, scan 1 the frame
    assert not free(SimpleNamespace(source=0, target=1, transform=found["between"]))  # no edge
    assert scan_alignment._conflicts(run, poses, []) == []  # no conflict
    poses[0] = found["beyond"]
    assert scan_alignment._conflicts(run, poses, []) == [(0, 1)]


def test_a_compacted_free_space_check_judges_as_before():
    """``FreeSpace.compact`` (before a site's finer scans): the range images let go, the points held in float32 as
    its own copies; the check made again from them gives the same verdicts and shares within 0.1% of the points."""
    from rpmnet_jax.geometry import sampling, visibility
    from rpmnet_jax.multiway import edge_graph
    from rpmnet_jax.simulation import rooms

    voxel = 0.05
    a, b = rooms.stations(0)[:2]
    points = [sampling.voxel_downsample(s.points, None, voxel)[0] for s in (a, b)]
    free = edge_graph.FreeSpace(points, [np.zeros(3), np.zeros(3)], voxel)
    slides = [_at((d, 0.0, 0.0))[0] @ np.linalg.inv(b.pose) @ a.pose for d in (0.0, 0.3, 1.0, 2.0)]
    before = [visibility.violation(free.points[0], free.image(0), free.points[1], free.image(1), t, free.margin)
              for t in slides]
    verdicts = [free.clear(0, 1, t) for t in slides]
    free.compact()
    assert free.images == {} and all(p.dtype == np.float32 and not np.shares_memory(p, q)
                                     for p, q in zip(free.points, points))
    after = [visibility.violation(free.points[0], free.image(0), free.points[1], free.image(1), t, free.margin)
             for t in slides]
    assert max(before) > 0.05 and min(before) < 0.01  # right and wrong slides both judged
    np.testing.assert_allclose(after, before, rtol=0, atol=1e-3)  # a few points across a bin's edge: measured 4e-4
    assert [free.clear(0, 1, t) for t in slides] == verdicts
