"""``align_scans``: real bunny scans into one frame, the pair edges alone (``refine="none"``), each scan's size
from its robust radius, bad options, a placement flagged likely wrong, a planted flip kept out of the graph, the scans
resting on doubtful edges reported, a symmetric ring kept off its flips by the edges' doubt."""

import numpy as np
import pytest

import rpmnet_jax
from conftest import DATA, cropped_pair, require, ring_scans, rotation_about, rotation_error_deg, synthetic_scans
from rpmnet_jax.evaluation import pose_errors
from rpmnet_jax.geometry import cloud
from rpmnet_jax.io import clouds as cloud_io
from rpmnet_jax.io import poses as scan_poses
from rpmnet_jax.multiway import edge_doubt, edge_graph, placement, preparation, refinement, sizes
from rpmnet_jax.pair_edges import edges as edges_lib
from rpmnet_jax.pose_graphs import joint_refine

BUNNY = DATA / "stanford_bunny"


@pytest.fixture(scope="module")
def bunny():
    require(BUNNY / "bun.conf", "Stanford bunny scans")
    return scan_poses.read_poses(str(BUNNY / "bun.conf"))


def _read(names):
    return [cloud_io.read_cloud(str(BUNNY / f"{n}.ply"))[0] for n in names]


def test_align_scans_four_bunny_scans(bunny):
    names = ["bun000", "bun045", "bun315", "chin"]
    clouds = _read(names)
    reports = []
    result = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(voxel_size=0.003),
                                    progress=lambda *report: reports.append(report))
    truth = np.stack([bunny[n] for n in names])
    assert result.pairs["classical"] == 6 and 3 <= result.pairs["refine"] <= 6 and "network" not in result.pairs
    assert [r for r in reports if r[0] == "joint refinement stages"] == [("joint refinement stages", k, 3)
                                                                        for k in (1, 2, 3)]
    errors = pose_errors.pose_errors(result.poses, truth, clouds)
    print(dict(zip(names, errors)))
    np.testing.assert_allclose(result.poses[0], np.eye(4), atol=1e-9)
    assert all(rot < 1.0 and rms < 2e-3 for rot, rms in errors), errors  # measured 0.16° and 0.3 mm
    assert result.left_out == () and result.voxel_size == 0.003
    assert len(result.edges) >= 3 and {e.stage for e in result.edges} == {"joint"}
    ran = [k for k in result.timings if k != "total"]  # the stages that ran, in the pipeline's order
    assert ran == [s for s in ("prepare", "candidates", "classical", "network", "graph", "global", "refine") if s in ran]
    assert {"prepare", "classical", "refine"} <= set(ran) and list(result.timings)[-1] == "total"
    for e in result.edges:
        assert e.information.shape == (6, 6) and 0 < e.fitness <= 1 and e.inlier_rmse > 0
        assert np.all(np.linalg.eigvalsh(0.5 * (e.information + e.information.T)) > 0)


@pytest.mark.parametrize("classical", [True, False])
def test_align_scans_without_refinement_keeps_the_pair_edges(classical):
    clouds, poses = synthetic_scans()
    reports = []
    result = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(refine="none", classical=classical),
                                    progress=lambda *report: reports.append(report))
    errors = pose_errors.pose_errors(result.poses, poses, clouds)
    print(errors)
    assert all(rot < 2.0 for rot, _ in errors), errors  # a pair method and a short ICP: measured 0.006°
    stage = "classical" if classical else "network"
    assert result.edges and {e.stage for e in result.edges} == {stage} and "refine" not in result.timings
    assert ("network" in result.timings) == (not classical)  # the classical edges connect the three scans
    assert reports == [(s, k, 3) for s in ("preparing scans", f"{stage} edges") for k in (1, 2, 3)]  # three scans,
    # then their three candidate pairs, in turn
    with pytest.raises(ValueError, match="at least two scans"):
        rpmnet_jax.align_scans(clouds[:1])


