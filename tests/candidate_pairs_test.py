"""Candidate pairs: the selection gives every scan its partners in one connected graph, deterministically; the
overlap scores are symmetric, ignore each scan's orientation, rank neighbouring views above far ones, and on the
real bunny scans give bun000 its true neighbours."""

import numpy as np
import pytest

from conftest import DATA, random_pose, require
from rpmnet_jax.data import synthetic
from rpmnet_jax.io import clouds as cloud_io, poses as scan_poses
from rpmnet_jax.multiway import candidate_pairs, preparation
from rpmnet_jax.pair_edges import edges

BUNNY = DATA / "stanford_bunny"


def _connected(num_scans, pairs):
    reached, frontier = {0}, [0]
    while frontier:
        a = frontier.pop()
        for b in {j for i, j in pairs if i == a} | {i for i, j in pairs if j == a}:
            if b not in reached:
                reached.add(b)
                frontier.append(b)
    return len(reached) == num_scans


def _random_scores(rng, n, groups=1):
    """``(n, n)`` symmetric scores; with ``groups``, high within blocks of consecutive scans, low across."""
    s = rng.uniform(size=(n, n))
    block = np.arange(n) * groups // n
    s = 0.5 * (s + s.T) + 2.0 * (block[:, None] == block[None])
    return s


@pytest.mark.parametrize("n, k, groups", [(2, 1, 1), (7, 3, 1), (7, 10, 1), (30, 3, 1), (30, 2, 3), (40, 4, 5)])
def test_select_pairs_gives_every_scan_k_partners_in_one_connected_graph(n, k, groups):
    scores = _random_scores(np.random.default_rng(n + k), n, groups)
    pairs = candidate_pairs.select_pairs(scores, k)
    assert all(0 <= i < j < n for i, j in pairs) and len(set(pairs)) == len(pairs) and pairs == sorted(pairs)
    partners = np.bincount(np.array(pairs).ravel(), minlength=n)
    assert partners.min() >= min(k, n - 1)
    assert _connected(n, pairs)  # the groups' best k stay inside each group: the spanning tree joins them
    assert len(pairs) <= n * k + n - 1
    assert candidate_pairs.select_pairs(scores.copy(), k) == pairs
    others = np.where(np.eye(n, dtype=bool), -np.inf, scores)
    best = {(min(i, int(j)), max(i, int(j))) for i in range(n) for j in np.argsort(-others[i])[:min(k, n - 1)]}
    assert best <= set(pairs)


def test_bridging_pairs_give_each_scan_outside_the_largest_group_its_next_partners_across_groups():
    scores = np.full((6, 6), 0.3)
    for (i, j), v in {(0, 3): .9, (3, 4): .8, (2, 3): .7, (1, 3): .1, (3, 5): .05, (4, 5): .6, (0, 4): .2,
                      (1, 4): .1, (2, 4): .05, (1, 5): .5, (0, 5): .1, (2, 5): .05}.items():
        scores[i, j] = scores[j, i] = v
    labels = [0, 0, 0, 1, 1, 2]  # group 0 the largest
    # scan 3: 0 tried, 4 in its own group, then 2; scan 4: 3 in its group, then 5; scan 5: 4 chosen already, then 1
    assert candidate_pairs.bridging_pairs(scores, labels, {(0, 3)}, 1) == [(1, 5), (2, 3), (4, 5)]
    assert candidate_pairs.bridging_pairs(scores, labels, set(), 1) == [(0, 3), (1, 5), (4, 5)]
    assert candidate_pairs.bridging_pairs(scores, [0] * 6, set(), 2) == []  # one group: nothing to bridge


def test_best_partners_rank_by_the_symmetric_score_never_the_scan_itself():
    scores = np.array([[9.0, 1.0, 3.0, 2.0],
                       [1.0, 9.0, 0.0, 5.0],
                       [1.0, 0.0, 9.0, 4.0],  # (0, 2) averages to 2: a tie with (0, 3), to the lower index
                       [2.0, 5.0, 4.0, 9.0]])
    partners = candidate_pairs.best_partners(scores, 2)
    assert partners(0) == [2, 3]
    assert partners(3) == [1, 2]
    assert candidate_pairs.best_partners(scores, 5)(1) == [3, 0, 2]


