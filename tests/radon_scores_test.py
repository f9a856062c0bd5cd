"""The footprint's sinogram score: the same for a scan turned about the vertical, high for neighbouring stations of a
simulated site and lower for stations far apart; the ground left out; used by the scan sets only for a levelled
scene's scans; bad input refused."""

import numpy as np
import pytest

from rpmnet_jax.geometry import packed_normals
from rpmnet_jax.multiway import preparation, radon_scores
from rpmnet_jax.simulation import sites


class _Scan:
    def __init__(self, points, normals):
        self.points, self.normals = points, normals


@pytest.fixture(scope="module")
def site():
    """12 stations of the site (a coarse 1.2° scanner), prepared as ``align_scans`` prepares them."""
    _, stations = sites.stations(12, seed=0, step_deg=1.2)
    prepared = preparation.prepare_scans([s.points for s in stations], None, None, np.zeros(3),
                                         [np.zeros(3)] * 12, features=False)
    return prepared, np.stack([s.pose for s in stations])


def _turned(scan, degrees):
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return _Scan(scan.points @ rotation.T, packed_normals.unit(scan.normals) @ rotation.T)


def test_a_turn_about_the_vertical_keeps_the_score(site):
    prepared, _ = site
    scan = prepared.scans[0]
    scans = [scan, _turned(scan, 37.0), _turned(scan, 181.0)] + list(prepared.scans[1:])
    scores = radon_scores.overlap_scores(scans, [np.zeros(3)] * len(scans), prepared.voxel)
    assert scores[0, 1] > 0.95 and scores[0, 2] > 0.95  # 1 but for the grid's cells
    assert min(scores[0, 1], scores[0, 2]) > scores[0, 3:].max()  # above every other station
    np.testing.assert_allclose(scores, scores.T)


def test_neighbouring_stations_score_above_far_ones(site):
    prepared, truth = site
    scores = radon_scores.overlap_scores(prepared.scans, prepared.sensors, prepared.voxel)
    positions = truth[:, :3, 3]
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=-1)
    near = (distance < 12.0) & ~np.eye(12, dtype=bool)
    far = distance > 40.0
    assert near.any() and far.any()
    assert np.median(scores[near]) > np.percentile(scores[far], 90)


def test_the_ground_under_the_sensor_is_found():
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-10, 10, (2000, 2)), np.full(2000, -1.6)])
    wall = np.column_stack([np.full(500, 5.0), rng.uniform(-5, 5, 500), rng.uniform(-1.6, 6.0, 500)])
    points = np.concatenate([ground, wall])
    normals = np.concatenate([np.tile([0.0, 0.0, 1.0], (2000, 1)), np.tile([-1.0, 0.0, 0.0], (500, 1))])
    assert radon_scores.ground_height(points, normals, 8.0) == pytest.approx(-1.6)
    # the ground's cells are left out: the same wall over another ground gives the same descriptor
    other = np.concatenate([ground[::2], wall])
    other_normals = np.concatenate([normals[:2000:2], normals[2000:]])
    np.testing.assert_allclose(radon_scores.descriptor(points, normals, 0.5, 9.0),
                               radon_scores.descriptor(other, other_normals, 0.5, 9.0))


def test_only_a_levelled_scene_uses_it(site):
    prepared, _ = site
    assert preparation.levelled(prepared) is not None
    on_its_side = prepared._replace(scans=[_Scan(s.points[:, [2, 0, 1]],
                                                 packed_normals.unit(s.normals)[:, [2, 0, 1]])
                                           for s in prepared.scans])
    assert preparation.levelled(on_its_side) is None
    assert preparation.levelled(prepared._replace(sensors=[None] * 12)) is None
    assert preparation.levelled(prepared._replace(scene=False)) is None


def test_bad_input_is_refused(site):
    prepared, _ = site
    with pytest.raises(ValueError, match="at least two scans"):
        radon_scores.overlap_scores(prepared.scans[:1], prepared.sensors[:1], prepared.voxel)
    with pytest.raises(ValueError, match="sensor"):
        radon_scores.overlap_scores(prepared.scans[:2], [None, np.zeros(3)], prepared.voxel)