def test_beyond_all_pairs_the_file_order_does_not_matter():
    clouds, truth = ring_scans(8, asymmetric=True)  # a shape a 180° turn maps onto itself needs more pairs
    options = rpmnet_jax.ScanOptions(all_pairs_up_to=4, neighbours=2)  # candidate pairs by the overlap estimate
    order = [5, 2, 7, 0, 3, 6, 1, 4]  # neighbours on the ring are never neighbours in the list
    results = [rpmnet_jax.align_scans([clouds[k] for k in o], options=options) for o in (range(8), order)]
    for o, result in zip((list(range(8)), order), results):
        errors = pose_errors.pose_errors(result.poses, truth[o], [clouds[k] for k in o])
        assert all(rot < 0.5 and rms < 5e-4 for rot, rms in errors), errors
        assert "candidates" in result.timings and result.left_out == ()
        assert len({(e.source, e.target) for e in result.edges}) < 28  # not every pair


def test_bad_options_are_a_value_error():
    clouds, _ = synthetic_scans()
    with pytest.raises(ValueError, match="ScanOptions"):
        rpmnet_jax.align_scans(clouds, options="x")
    with pytest.raises(ValueError, match="ScanOptions.refine"):
        rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(refine="bad"))
    with pytest.raises(ValueError, match="ScanOptions.edge_doubt"):
        rpmnet_jax.ScanOptions(edge_doubt="screen")


def test_a_stray_point_does_not_change_a_scan_s_size():
    """The default voxel and correspondence distance follow the median robust radius of the scans: one point
    100 radii away leaves them as they are."""
    clouds, _ = synthetic_scans()
    voxel = preparation.prepare_scans(clouds, None, None).voxel
    radius = float(np.median([cloud.robust_radius(c) for c in clouds]))
    stray = clouds[1].mean(0) + 100 * np.ptp(clouds[1], axis=0)
    dirty = [clouds[0], np.concatenate([clouds[1], stray[None]]), clouds[2]]
    dirty_voxel = preparation.prepare_scans(dirty, None, None).voxel
    assert dirty_voxel == voxel
    assert voxel == pytest.approx(sizes.OBJECT_RELATIVE_VOXEL * radius)


@pytest.mark.slow
def test_align_scans_all_bunny_scans_within_half_a_degree(bunny):
    names = list(bunny)
    clouds = _read(names)
    result = rpmnet_jax.align_scans(clouds)
    errors = pose_errors.pose_errors(result.poses, np.stack([bunny[n] for n in names]), clouds)
    print(dict(zip(names, errors)))
    # measured up to 0.38° and 0.5 mm over the ten scans
    assert all(rot <= 0.5 and rms <= 1e-3 for rot, rms in errors), dict(zip(names, errors))


def test_a_placement_flagged_likely_wrong_is_reported(monkeypatch):
    """Step 4 reports the scans whose ``align`` answer was ``likely_wrong`` (and places them all the same)."""
    import types

    clouds, _ = synthetic_scans()
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    poses = np.full((len(scans), 4, 4), np.nan)
    poses[0] = np.eye(4)
    flags = iter([True, False])
    monkeypatch.setattr(placement.alignment, "align", lambda *a, **k: types.SimpleNamespace(
        transform=np.eye(4), fitness=1.0, correspondences=np.zeros((0, 2), int), likely_wrong=next(flags)))
    singles = [placement.Group((s,), np.eye(4)[None]) for s in range(1, len(scans))]
    poses, edges, pending, doubtful = placement.place_remaining(
        scans, poses, singles, None, None, voxel, sizes.DISTANCE_VOXELS * voxel, lambda fitness, residual, balanced: True, 0,
        lambda *_: None)
    assert pending == [] and doubtful == [1] and np.isfinite(poses).all()


