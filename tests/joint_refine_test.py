"""Joint multi-view refinement: poses a degree and millimetres off come back to the truth, the anchor and the scans in
no pair stay where they are, it beats the pose-graph refinement on noisy scans, and its sparse normal equations (only
the pairs' blocks) give the dense solve's step."""

import itertools

import numpy as np
import pytest

from conftest import ring_scans, rotation_about, rotation_error_deg
from rpmnet_jax.evaluation import pose_errors
from rpmnet_jax.geometry import packed_normals
from rpmnet_jax.pose_graphs import joint_refine
from rpmnet_jax.multiway import preparation, sizes


def _perturbed(poses, degrees, shift, seed):
    """``poses (S, 4, 4)`` each turned by ``degrees`` about a random axis and moved by ``shift``, but the first."""
    rng = np.random.default_rng(seed)
    out = np.array(poses)
    for s in range(1, len(out)):
        step = np.eye(4)
        step[:3, :3], step[:3, 3] = rotation_about(rng.normal(size=3), degrees), shift * rng.normal(size=3)
        out[s] = step @ out[s]
    return out


def _relative_errors(poses, truth, clouds):
    """Per scan: (rotation °, RMS displacement of its points) in the first scan's frame."""
    return np.array(pose_errors.pose_errors(np.linalg.inv(poses[0]) @ poses, truth, clouds))


def test_poses_a_degree_off_come_back_to_the_truth():
    clouds, truth = ring_scans(5)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    start = _perturbed(truth, 1.5, 0.002, seed=0)  # 1.5° and ~3 mm on a 0.2-wide shape
    pairs = [(i, j) for i, j in itertools.combinations(range(5), 2) if (j - i) % 5 in (1, 4)]  # the ring
    before = _relative_errors(start, truth, clouds)
    out = joint_refine.refine_jointly(scans, start, pairs, sizes.DISTANCE_VOXELS * voxel, anchor=0)
    after = _relative_errors(out.poses, truth, clouds)
    print(before.max(0), after.max(0), out.iterations)
    assert before[:, 0].max() > 1.0  # the start was off
    assert after[:, 0].max() < 0.1 and after[:, 1].max() < 2e-4  # noise-free views: measured 0.01° / 0.02 mm
    np.testing.assert_array_equal(out.poses[0], start[0])  # the anchor does not move
    assert 0 < out.iterations <= len(joint_refine.GATES) * joint_refine.MAX_ITERATIONS


def test_a_scan_in_no_pair_stays_and_no_pairs_change_nothing():
    clouds, truth = ring_scans(4)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    start = _perturbed(truth, 1.0, 0.001, seed=1)
    out = joint_refine.refine_jointly(scans, start, [(0, 1), (1, 2)], sizes.DISTANCE_VOXELS * voxel, anchor=0)
    np.testing.assert_array_equal(out.poses[3], start[3])  # scan 3 is in no pair
    assert rotation_error_deg(out.poses[1][:3, :3], truth[1][:3, :3]) < 0.2
    same = joint_refine.refine_jointly(scans, start, [], sizes.DISTANCE_VOXELS * voxel, anchor=0)
    np.testing.assert_array_equal(same.poses, start)
    assert same.iterations == 0 and same.converged


def test_noisy_scans_end_closer_than_the_pose_graph_of_icp_edges():
    clouds, truth = ring_scans(5)
    rng = np.random.default_rng(3)
    noisy = [c + rng.normal(scale=0.0005, size=c.shape) for c in clouds]  # 0.5 mm on a 0.2-wide shape
    import rpmnet_jax

    joint = rpmnet_jax.align_scans(noisy, options=rpmnet_jax.ScanOptions(refine="joint"))
    graph = rpmnet_jax.align_scans(noisy, options=rpmnet_jax.ScanOptions(refine="icp"))
    a, b = (_relative_errors(r.poses, truth, clouds) for r in (joint, graph))
    print("joint", a.max(0), "icp", b.max(0))
    assert {e.stage for e in joint.edges} == {"joint"}
    assert a[:, 1].max() < b[:, 1].max()  # the worst scan's RMS displacement


