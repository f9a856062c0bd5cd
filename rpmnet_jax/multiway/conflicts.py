"""Step 3b of :func:`rpmnet_jax.align_scans`: the pose graph's answer checked where no edge looked. On a site whose
streets look alike, one wrong pair edge can carry a whole group of scans, each right with its neighbours, onto a
look-alike street elsewhere; no cycle contradicts that edge, so the robust graph keeps it. The scans the answer
puts near one another (sensors within ``reach``) must then see each other's surfaces, not stand in their free
space: pairs that fail the free-space check (:mod:`rpmnet_jax.geometry.visibility`) are conflicts, and the kept
edges the most conflicts' paths cross in the maximum spanning tree of the kept edges are the suspects.

Measured on 300 stations of the simulated site (seed 2, tuning data): the graph placed a group of 12 stations 90°
and about 200 m off on one wrong edge. Of the placed pairs with sensors within 20 m, the 729 right ones put at most
1.1% of their points in the other's free space; the 39 between that group and the scans it was laid over, 1.7% to
far above the bound of then, 4%, median 5.7%.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from scipy.spatial import cKDTree

from rpmnet_jax.pose_graphs import pose_graph

REACH = 0.3  # × the median robust scan radius: pairs of placed scans whose sensors lie this near are checked
# (20 m on the site's 62 m scans; at 40 m the pairs the wrong group made included some at 0%: tuning data)
MAX_SHARE = 0.04  # a conflict: more than this share of either scan in the other's free space at poses composed
# through the pose graph (steps 3b, 3c and 5b), not visibility.MAX_FREE_SPACE_SHARE (0.015), the bar of one
# registration's answer. A group of stations joined at one junction carries its own drift (0.5-5 m at a 1,000-station
# site's far ends before the refinement), and its right placements fail 0.015. On the town's seed 8 (1,000 stations,
# pairs cached; tuning data since): 0.015 placed 390 (348 within 0.2 deg and 1 cm), 0.04 placed 736 (511 within),
# none wrong in either. Seed 7's look-alike streets stay refused at the edges (0.015): its 10 stations all within
# 0.2 deg and 1 cm at both


def near_placed(poses: np.ndarray, sensors, reach: float) -> list:
    """``[(i, j), ...]``, ``i < j``: the placed scans (finite ``poses (S, 4, 4)``) with a known sensor (``sensors``:
    ``(3,)`` or None per scan, in its own frame) whose sensors lie within ``reach`` of each other at ``poses``."""
    rows = [s for s in range(len(poses)) if np.isfinite(poses[s, 0, 0]) and sensors[s] is not None]
    if len(rows) < 2:
        return []
    at = np.array([poses[s, :3, :3] @ sensors[s] + poses[s, :3, 3] for s in rows])
    return sorted((rows[a], rows[b]) for a, b in cKDTree(at).query_pairs(reach, output_type="ndarray"))  # a < b


def suspects(num_scans: int, kept, weights, conflicts) -> list:
    """The indices into ``kept`` (edges with ``source``, ``target``) of the edges whose removal explains the most of
    ``conflicts`` ``[(i, j), ...]``: of the maximum-``weights`` spanning forest of ``kept``, the edges on the most
    conflicting pairs' paths, every one of a tie (along a chain of bridges the conflicts cannot tell which link
    is wrong: on 1,000 site stations, seed 3, a wrong edge and the right one next to it were crossed by the same
    705 conflicts, and the doubt weights favoured the wrong one), lowest weight first; where no edge is crossed
    twice (one conflict's path) only the lightest. Empty without a conflict joined by the forest."""
    pairs = np.array([(e.source, e.target) for e in kept], np.int64).reshape(-1, 2)
    tree = np.flatnonzero(pose_graph.spanning_forest(num_scans, pairs, weights))
    neighbours = [[] for _ in range(num_scans)]
    for e in tree:
        a, b = pairs[e]
        neighbours[a].append((b, e))
        neighbours[b].append((a, e))
    parent, up, depth = np.full(num_scans, -1), np.full(num_scans, -1), np.full(num_scans, -1)
    for root in range(num_scans):  # every tree of the forest, breadth first
        if depth[root] >= 0 or not neighbours[root]:
            continue
        depth[root] = 0
        queue = deque([root])
        while queue:
            a = queue.popleft()
            for b, e in neighbours[a]:
                if depth[b] < 0:
                    parent[b], up[b], depth[b] = a, e, depth[a] + 1
                    queue.append(b)
    crossed = np.zeros(len(kept))
    for a, b in conflicts:
        if depth[a] < 0 or depth[b] < 0:
            continue
        path = []
        while a != b:  # climb from the deeper end until they meet
            if depth[a] < depth[b]:
                a, b = b, a
            if parent[a] < 0:  # different trees of the forest
                path = []
                break
            path.append(up[a])
            a = parent[a]
        crossed[path] += 1
    if not crossed.any():
        return []
    w = np.asarray(weights, np.float64)
    tied = sorted((int(e) for e in np.flatnonzero(crossed == crossed.max())), key=lambda e: (w[e], e))
    return tied if crossed.max() > 1 else tied[:1]