def _place_second_room_station(monkeypatch, turned: bool, doubted: bool, place_doubtful: bool) -> tuple:
    """Step 4 with the free-space check on a room's first two stations: station 1 registered onto the placed
    station 0 at the truth, or a half turn off (``turned``: its walls and furniture where station 0 saw through),
    with ``align``'s ``likely_wrong`` = ``doubted``. Returns (poses, pending, doubtful)."""
    import types
    from rpmnet_jax.simulation import rooms

    stations = rooms.stations(0)[:2]
    prepared = preparation.prepare_scans([st.points for st in stations], None, None, viewpoints="origin")
    visible = edge_graph.FreeSpace([s.points for s in prepared.scans], prepared.sensors, prepared.voxel)
    answer = np.linalg.inv(stations[0].pose) @ stations[1].pose
    if turned:
        turn = np.eye(4)
        turn[:3, :3] = rotation_about([0.0, 0.0, 1.0], 180.0)
        answer = answer @ turn
    monkeypatch.setattr(placement.alignment, "align", lambda *a, **k: types.SimpleNamespace(
        transform=answer, fitness=1.0, correspondences=np.zeros((0, 2), int), likely_wrong=doubted))
    poses = np.full((2, 4, 4), np.nan)
    poses[0] = np.eye(4)
    poses, _, pending, doubtful = placement.place_remaining(
        prepared.scans, poses, [placement.Group((1,), np.eye(4)[None])], None, None, prepared.voxel,
        sizes.DISTANCE_VOXELS * prepared.voxel, lambda fitness, residual, balanced: True, 0, lambda *_: None,
        visible=visible, place_doubtful=place_doubtful)
    return poses, pending, doubtful


def test_a_placement_in_another_scan_s_free_space_is_named(monkeypatch):
    """Step 4 with the free-space check: a room station registered onto the placed one a half turn off is placed
    but named; registered right, it is not named."""
    for turned, named in ((True, [1]), (False, [])):
        poses, pending, doubtful = _place_second_room_station(monkeypatch, turned, False, True)
        assert pending == [] and np.isfinite(poses[1]).all() and doubtful == named


def test_a_campaign_leaves_out_a_scan_whose_only_answers_are_doubtful(monkeypatch):
    """Step 4 with ``place_doubtful=False`` (a levelled scene's campaign): a room station registered a half turn off
    (in the placed station's free space), or with an answer ``align`` calls likely wrong, stays pending; the right
    answer, not doubted, places it, unnamed."""
    for turned, doubted, placed in ((True, False, False), (False, True, False), (False, False, True)):
        poses, pending, doubtful = _place_second_room_station(monkeypatch, turned, doubted, False)
        assert doubtful == [] and pending == ([] if placed else [1])
        assert np.isfinite(poses[1]).all() == placed


def test_a_group_moves_as_one_and_is_not_placed_in_free_space(monkeypatch):
    """Step 4 places a group of scans as one: stations 1 and 2 of a room, joined by their edge, placed onto station
    0. The first member registered a half turn off would put the group where station 0 saw through: refused, and
    the next member's right answer places both, each at its true pose; the group's own edge joins the edges."""
    import types
    from rpmnet_jax.simulation import rooms

    stations = rooms.stations(0)[:3]
    prepared = preparation.prepare_scans([st.points for st in stations], None, None, viewpoints="origin")
    visible = edge_graph.FreeSpace([s.points for s in prepared.scans], prepared.sensors, prepared.voxel)
    truth = [np.linalg.inv(stations[0].pose) @ st.pose for st in stations]
    turn = np.eye(4)
    turn[:3, :3] = rotation_about([0.0, 0.0, 1.0], 180.0)
    joined = edges_lib.measure(prepared.scans, 2, 1, np.linalg.inv(truth[1]) @ truth[2], 0.1, "classical")
    group = placement.Group((1, 2), np.stack([np.eye(4), np.linalg.inv(truth[1]) @ truth[2]]), (joined,))
    answers = iter([truth[1] @ turn, truth[2]])  # member 1 a half turn off, then member 2 right
    monkeypatch.setattr(placement.alignment, "align", lambda *a, **k: types.SimpleNamespace(
        transform=next(answers), fitness=1.0, correspondences=np.zeros((0, 2), int), likely_wrong=False))
    poses = np.full((3, 4, 4), np.nan)
    poses[0] = np.eye(4)
    poses, edges, pending, doubtful = placement.place_remaining(
        prepared.scans, poses, [group], None, None, prepared.voxel, sizes.DISTANCE_VOXELS * prepared.voxel,
        lambda fitness, residual, balanced: True, 0, lambda *_: None, visible=visible)
    assert pending == [] and doubtful == [] and joined in edges
    for s in (1, 2):
        np.testing.assert_allclose(poses[s], truth[s], atol=1e-9)