def _dense_step(blocks, g, used, num_scans):
    """The reference: the whole ``(6S, 6S)`` matrix of ``blocks``, cut to ``used``, damped, solved densely."""
    h = np.zeros((num_scans, num_scans, 6, 6))
    for (i, j), block in blocks.items():
        h[i, j] = block
    h = h.transpose(0, 2, 1, 3).reshape(6 * num_scans, 6 * num_scans)
    cols = np.concatenate([np.arange(6 * s, 6 * s + 6) for s in used])
    a = h[np.ix_(cols, cols)]
    a[np.diag_indices_from(a)] += joint_refine.DAMPING * max(np.trace(a) / len(a), 1e-12)
    return np.linalg.solve(a, -g.reshape(-1)[cols]).reshape(-1, 6)


def test_the_sparse_step_is_the_dense_solve_of_the_same_blocks():
    rng = np.random.default_rng(0)
    num_scans, anchor = 9, 2
    pairs = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0), (1, 3), (6, 7)]  # scans 5 and 8 in no pair; 6-7 apart
    blocks = {}
    for a, b in pairs:
        for i, j in ((a, b), (b, a)):
            ji, jj = rng.normal(size=(2, 40, 6))  # d r / d (ω, v) of scans i and j
            w = rng.uniform(0.1, 1.0, 40)
            for key, block in (((i, i), ji.T @ (ji * w[:, None])), ((j, j), jj.T @ (jj * w[:, None])),
                               ((i, j), ji.T @ (jj * w[:, None])), ((j, i), jj.T @ (ji * w[:, None]))):
                blocks[key] = blocks.get(key, 0) + block
    g = rng.normal(size=(num_scans, 6))
    used = sorted({s for p in pairs for s in p} - {anchor})
    sparse_step = joint_refine._twists(blocks, g, used)
    dense_step = _dense_step(blocks, g, used, num_scans)
    assert sparse_step.shape == (len(used), 6)
    np.testing.assert_allclose(sparse_step, dense_step, rtol=0, atol=1e-10 * np.abs(dense_step).max())


def test_the_normal_equations_hold_only_the_pairs_blocks():
    clouds, truth = ring_scans(5)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    pairs = [(0, 1), (1, 2), (2, 3)]  # scan 4 in none
    start = _perturbed(truth, 1.0, 0.001, seed=2)
    directed = [(i, j) for a, b in pairs for i, j in ((a, b), (b, a))]
    centre = np.mean([p[:3, 3] for p in start], axis=0)
    args = (start, 200, 0, centre, sizes.DISTANCE_VOXELS * voxel)
    whole = [joint_refine.pair_equations(scans, directed, *args)]
    residuals = whole[0][2]
    blocks, g, magnitudes = joint_refine._normal_equations(whole, 5)
    assert whole == [None]  # let go once summed
    assert set(blocks) == {(s, s) for s in range(4)} | {(i, j) for a, b in pairs for i, j in ((a, b), (b, a))}
    assert g.shape == (5, 6) and len(residuals) > 0 and not g[4].any()
    np.testing.assert_array_equal(magnitudes, np.abs(residuals))
    # in shares (tasks on a cluster, each with only its scans), summed: the same equations
    shares = [joint_refine.pair_equations({s: scans[s] for p in part for s in p}, part, *args)
              for part in (directed[:1], directed[1:4], directed[4:])]
    in_shares = joint_refine._normal_equations(shares, 5)
    assert set(in_shares[0]) == set(blocks) and np.array_equal(in_shares[2], magnitudes)
    for key, block in blocks.items():
        np.testing.assert_allclose(in_shares[0][key], block, rtol=1e-12, atol=1e-12 * np.abs(block).max())
    np.testing.assert_allclose(in_shares[1], g, rtol=1e-12, atol=1e-12 * np.abs(g).max())
    for (i, j), block in blocks.items():
        np.testing.assert_allclose(block, blocks[j, i].T, rtol=0, atol=1e-12 * np.abs(block).max())
    dense_step = _dense_step(blocks, g, [1, 2, 3], 5)
    np.testing.assert_allclose(joint_refine._twists(blocks, g, [1, 2, 3]), dense_step, rtol=0,
                               atol=1e-10 * np.abs(dense_step).max())