def _town(seed, size=50.0):
    """Points and normals of a flat ground (z = -1.6) and 12 box-shaped buildings' walls around the origin."""
    rng = np.random.default_rng(seed)
    ground = np.column_stack([rng.uniform(-size, size, (20000, 2)), np.full(20000, -1.6)])
    points, normals = [ground], [np.tile([0.0, 0.0, 1.0], (20000, 1))]
    for _ in range(12):
        (x0, y0), (w, d) = rng.uniform(-size, size - 15.0, 2), rng.uniform(4.0, 15.0, 2)
        for start, along, normal in (((x0, y0), (w, 0), (0, -1)), ((x0, y0 + d), (w, 0), (0, 1)),
                                     ((x0, y0), (0, d), (-1, 0)), ((x0 + w, y0), (0, d), (1, 0))):
            t, z = rng.uniform(0, 1, 600), rng.uniform(-1.6, 6.0, 600)
            points.append(np.column_stack([start[0] + t * along[0], start[1] + t * along[1], z]))
            normals.append(np.tile([normal[0], normal[1], 0.0], (600, 1)))
    return np.concatenate(points), np.concatenate(normals)


def _seen_from(town, x, y, degrees):
    """The town's points within 45 m of a sensor at (x, y), in that sensor's frame turned by ``degrees``."""
    points, normals = town
    keep = np.hypot(points[:, 0] - x, points[:, 1] - y) < 45.0
    return _turned(_Scan(points[keep] - np.array([x, y, 0.0]), normals[keep]), degrees)


def test_aligned_footprints_find_one_town_seen_from_elsewhere_turned_any_way():
    town, other = _town(1), _town(2)
    for degrees in (37.0, 181.0, 250.0):  # the sinogram spans half a turn: 181 and 250 need the other half
        scans = [_seen_from(town, 0.0, 0.0, 0.0), _seen_from(town, 6.0, -4.0, degrees),
                 _seen_from(other, 0.0, 0.0, 0.0), _seen_from(other, 6.0, -4.0, degrees)]
        footprints = radon_scores.Footprints(scans, [np.zeros(3)] * 4, 0.5)
        same, others = footprints.aligned(0, [1]), footprints.aligned(0, [2, 3])
        assert same[0] > 0.4 and same[0] > 1.8 * others.max()  # 0.46-0.6 against at most 0.26
        assert footprints.aligned(1, [0, 2, 3]).argmax() == 0


def test_aligned_footprints_rank_a_stations_nearest_neighbour_among_its_two_first(site):
    prepared, truth = site
    footprints = radon_scores.Footprints(prepared.scans, prepared.sensors, prepared.voxel)
    positions = truth[:, :3, 3]
    distance = np.linalg.norm(positions[:, None] - positions[None], axis=-1) + np.diag(np.full(12, np.inf))
    others = [np.delete(np.arange(12), i) for i in range(12)]
    ranks = [int(np.flatnonzero(o[np.argsort(-footprints.aligned(i, o))] == np.argmin(distance[i]))[0])
             for i, o in enumerate(others)]
    assert max(ranks) <= 1  # along a street the nearest and the next on the other side overlap alike
    np.testing.assert_array_equal(footprints.scores, radon_scores.overlap_scores(prepared.scans, prepared.sensors,
                                                                                 prepared.voxel))


def test_ranked_orders_each_scans_best_by_aligned_footprints_and_the_rest_by_the_sinograms(site):
    prepared, _ = site
    footprints = radon_scores.Footprints(prepared.scans, prepared.sensors, prepared.voxel)
    ranked = footprints.ranked(3)
    np.testing.assert_array_equal(ranked, ranked.T)
    scores = footprints.scores - np.diag(np.full(12, np.inf))
    best = [set(np.argsort(-scores[i], kind="stable")[:3]) for i in range(12)]
    for i in range(12):
        firsts = set(np.flatnonzero(ranked[i] >= 1.0)) - {i}
        assert firsts == best[i] | {j for j in range(12) if i in best[j]}  # its 3 best, and those it is best of
        for j in firsts:
            ways = [footprints.aligned(a, [b])[0] for a, b in ((i, j), (j, i)) if b in best[a]]
            assert ranked[i, j] == pytest.approx(1.0 + max(ways))
        rest = np.setdiff1d(np.arange(12), list(firsts | {i}))
        np.testing.assert_array_equal(ranked[i, rest], footprints.scores[i, rest])