def _identity_align(monkeypatch) -> list:
    """Step 4's ``align`` replaced by one that answers the identity, fitness 1: the sizes of the models it was given,
    in call order (the list returned)."""
    import types

    sizes_seen = []

    def align(src, model, *a, **k):
        sizes_seen.append(len(model))
        return types.SimpleNamespace(transform=np.eye(4), fitness=1.0, correspondences=np.zeros((0, 2), int),
                                     likely_wrong=False)

    monkeypatch.setattr(placement.alignment, "align", align)
    return sizes_seen


def test_a_campaign_places_each_scan_onto_its_placed_partners_only(monkeypatch):
    """Step 4 with ``partners``: a scan is registered onto its placed partners merged (not every placed scan), a
    scan without a placed partner waits for a later round, and a group is tried from at most ``max_tries``
    members a round."""
    clouds, _ = synthetic_scans()
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]  # three scans
    calls = _identity_align(monkeypatch)
    poses = np.full((3, 4, 4), np.nan)
    poses[0] = np.eye(4)
    partners = {1: [0], 2: [1]}.get  # a chain: scan 2's partner is placed only once scan 1 is
    singles = [placement.Group((s,), np.eye(4)[None]) for s in (2, 1)]
    poses, edges, pending, doubtful = placement.place_remaining(
        scans, poses, singles, None, None, voxel, sizes.DISTANCE_VOXELS * voxel, lambda *_: True, 0,
        lambda *_: None, partners=partners, max_tries=1)
    assert pending == [] and np.isfinite(poses).all()
    # scan 1 onto scan 0 alone, then 2 onto 1 alone: one registration each
    assert calls == [len(placement.merged(scans, np.tile(np.eye(4), (3, 1, 1)), [s], voxel)[0]) for s in (0, 1)]
    assert {(e.source, e.target) for e in edges} == {(1, 0), (2, 1)}

    calls.clear()
    refuse = lambda fitness, residual, balanced: False  # noqa: E731
    group = placement.Group((1, 2), np.tile(np.eye(4), (2, 1, 1)))
    poses = np.full((3, 4, 4), np.nan)
    poses[0] = np.eye(4)
    _, _, pending, _ = placement.place_remaining(
        scans, poses, [group], None, None, voxel, sizes.DISTANCE_VOXELS * voxel, refuse, 0, lambda *_: None,
        partners=lambda s: [0], max_tries=1)
    assert pending == [1, 2] and len(calls) == 1


def test_a_campaign_places_a_scan_onto_the_placed_scans_its_pair_edges_join_first(monkeypatch):
    """Step 4 with ``joined``: a scan whose pair edges join it to placed scans is registered onto those alone,
    not onto its best-scored partners (a site's look-alike streets: seed 12's station 645 had right edges to two
    placed neighbours, its best-scored placed partners lay 100-400 m away); without a placed one, onto those."""
    clouds, _ = synthetic_scans()
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]  # three scans
    models = _identity_align(monkeypatch)
    size = [len(placement.merged(scans, np.tile(np.eye(4), (3, 1, 1)), [s], voxel)[0]) for s in (0, 1)]
    # (placed, best-scored partners, joined, the scan registered onto)
    for placed, best, joined, onto in (((0, 1), [1], {2: [0]}, 0), ((0, 1), [1], {}, 1), ((0,), [0], {2: [1]}, 0)):
        models.clear()
        poses = np.full((3, 4, 4), np.nan)
        poses[list(placed)] = np.eye(4)
        poses, _, pending, _ = placement.place_remaining(
            scans, poses, [placement.Group((2,), np.eye(4)[None])], None, None, voxel, sizes.DISTANCE_VOXELS * voxel,
            lambda *_: True, 0, lambda *_: None, partners=lambda s, best=best: best, max_tries=1, joined=joined)
        assert pending == [] and models == [size[onto]]