def _unit(normals):
    """Unit normals in float64: a refinement's packed ones unpacked (as the compiled rows read them)."""
    return packed_normals.unpack(normals, np.float64) if packed_normals.is_packed(normals) else normals


def _reference_pair(scans, i, j, poses, num_points, seed, centre, gate, cosine=-1.0):
    """One directed pair's ``(A (12, 12), b (12,), r)`` in plain NumPy with SciPy's k-d tree: the Tukey-weighted
    point-to-plane residuals of scan ``i``'s seeded rows on scan ``j``'s tangent planes and their derivatives in
    ``(ω_i, v_i, ω_j, v_j)`` (left twists about ``centre``), the rows whose normals meet their neighbours' at
    ``|cos|`` below ``cosine`` left out."""
    from scipy.spatial import cKDTree

    rows = joint_refine._rows(scans, i, j, num_points, seed)
    x = scans[i].points[rows] @ poses[i][:3, :3].T + poses[i][:3, 3]
    in_j = (x - poses[j][:3, 3]) @ poses[j][:3, :3]
    dist, idx = cKDTree(scans[j].points).query(in_j, distance_upper_bound=gate)
    near = np.isfinite(dist)
    normals_i, normals_j = _unit(scans[i].normals), _unit(scans[j].normals)
    n_i = normals_i[rows] @ poses[i][:3, :3].T
    n_j = normals_j[np.minimum(idx, len(scans[j].points) - 1)] @ poses[j][:3, :3].T
    near &= np.abs(np.sum(n_i * n_j, axis=1)) >= cosine
    x = x[near] - centre
    q = scans[j].points[idx[near]] @ poses[j][:3, :3].T + poses[j][:3, 3] - centre
    n = normals_j[idx[near]] @ poses[j][:3, :3].T
    r = np.sum((x - q) * n, axis=1)
    w = (1.0 - np.minimum(np.abs(r) / gate, 1.0) ** 2) ** 2
    jac = np.concatenate([np.cross(x, n), n, np.cross(n, x - q) - np.cross(q, n), -n], axis=1)
    return jac.T @ (jac * w[:, None]), jac.T @ (w * r), r


def test_the_compiled_pair_equations_match_a_numpy_reference():
    """The compiled rows (query, residual, Jacobian, Tukey weight, sums) give the blocks and gradients of a plain
    NumPy computation with SciPy's k-d tree, for each directed pair, both gates and both row counts (serial and
    parallel queries)."""
    clouds, truth = ring_scans(4)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    start = _perturbed(truth, 0.1, 0.0005, seed=4)
    centre = np.mean([p[:3, 3] for p in start], axis=0)
    for num_points, gate in ((200, sizes.DISTANCE_VOXELS * voxel), (1500, voxel)):
        for i, j in ((0, 1), (1, 0), (2, 3), (3, 2)):
            blocks, g, r = joint_refine.pair_equations(scans, [(i, j)], start, num_points, 0, centre, gate)
            a, b, want = _reference_pair(scans, i, j, start, num_points, 0, centre, gate)
            assert len(want) > 50 and len(r) == len(want)
            np.testing.assert_allclose(r, want, rtol=0, atol=1e-12)
            for (s, t), block in (((i, i), a[:6, :6]), ((j, j), a[6:, 6:]), ((i, j), a[:6, 6:]), ((j, i), a[6:, :6])):
                np.testing.assert_allclose(blocks[s, t], block, rtol=0, atol=1e-10 * np.abs(a).max())
            np.testing.assert_allclose(g[i], b[:6], rtol=0, atol=1e-10 * np.abs(b).max())
            np.testing.assert_allclose(g[j], b[6:], rtol=0, atol=1e-10 * np.abs(b).max())


