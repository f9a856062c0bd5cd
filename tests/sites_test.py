"""The simulated site: rays stop at the first surface of each kind of solid; a station's points, moved by its true
pose, lie on the town's surfaces; stations stand in free space along connected streets; a campaign is the same
from the same seed; the CLI writes a shuffled set with its truth and refuses bad input."""

import json
import os

import numpy as np
import pytest
from scipy.sparse import csgraph, csr_matrix
from scipy.spatial import cKDTree

from rpmnet_jax.simulation import sites
from rpmnet_jax.io import poses as poses_io

FLAT = np.zeros(2)


def _town(boxes=(), cylinders=(), balls=()):
    return sites.Town(np.array(boxes, np.float64).reshape(-1, 6), np.array(cylinders, np.float64).reshape(-1, 5),
                      np.array(balls, np.float64).reshape(-1, 4), np.zeros((1, 2)), (10.0, 10.0))


def _cast(town, origin, direction, slope=FLAT, max_range=60.0):
    d = np.asarray(direction, np.float64)
    d = (d / np.linalg.norm(d))[None]
    return sites._first_hits(np.asarray(origin, np.float64), d, town.boxes, town.cylinders, town.balls,
                             np.asarray(slope, np.float64), max_range)[0]


@pytest.mark.parametrize("origin, direction, distance", [
    ((0.0, 0.0, 1.6), (0, 0, -1), 1.6),  # the flat ground
    ((0.0, 0.0, 1.6), (1, 0, 0), 4.0),  # the box's face at x = 4
    ((0.0, 0.0, 1.6), (0, 1, 0), 2.8),  # the cylinder's side at y = 3 - 0.2
    ((0.0, -4.0, 5.0), (0, 0, -1), 1.0),  # the cylinder's top at z = 4 (the ray at its axis, x = 0, y = -4)
    ((0.0, 0.0, 1.6), (-1, 0, 0), 5.0),  # the ball's near side at x = -6 + 1
    ((0.0, 0.0, 1.6), (0, -1, 1), np.inf),  # over everything: nothing within range
])
def test_a_ray_stops_at_the_first_surface(origin, direction, distance):
    town = _town(boxes=[(4.0, -1.0, 0.0, 6.0, 1.0, 3.0)], balls=[(-6.0, 0.0, 1.6, 1.0)],
                 cylinders=[(0.0, 3.0, 0.2, 0.0, 3.0), (0.0, -4.0, 0.5, 0.0, 4.0)])
    assert _cast(town, origin, direction) == pytest.approx(distance, abs=1e-9)


def test_the_nearest_of_two_solids_and_the_sloping_ground():
    town = _town(boxes=[(8.0, -1.0, 0.0, 9.0, 1.0, 3.0)], balls=[(5.0, 0.0, 1.6, 1.0)])
    assert _cast(town, (0.0, 0.0, 1.6), (1, 0, 0)) == pytest.approx(4.0, abs=1e-9)  # the ball hides the box
    # ground z = 0.1 x: straight down from (10, 0, 3) it is 2 below
    assert _cast(_town(), (10.0, 0.0, 3.0), (0, 0, -1), slope=(0.1, 0.0)) == pytest.approx(2.0, abs=1e-9)
    assert _cast(_town(), (0.0, 0.0, 1.6), (0, 0, -1), max_range=1.0) == np.inf  # beyond range: no return


def _distance_to_town(town, xyz):
    """``(N,)`` unsigned distance of ``xyz (N, 3)`` to the nearest surface of the town (the union of its solids and
    the ground), from each solid's signed distance (a separate computation from the ray caster's)."""
    slope = np.array(sites.SLOPE)
    best = (xyz[:, 2] - xyz[:, :2] @ slope) / np.sqrt(1 + slope @ slope)
    for lo_hi in town.boxes:
        q = np.maximum(lo_hi[:3] - xyz, xyz - lo_hi[3:])
        best = np.minimum(best, np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0))
    for cx, cy, r, z0, z1 in town.cylinders:
        q = np.stack([np.hypot(xyz[:, 0] - cx, xyz[:, 1] - cy) - r, np.maximum(z0 - xyz[:, 2], xyz[:, 2] - z1)], 1)
        best = np.minimum(best, np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0))
    for c in town.balls:
        best = np.minimum(best, np.linalg.norm(xyz - c[:3], axis=1) - c[3])
    return np.abs(best)