def test_unplaced_scans_joined_by_edges_form_a_group_with_their_relative_poses():
    """The scans the pose graph left out come back as groups: those joined by pair edges with their own graph's
    relative poses (largest first), then single scans."""
    scans, truth = cropped_pair(0, 1600)
    e = edges_lib.measure(scans, 0, 1, truth, 0.05, "classical")
    poses = np.full((4, 4, 4), np.nan)
    poses[2] = np.eye(4)
    moved = [e._replace(source=1, target=3)]  # scans 1 and 3 joined; 0 alone; 2 placed
    groups = placement.unplaced_groups(4, moved, poses, (0.01, 0.01), 0, weigh=True)
    assert [g.members for g in groups] == [(1, 3), (0,)]
    np.testing.assert_allclose(np.linalg.inv(groups[0].poses[1]) @ groups[0].poses[0], truth, atol=1e-9)
    assert groups[0].edges == tuple(moved)


def test_a_finer_refinement_voxel_makes_coarse_poses_precise(monkeypatch):
    """Registered at a coarse voxel (0.01 on a 0.2 shape), the poses are off by up to 0.11° (measured); refined on
    the scans prepared again at ``refine_voxel_size`` 0.002, by 0.007° (measured), and the answer reports the
    refinement's voxel and correspondence distance (2.5 voxels). The joint refinement runs twice: all its gates at
    the registration's voxel, then the finer pass's gate, points and stop."""
    clouds, truth = synthetic_scans()
    errors, refined, passes = {}, {}, []
    refine_jointly = joint_refine.refine_jointly

    def recorded(*args, **kwargs):
        passes.append({k: kwargs.get(k) for k in ("gates", "num_points", "tolerance", "max_iterations",
                                                  "max_extrapolation", "normal_cosine")})
        return refine_jointly(*args, **kwargs)

    monkeypatch.setattr(joint_refine, "refine_jointly", recorded)
    for fine in (None, 0.002):
        r = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(voxel_size=0.01, refine_voxel_size=fine))
        errors[fine] = max(rot for rot, _ in pose_errors.pose_errors(r.poses, truth, clouds))
        refined[fine] = r.pairs["refine"]
        assert r.voxel_size == (fine or 0.01) and r.max_correspondence_distance == pytest.approx(2.5 * r.voxel_size)
    assert errors[None] > 0.05 and errors[0.002] < 0.02, errors
    assert refined[0.002] > refined[None]  # both passes counted: at the registration's voxel, then the finer one
    first = {"gates": joint_refine.GATES, "num_points": joint_refine.POINTS, "tolerance": joint_refine.TOLERANCE,
             "max_iterations": None, "max_extrapolation": None, "normal_cosine": None}  # the defaults
    finer = {"gates": refinement.FINER_GATES, "num_points": refinement.FINER_POINTS,
             "tolerance": refinement.FINER_TOLERANCE, "max_iterations": refinement.FINER_ITERATIONS,
             "max_extrapolation": refinement.FINER_EXTRAPOLATION, "normal_cosine": refinement.FINER_NORMAL_COSINE}
    assert passes == [first, first, finer]
    with pytest.raises(ValueError, match="refine_voxel_size"):
        rpmnet_jax.ScanOptions(refine_voxel_size=0.0)


def test_icp_rounds_refine_on_the_finer_float32_scans():
    """``refine="icp"`` with ``refine_voxel_size``: the rounds of ICP edges run on the refinement's scans (float32
    points and normals in their trees' order) and bring the coarse poses in: worst 0.0007° against 0.21° at the
    registration's voxel alone (measured)."""
    clouds, truth = synthetic_scans()
    r = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(voxel_size=0.01, refine_voxel_size=0.002,
                                                                      refine="icp"))
    assert r.voxel_size == 0.002 and not r.left_out
    assert max(rot for rot, _ in pose_errors.pose_errors(r.poses, truth, clouds)) < 0.05