def test_rows_whose_normals_disagree_are_left_out_as_a_numpy_reference_leaves_them():
    """With ``normal_cosine`` the compiled rows drop a row whose normal and its neighbour's meet at more than the
    angle, as the NumPy reference does, and only those: fewer rows than without, the same equations as the
    reference's on the rows kept (noisy scans: their normals disagree somewhere)."""
    clouds, truth = ring_scans(4)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    start = _perturbed(truth, 0.1, 0.0005, seed=4)
    centre = np.mean([p[:3, 3] for p in start], axis=0)
    gate = sizes.DISTANCE_VOXELS * voxel
    for i, j in ((0, 1), (3, 2)):
        every = joint_refine.pair_equations(scans, [(i, j)], start, 1500, 0, centre, gate)[2]
        blocks, g, r = joint_refine.pair_equations(scans, [(i, j)], start, 1500, 0, centre, gate, 0.985)
        a, b, want = _reference_pair(scans, i, j, start, 1500, 0, centre, gate, 0.985)
        assert 50 < len(r) < len(every) and len(r) == len(want)
        np.testing.assert_allclose(r, want, rtol=0, atol=1e-12)
        np.testing.assert_allclose(blocks[i, j], a[:6, 6:], rtol=0, atol=1e-10 * np.abs(a).max())
        np.testing.assert_allclose(g[i], b[:6], rtol=0, atol=1e-10 * np.abs(b).max())


def test_a_refinements_packed_normals_are_read_as_the_reference_unpacks_them(monkeypatch):
    """A refinement's scans (points in float32 in their tree's order, normals packed in two int16) give the
    reference's equations on the same rows, their normals unpacked; and the same poses as with the unit normals
    the codes came from (held in float32), but for the codes' rounding (under 1e-4 rad a normal)."""
    clouds, truth = ring_scans(4)
    voxel = preparation.prepare_scans(clouds, None, None).voxel
    scans = preparation.prepare_scans(clouds, None, voxel, features=False).scans
    assert all(packed_normals.is_packed(s.normals) for s in scans)
    start = _perturbed(truth, 0.1, 0.0005, seed=4)
    centre = np.mean([p[:3, 3] for p in start], axis=0)
    gate = sizes.DISTANCE_VOXELS * voxel
    for i, j in ((0, 1), (3, 2)):
        blocks, g, r = joint_refine.pair_equations(scans, [(i, j)], start, 1500, 0, centre, gate, 0.985)
        a, b, want = _reference_pair(scans, i, j, start, 1500, 0, centre, gate, 0.985)
        assert len(want) > 50 and len(r) == len(want)
        np.testing.assert_allclose(r, want, rtol=0, atol=1e-12)
        np.testing.assert_allclose(blocks[i, j], a[:6, 6:], rtol=0, atol=1e-10 * np.abs(a).max())
        np.testing.assert_allclose(g[i], b[:6], rtol=0, atol=1e-10 * np.abs(b).max())
    monkeypatch.setattr(preparation.packed_normals, "pack", lambda n: np.asarray(n, np.float32))  # not packed
    unpacked = preparation.prepare_scans(clouds, None, voxel, features=False).scans
    assert all(s.normals.dtype == np.float32 and s.normals.shape[1] == 3 for s in unpacked)
    pairs = [(0, 1), (1, 2), (2, 3), (0, 3)]
    packed_out = joint_refine.refine_jointly(scans, start, pairs, gate, anchor=0, normal_cosine=0.985)
    unit_out = joint_refine.refine_jointly(unpacked, start, pairs, gate, anchor=0, normal_cosine=0.985)
    assert not np.array_equal(packed_out.poses, start)
    assert not np.array_equal(unit_out.poses, packed_out.poses)  # the codes were read, not the unit normals
    moved = _relative_errors(unit_out.poses, packed_out.poses, clouds)
    assert moved[:, 0].max() < 1e-5 and moved[:, 1].max() < 1e-8  # measured 5e-7 deg, 5e-10 m on a 0.2-wide shape
    # (noise-free views: the same optimum, the normals only weigh its directions)