def test_a_station_s_points_lie_on_the_town_s_surfaces_and_each_kind_of_solid_is_seen():
    town, stations = sites.stations(12, seed=3, step_deg=1.0)
    s = stations[7]
    site = s.points @ s.pose[:3, :3].T + s.pose[:3, 3]
    assert len(s.points) > 5000
    assert np.all(_distance_to_town(town, site) < 6 * sites.NOISE)
    assert np.all(np.linalg.norm(s.points, axis=1) < sites.MAX_RANGE + 6 * sites.NOISE)
    # levelled: heights in the station's frame are heights above the sensor; turned about the vertical
    np.testing.assert_allclose(s.points[:, 2], site[:, 2] - s.pose[2, 3], atol=1e-9)
    np.testing.assert_allclose(s.pose[2, 3], sites.ground(s.pose[:2, 3]) + sites.SENSOR_HEIGHT)
    seen = {kind: 0 for kind in ("boxes", "cylinders", "balls")}
    for kind in seen:
        only = town._replace(**{k: getattr(town, k)[:0] for k in seen if k != kind})
        ground = np.abs(site[:, 2] - sites.ground(site[:, :2])) < 6 * sites.NOISE
        seen[kind] = int(np.sum((_distance_to_town(only, site) < 6 * sites.NOISE) & ~ground))
    assert min(seen.values()) > 20, seen


def test_stations_stand_in_free_space_along_connected_streets():
    for num in (10, 100, 1000):
        town = sites.town(num, seed=0)
        slots = town.slots[:num]
        assert len(town.slots) >= num
        jittered = (slots[:, None, :] + np.array([[dx, dy] for dx in (-1, 0, 1) for dy in (-1, 0, 1)])).reshape(-1, 2)
        sensors = np.column_stack([jittered, sites.ground(jittered) + sites.SENSOR_HEIGHT])
        clear = _distance_to_town(town, sensors)
        assert clear.min() > 0.5  # every station, anywhere within its jitter, at least 0.5 m from any solid
        pairs = cKDTree(slots).query_pairs(sites.SPACING + 1e-6, output_type="ndarray")
        graph = csr_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(num, num))
        assert csgraph.connected_components(graph, directed=False)[0] == 1
    assert sites.town(1000).size[0] >= 100.0 and sites.blocks_for(10) < sites.blocks_for(100) < sites.blocks_for(1000)


def test_the_same_seed_gives_the_same_campaign():
    a = sites.stations(3, seed=5, step_deg=3.0)[1]
    b = sites.stations(3, seed=5, step_deg=3.0)[1]
    c = sites.stations(3, seed=6, step_deg=3.0)[1]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.points, y.points)
        np.testing.assert_array_equal(x.pose, y.pose)
    assert not np.array_equal(a[0].pose, c[0].pose)
    with pytest.raises(ValueError, match="num_stations"):
        sites.stations(0)


def test_make_site_writes_a_shuffled_set_with_its_truth(tmp_path, capsys):
    from experiments import make_site

    out = tmp_path / "site"
    assert make_site.main(["--stations", "4", "--step", "4", "--seed", "2", "--shuffle", "--out", str(out)]) == 0
    settings = json.loads((out / "settings.json").read_text())
    truth = poses_io.read_poses(str(out / "truth.conf"))
    _, stations = sites.stations(4, seed=2, step_deg=4.0)
    assert sorted(truth) == settings["files"] == [f"scan{k:03d}" for k in range(4)]
    assert sorted(settings["simulated_index"]) == [0, 1, 2, 3] and settings["simulated_index"] != [0, 1, 2, 3]
    for name, index in zip(settings["files"], settings["simulated_index"]):
        np.testing.assert_allclose(truth[name], stations[index].pose, atol=1e-9)
    assert "wrote 4 stations" in capsys.readouterr().out
    for bad in (["--stations", "0"], ["--step", "0"]):
        with pytest.raises(SystemExit) as e:
            make_site.main([*bad, "--out", str(tmp_path / "never")])
        assert e.value.code == 2
    assert not os.path.exists(tmp_path / "never")