def test_select_pairs_refuses_bad_input():
    for scores, k in [(np.ones((3, 2)), 2), (np.ones((1, 1)), 1), (np.full((3, 3), np.nan), 1), (np.ones((3, 3)), 0),
                      (np.ones((3, 3)), 1.5)]:
        with pytest.raises(ValueError):
            candidate_pairs.select_pairs(scores, k)


def _station_views(num_views=8, stations=8, per_station=600, seed=0):
    """``num_views`` scans of a ring of ``stations`` different synthetic shapes (0.35 across, on a unit circle),
    each keeping the stations on one side of a line at 360°/num_views further round (about half of them), in a
    random frame: neighbouring views share most stations, views more than 90° apart share none. The analytic
    normals are jittered (1e-3): exactly opposite normals put the SPFH angle α at ±π, bin 0 or 10 by rounding."""
    rng = np.random.default_rng(seed)
    parts = []
    for s in range(stations):
        angle = 2 * np.pi * s / stations
        shape = synthetic.sample_shape(rng, 3 * s % 40, per_station).astype(np.float64)
        parts.append(np.concatenate([0.35 * shape[:, :3] + [np.cos(angle), np.sin(angle), 0.0], shape[:, 3:]], 1))
    world = np.concatenate(parts)
    world[:, 3:] += rng.normal(scale=1e-3, size=(len(world), 3))
    world[:, 3:] /= np.linalg.norm(world[:, 3:], axis=1, keepdims=True)
    scans = []
    for v in range(num_views):
        angle = 2 * np.pi * v / num_views
        seen = world[world[:, :2] @ [np.cos(angle), np.sin(angle)] > 0.2]
        pose = random_pose(rng)
        scans.append(edges.make_scan(seen[:, :3] @ pose[:3, :3].T + pose[:3, 3], seen[:, 3:] @ pose[:3, :3].T))
    return scans


def test_overlap_scores_rank_neighbouring_views_above_far_ones():
    scans = _station_views()
    scores = candidate_pairs.overlap_scores(scans)
    n = len(scans)
    assert scores.shape == (n, n) and np.allclose(scores, scores.T) and np.allclose(np.diag(scores), 1.0)
    assert np.all((scores >= 0) & (scores <= 1 + 1e-12))
    for i in range(n):  # measured margins 0.30-0.39 (0.20-0.36 on seeds 1, 2)
        near = min(scores[i, (i - 1) % n], scores[i, (i + 1) % n])
        far = max(scores[i, (i + d) % n] for d in (3, 4, 5))  # 135-225° away: no station in common
        assert near > far + 0.1, (i, near, far)
    pairs = candidate_pairs.select_pairs(scores, 2)
    assert {(i, (i + 1) % n) if i + 1 < n else (0, i) for i in range(n)} <= set(pairs)


def test_overlap_scores_ignore_a_scans_orientation():
    scans = _station_views(num_views=6, per_station=400, seed=1)
    before = candidate_pairs.overlap_scores(scans, seed=3)
    assert np.array_equal(candidate_pairs.overlap_scores(scans, seed=3), before)  # deterministic
    motion = random_pose(np.random.default_rng(7), trans=5.0)
    turned = list(scans)
    rot = motion[:3, :3]
    turned[2] = edges.make_scan(scans[2].points @ rot.T + motion[:3, 3], scans[2].normals @ rot.T)
    np.testing.assert_allclose(candidate_pairs.overlap_scores(turned, seed=3), before, atol=1e-9)


def test_bunny_scan_bun000_scores_its_true_neighbours_best():
    """The ten real bunny scans prepared as ``align_scans`` prepares them: bun000's two best-scored partners are
    bun045 and bun315 (45° either side; true overlaps 92% and 86%, the two largest; the same for seeds 0-3)."""
    require(BUNNY / "bun.conf", "Stanford bunny scans")
    names = list(scan_poses.read_poses(str(BUNNY / "bun.conf")))
    clouds = [cloud_io.read_cloud(str(BUNNY / f"{n}.ply"))[0] for n in names]
    scans, _ = preparation.prepare_scans(clouds, None, None)[:2]
    scores = candidate_pairs.overlap_scores(scans)
    first = names.index("bun000")
    ranked = [names[j] for j in np.argsort(-scores[first]) if j != first]
    assert set(ranked[:2]) == {"bun045", "bun315"}, ranked
    pairs = candidate_pairs.select_pairs(scores, 2)
    assert _connected(len(names), pairs) and len(pairs) <= 2 * len(names) + len(names) - 1