def test_a_count_of_rows_per_gate():
    """``num_points`` one per gate: each stage's equations on its own count of rows, and ``normal_cosine`` in each
    (recorded where the pairs are mapped); a list of the wrong length is refused before any work."""
    clouds, truth = ring_scans(3)
    scans, voxel = preparation.prepare_scans(clouds, None, None)[:2]
    start = _perturbed(truth, 0.5, 0.001, seed=1)
    seen = []

    def recorded(fn, chunks, *args):
        seen.append(args[1])
        cosines.append(args[-1])
        return joint_refine.in_process(scans)(fn, chunks, *args)

    cosines = []
    out = joint_refine.refine_jointly(scans, start, [(0, 1), (1, 2)], sizes.DISTANCE_VOXELS * voxel, anchor=0,
                                      gates=(1.0, 0.5), num_points=(300, 700), max_iterations=2, map_pairs=recorded,
                                      normal_cosine=0.9)
    assert out.iterations == len(seen) and seen[0] == 300 and seen[-1] == 700 and sorted(seen) == seen
    assert cosines == [0.9] * len(seen)  # the normal test reaches every step's equations
    with pytest.raises(ValueError, match="num_points"):
        joint_refine.refine_jointly(scans, start, [(0, 1)], 0.1, anchor=0, gates=(1.0, 0.5), num_points=(300,),
                                    map_pairs=recorded)
    assert out.iterations == len(seen)  # nothing mapped for the refused call


def test_steps_that_line_up_and_shrink_are_extrapolated():
    """Besl and McKay's acceleration: a step along the last one, shrunk by ρ, is taken as the sum of the steps to
    come, 1 / (1 − ρ), capped; a stage's first step, a step that turns away or grows: taken as it is. Translations
    count over the radius (a step in metres on a 100 m set weighs like one in radians)."""
    rng = np.random.default_rng(0)
    last = rng.normal(size=(7, 6)) * [1e-3, 1e-3, 1e-3, 0.1, 0.1, 0.1]
    assert joint_refine.extrapolation(0.5 * last, None, 100.0) == 1.0
    assert joint_refine.extrapolation(0.5 * last, last, 100.0) == pytest.approx(2.0)
    assert joint_refine.extrapolation(0.8 * last, last, 100.0) == pytest.approx(5.0)
    assert joint_refine.extrapolation(0.99 * last, last, 100.0) == joint_refine.MAX_EXTRAPOLATION
    assert joint_refine.extrapolation(0.99 * last, last, 100.0, cap=20.0) == 20.0
    assert joint_refine.extrapolation(0.96 * last, last, 100.0, cap=40.0) == pytest.approx(25.0)
    assert joint_refine.extrapolation(1.2 * last, last, 100.0) == 1.0
    assert joint_refine.extrapolation(-0.5 * last, last, 100.0) == 1.0
    turned = 0.5 * np.roll(last, 1, axis=0)  # as long, another direction
    assert joint_refine.extrapolation(turned, last, 100.0) == 1.0
    # half of the last step's translations, a tenth of its rotations about other axes: aligned where translations
    # dominate (a radius of 1 m: 0.1 m against 1e-3 rad), not where the rotations do (1e4 m: 1e-5 against 1e-3)
    mixed = np.concatenate([0.1 * np.roll(last[:, :3], 1, axis=1), 0.5 * last[:, 3:]], axis=1)
    assert joint_refine.extrapolation(mixed, last, 1.0) > 1.5
    assert joint_refine.extrapolation(mixed, last, 1e4) == 1.0
    assert joint_refine.extrapolation(np.full((7, 6), np.nan), last, 100.0) == 1.0


def test_near_pairs_are_every_pair_whose_spheres_touch():
    """The k-d tree's candidates give exactly the all-pairs rule (spheres within ``max_dist``), sorted, on a
    random set of spheres of mixed sizes, and nothing for fewer than two."""
    import itertools

    from rpmnet_jax.multiway import refinement

    rng = np.random.default_rng(5)
    centres, radii = rng.uniform(-50.0, 50.0, size=(300, 3)), rng.uniform(0.5, 6.0, size=300)
    every = [(a, b) for a, b in itertools.combinations(range(300), 2)
             if np.linalg.norm(centres[a] - centres[b]) <= radii[a] + radii[b] + 0.7]
    assert len(every) > 50 and refinement.near_pairs(centres, radii, 0.7) == every
    assert refinement.near_pairs(centres[:1], radii[:1], 0.7) == []