@pytest.mark.slow  # two runs of align_scans on ten 60k-point stations: about 90 s
def test_a_street_campaign_places_no_station_wrong_without_naming_it():
    """The first 10 stations of the site (seed 0): with the balance bar (the default) every station placed is
    within 0.1 deg and 5 cm of the truth, or named; without it (``min_balanced_fitness=0``) the ground carries
    wrong pair edges and a station is placed more than 1 deg or 1 m off (measured: one a quarter turn off, one slid
    11 m along its street; both without a name before placements were checked against the free space)."""
    import rpmnet_jax
    from conftest import rotation_error_deg

    _, stations = sites.stations(10, seed=0)
    clouds, truth = [s.points for s in stations], np.stack([s.pose for s in stations])

    def placed_errors(options):
        """``[(rotation deg, shift m, named)]`` of every placed station but the first."""
        result = rpmnet_jax.align_scans(clouds, options=options)
        out = []
        for s in range(1, len(clouds)):
            if np.isfinite(result.poses[s, 0, 0]):
                rel = np.linalg.inv(truth[0]) @ truth[s]
                out.append((rotation_error_deg(result.poses[s, :3, :3], rel[:3, :3]),
                            float(np.linalg.norm(result.poses[s, :3, 3] - rel[:3, 3])), s in result.likely_wrong))
        return out

    barred = [(rot, shift) for rot, shift, named in placed_errors(rpmnet_jax.ScanOptions()) if not named]
    print(f"placed and not named, with the bar: {barred}")
    assert len(barred) >= 6 and all(rot < 0.1 and shift < 0.05 for rot, shift in barred), barred
    free = placed_errors(rpmnet_jax.ScanOptions(min_balanced_fitness=0.0))
    print(f"without: {free}")
    assert any(rot > 1.0 or shift > 1.0 for rot, shift, _ in free), free


@pytest.mark.slow  # two runs of align_scans on ten 60k-point stations: about 30 s
def test_two_look_alike_streets_from_a_corner_are_not_folded_onto_one(monkeypatch):
    """The first 10 stations of seed 7 walk two perpendicular streets from their corner, and the streets look alike:
    a station of one matches a station of the other a quarter turn off. The seven such pair edges that the graph
    kept at 4% (the bar before) put 1.6-3.9% of a scan in the other's free space, and it folded one street onto the
    other: every station more than 1 deg off after a fit to the truth, eight not named. At 1.5% those edges fail the
    check (right answers measured at most 0.1% here): all ten stations are placed, each right or named."""
    import rpmnet_jax
    from rpmnet_jax.geometry import visibility
    from conftest import rotation_error_deg

    _, stations = sites.stations(10, seed=7)
    clouds, truth = [s.points for s in stations], np.stack([s.pose for s in stations])

    def wrong_and_unnamed():
        """Stations placed more than 1 deg or 1 m off relative to the first, with no name; the stations left out."""
        result = rpmnet_jax.align_scans(clouds, viewpoints=[np.zeros(3)] * len(clouds))
        bad = []
        for s in range(1, len(clouds)):
            if np.isfinite(result.poses[s, 0, 0]) and s not in result.likely_wrong:
                rel = np.linalg.inv(truth[0]) @ truth[s]
                if (rotation_error_deg(result.poses[s, :3, :3], rel[:3, :3]) > 1.0
                        or np.linalg.norm(result.poses[s, :3, 3] - rel[:3, 3]) > 1.0):
                    bad.append(s)
        return bad, result.left_out

    assert wrong_and_unnamed() == ([], ())
    monkeypatch.setattr(visibility, "MAX_FREE_SPACE_SHARE", 0.04)
    assert wrong_and_unnamed()[0]


def test_a_station_the_graph_left_a_metre_off_is_refined_in_at_a_finer_voxel(monkeypatch):
    """With ``refine_voxel_size`` the refinement runs at the registration's voxel first: the finer correspondence
    distance alone cannot reach a station the graph left a metre off (seed 2's 300 stations: three stayed 1.82 m
    off, unnamed). One of three stations is moved 1 m along x before the refinement; it ends within 1 cm."""
    import rpmnet_jax
    from rpmnet_jax.multiway import scan_alignment

    _, stations = sites.stations(3, seed=3, step_deg=1.0)
    clouds, truth = [s.points for s in stations], np.stack([s.pose for s in stations])
    place_others = scan_alignment._place_others

    def moved(run):
        place_others(run)
        run.poses[2, 0, 3] += 1.0

    monkeypatch.setattr(scan_alignment, "_place_others", moved)
    result = rpmnet_jax.align_scans(clouds, viewpoints=[np.zeros(3)] * 3,
                                    options=rpmnet_jax.ScanOptions(refine_voxel_size=0.1))
    rel = np.linalg.inv(truth[0]) @ truth[2]
    assert np.linalg.norm(result.poses[2, :3, 3] - rel[:3, 3]) < 0.01