def test_a_planted_flip_stays_out_of_the_graph():
    """Step 2 with ``edge_doubt="reject"``: an answer 90° off the truth is kept out at ``p_wrong >=
    reject_threshold`` even where the good rule would let it through (here every answer is good); the right answer
    goes in with its ``p_wrong``; the consensus weighs the flip below it."""
    scans, truth = cropped_pair(0, 1600)
    turn = np.eye(4)
    turn[:3, :3] = rotation_about([1.0, 1.0, 0.0], 90.0)
    right, flip = (edges_lib.measure(scans, 0, 1, t, 0.05, "classical") for t in (truth, truth @ turn))
    found = edge_graph.screened([[right, flip]], 0.05, lambda e: True, reject=True)
    assert len(found[0]) == 1 and np.array_equal(found[0][0].transform, right.transform)
    assert found[0][0].p_wrong < edge_doubt.load().threshold  # measured 0.03
    found = edge_graph.screened([[right, flip]], 0.05, lambda e: True, reject=False)
    assert len(found[0]) == 2 and found[0][1].p_wrong >= edge_doubt.load().reject_threshold  # measured 1.00
    w_right, w_flip = edge_graph.doubt_weights(found[0])
    assert w_flip < 0.1 * w_right


def test_scans_resting_on_doubtful_edges_are_reported(monkeypatch):
    """``likely_wrong`` names the scans whose every path to the anchor crosses a kept edge with ``p_wrong`` at or
    above the threshold; with ``edge_doubt="reject"``, edges at ``reject_threshold`` and up never enter the
    graph."""
    clouds, _ = synthetic_scans()
    planted = {(0, 1): 0.0, (0, 2): 0.95, (1, 2): 0.6}  # the three candidate pairs, in order

    def p_wrong_of_pairs(answers_per_pair, max_distance, model=None):
        return [np.full(len(a), planted[(a[0].source, a[0].target)] if a else 0.0) for a in answers_per_pair]

    monkeypatch.setattr(edge_graph.edge_doubt, "p_wrong_of_pairs", p_wrong_of_pairs)
    screened = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(refine="none", edge_doubt="reject"))
    pairs = {(e.source, e.target) for e in screened.edges + screened.rejected}
    assert (0, 2) not in pairs and {(0, 1), (1, 2)} <= pairs
    assert screened.likely_wrong == (2,) and screened.left_out == ()
    unscreened = rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(refine="none"))
    assert (0, 2) in {(e.source, e.target) for e in unscreened.edges + unscreened.rejected}
    assert unscreened.likely_wrong == (2,)  # both of its edges are flagged
    planted[(0, 2)] = 0.1
    assert rpmnet_jax.align_scans(clouds, options=rpmnet_jax.ScanOptions(refine="none", edge_doubt="reject")
                                  ).likely_wrong == ()


def test_weighing_by_doubt_keeps_a_symmetric_ring_off_its_flips():
    """A ring of 5 noisy views of a box (180° turns map it nearly onto itself): ranked by fitness alone, the
    consensus takes the flips, which overlap more (measured 180.0° off); ranked by fitness × (1 − ``p_wrong``)
    (the default) it keeps the right edges (measured 0.19°). The box is the one the edge doubt fit left out. (Of
    12 such rings (seeds 0-11), 4 end 180° off by fitness and 1 weighed, with the features of the whole scan at
    keypoints on a grid; 6 and 2 with those of 1,024 random keypoints among themselves.)"""
    clouds, truth = ring_scans(5, seed=1)
    rng = np.random.default_rng(101)
    noisy = [c + rng.normal(scale=0.0005, size=c.shape) for c in clouds]
    errors = {mode: max(rot for rot, _ in pose_errors.pose_errors(
        rpmnet_jax.align_scans(noisy, options=rpmnet_jax.ScanOptions(edge_doubt=mode)).poses, truth, clouds))
        for mode in ("off", "weigh")}
    assert errors["off"] > 90 and errors["weigh"] < 1.0, errors


GRID = np.array([512_000.0, 4_100_000.0, 120.0])  # a national grid's easting, northing and height (metres)


@pytest.mark.parametrize("refine", ["none", "icp", "joint"])
def test_scans_in_a_national_grid_get_the_poses_they_get_near_the_origin(bunny, refine):
    """Four real bunny scans moved as a whole by (512 km, 4,100 km, 120 m): every relative pose as near the origin
    (before the common shift: ``refine="none"`` 1.1° and 868 mm off on five of them), and the edges' transforms in
    the caller's frame."""
    names = ["bun000", "bun045", "bun315", "chin"]
    clouds = _read(names)
    options = rpmnet_jax.ScanOptions(voxel_size=0.003, refine=refine)
    near = rpmnet_jax.align_scans(clouds, options=options)
    far = rpmnet_jax.align_scans([c + GRID for c in clouds], options=options)
    grid = np.eye(4)
    grid[:3, 3] = GRID
    for a, b in zip(near.poses[1:], far.poses[1:]):
        moved = np.linalg.inv(grid) @ b @ grid  # the grid pose as a motion of the scans near the origin
        assert rotation_error_deg(moved[:3, :3], a[:3, :3]) <= 0.01
        assert np.linalg.norm(moved[:3, 3] - a[:3, 3]) <= 1e-4  # 0.1 mm
    truth = np.stack([bunny[n] for n in names])
    back = np.linalg.inv(grid) @ far.poses @ grid
    assert all(rot < 1.0 and rms < 2e-3 for rot, rms in pose_errors.pose_errors(back, truth, clouds))
    for e in far.edges:  # kept edges move the source scan's points in the caller's coordinates as the poses do
        relative = np.linalg.inv(far.poses[e.target]) @ far.poses[e.source]
        src = clouds[e.source][::20] + GRID
        gap = np.linalg.norm(src @ (e.transform - relative)[:3, :3].T + (e.transform - relative)[:3, 3], axis=1)
        assert np.max(gap) < 5e-3  # 5 mm on a 15 cm bunny (the edges of the shifted frames: kilometres)


@pytest.mark.slow  # the run without the rounds places scans onto the merged ones
def test_groups_the_candidate_pairs_leave_apart_are_bridged_by_the_next_partners(monkeypatch):
    """Scores that rank each view's opposite first and its neighbours last: the first candidate pairs barely
    overlap, and rounds of each outside scan's next partners across groups find the neighbours (no network, no
    placement onto the merged scans); without the rounds they are not found."""
    from rpmnet_jax.multiway import candidate_pairs, scan_alignment

    count = 8
    clouds, truth = ring_scans(count, asymmetric=True)
    apart = np.abs(np.subtract.outer(np.arange(count), np.arange(count)))
    apart = np.minimum(apart, count - apart)  # 0 ... 4 views round the ring
    monkeypatch.setattr(candidate_pairs, "overlap_scores", lambda scans, seed=0: apart / 4.0)
    options = rpmnet_jax.ScanOptions(all_pairs_up_to=2, neighbours=1)
    reports = []
    result = rpmnet_jax.align_scans(clouds, options=options, progress=lambda *r: reports.append(r))
    errors = pose_errors.pose_errors(result.poses, truth, clouds)
    print(errors, result.pairs, result.timings)
    assert all(rot < 1.0 for rot, _ in errors), errors
    assert any(r[0].startswith("classical edges between groups") for r in reports)
    assert "network" not in result.timings and "global" not in result.timings
    monkeypatch.setattr(scan_alignment, "BRIDGING_ROUNDS", 0)
    without = rpmnet_jax.align_scans(clouds, options=options)
    assert "network" in without.timings or "global" in without.timings
