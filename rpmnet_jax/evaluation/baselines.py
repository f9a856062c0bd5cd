"""Baselines for the evaluation table: identity, classical RPM (this project's Sinkhorn and Procrustes),
ICP / FGR through Open3D (optional) with the settings the RPM-Net authors reported, and Open3D's own
recipe a practitioner would use: FPFH + RANSAC or FGR, then robust point-to-plane ICP."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from rpmnet_jax import registration
from rpmnet_jax.ops import grouping
from rpmnet_jax.ops import se3
from rpmnet_jax.ops import sinkhorn



def identity(src, ref):
    """``(B, 3, 4)`` identity transforms."""
    return np.broadcast_to(np.eye(3, 4, dtype=np.float32), (len(src), 3, 4)).copy()


@functools.partial(jax.jit, static_argnames=("num_steps", "sk_iters"))
def classical_rpm(src_xyz, ref_xyz, beta0: float = 0.1, beta_final: float = 1000.0, alpha: float = 0.01,
                  num_steps: int = 100, sk_iters: int = 20):
    """Robust point matching (Gold et al. 1998) on spatial distances with a slack row and column.

    Deterministic annealing: at each of ``num_steps`` inverse temperatures ``beta`` (geometric from ``beta0``
    to ``beta_final``) the match matrix ``sinkhorn(-beta (|T x_j - y_k|^2 - alpha))`` gives soft
    correspondences and weighted Procrustes the next ``T``. ``src_xyz (B, J, 3)``, ``ref_xyz (B, K, 3)`` →
    ``(num_steps, B, 3, 4)``.
    """
    betas = beta0 * (beta_final / beta0) ** (jnp.arange(num_steps, dtype=jnp.float32) / max(num_steps - 1, 1))

    def step(transform, beta):
        moved = se3.apply(transform, src_xyz)
        dist = grouping.square_distance(moved, ref_xyz)
        perm = jnp.exp(sinkhorn.log_sinkhorn(-beta * (dist - alpha), sk_iters, True))
        new, _, _ = registration.soft_procrustes(perm, src_xyz, ref_xyz)
        return new, new

    _, transforms = lax.scan(step, se3.identity((src_xyz.shape[0],), src_xyz.dtype), betas)
    return transforms


def open3d_available() -> str | None:
    """``None`` if Open3D imports, else why not (one line)."""
    try:
        import open3d  # noqa: F401
    except Exception as e:  # ImportError, or a missing system library
        return f"Open3D unavailable ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}); pip install open3d"
    return None


def _o3d_cloud(points):
    import open3d as o3d
    pc = o3d.geometry.PointCloud()
    pc.points = o3d.utility.Vector3dVector(np.asarray(points[:, :3], np.float64))
    if points.shape[1] >= 6:
        pc.normals = o3d.utility.Vector3dVector(np.asarray(points[:, 3:6], np.float64))
    return pc


def icp(src, ref, max_correspondence: float = 0.5, max_iterations: int = 30):
    """Point-to-point ICP from the identity (Open3D); ``(B, ·, 6)`` → ``(B, 3, 4)``."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    out = []
    for s, r in zip(src, ref):
        res = reg.registration_icp(_o3d_cloud(s), _o3d_cloud(r), max_correspondence, np.eye(4),
                                   reg.TransformationEstimationPointToPoint(),
                                   reg.ICPConvergenceCriteria(max_iteration=max_iterations))
        out.append(np.asarray(res.transformation)[:3])
    return np.stack(out).astype(np.float32)


def _fpfh(pc, radius: float, max_nn: int):
    import open3d as o3d
    return o3d.pipelines.registration.compute_fpfh_feature(
        pc, o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=max_nn))


def _fgr_pair(ps, pr, fs, fr, max_correspondence: float) -> np.ndarray:
    import open3d as o3d
    reg = o3d.pipelines.registration
    return np.asarray(reg.registration_fgr_based_on_feature_matching(
        ps, pr, fs, fr, reg.FastGlobalRegistrationOption(maximum_correspondence_distance=max_correspondence))
        .transformation)


def _ransac_pair(ps, pr, fs, fr, max_distance: float) -> np.ndarray:
    """Open3D's RANSAC on FPFH matches (its tutorial's recipe): mutual filter, point-to-point, 3 points per
    hypothesis, edge-length (0.9) and distance checkers, 100k iterations at confidence 0.999."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    return np.asarray(reg.registration_ransac_based_on_feature_matching(
        ps, pr, fs, fr, True, max_distance, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(max_distance)],
        reg.RANSACConvergenceCriteria(100000, 0.999)).transformation)


def _icp_point_to_plane(ps, pr, init, threshold: float, tukey_k: float, max_iterations: int) -> np.ndarray:
    """Robust (Tukey) point-to-plane ICP from ``init (4, 4)`` (the reference's normals)."""
    import open3d as o3d
    reg = o3d.pipelines.registration
    return np.asarray(reg.registration_icp(
        ps, pr, threshold, init, reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=tukey_k)),
        reg.ICPConvergenceCriteria(max_iteration=max_iterations)).transformation)


ICP_THRESHOLD, ICP_TUKEY_K, ICP_ITERATIONS = 0.05, 0.05, 60  # the recipe's ICP on unit-sphere clouds


def robust_icp(src, ref, init, threshold: float = ICP_THRESHOLD, tukey_k: float = ICP_TUKEY_K,
               max_iterations: int = ICP_ITERATIONS) -> np.ndarray:
    """The recipe's refinement alone: Tukey point-to-plane ICP (Open3D) of ``src (N, 6)`` onto ``ref (M, 6)``
    (xyz + normals) from ``init (4, 4)`` → ``(4, 4)``."""
    return _icp_point_to_plane(_o3d_cloud(np.asarray(src)), _o3d_cloud(np.asarray(ref)),
                               np.asarray(init, np.float64), threshold, tukey_k, max_iterations)


def fgr(src, ref, radius: float = 0.3, max_nn: int = 128, max_correspondence: float = 0.01):
    """Fast Global Registration on FPFH features (Open3D); ``(B, ·, 6)`` → ``(B, 3, 4)``."""
    out = []
    for s, r in zip(src, ref):
        ps, pr = _o3d_cloud(s), _o3d_cloud(r)
        out.append(_fgr_pair(ps, pr, _fpfh(ps, radius, max_nn), _fpfh(pr, radius, max_nn), max_correspondence)[:3])
    return np.stack(out).astype(np.float32)


def global_then_icp(src, ref, start: str, radius: float = 0.3, max_nn: int = 128, ransac_distance: float = 0.075,
                    fgr_distance: float = 0.01, icp_threshold: float = ICP_THRESHOLD, tukey_k: float = ICP_TUKEY_K,
                    icp_iterations: int = ICP_ITERATIONS):
    """Open3D's classical recipe for unit-sphere clouds: a global start from FPFH features (``start`` is
    ``"ransac"`` or ``"fgr"``), then robust point-to-plane ICP. ``o3d.utility.random.seed(0)`` before each
    pair. ``(B, ·, 6)`` (xyz + normals) → ``(B, 3, 4)``."""
    import open3d as o3d
    if start not in ("ransac", "fgr"):
        raise ValueError(f"start must be 'ransac' or 'fgr', got {start!r}")
    out = []
    for s, r in zip(src, ref):
        o3d.utility.random.seed(0)
        ps, pr = _o3d_cloud(s), _o3d_cloud(r)
        fs, fr = _fpfh(ps, radius, max_nn), _fpfh(pr, radius, max_nn)
        init = (_ransac_pair(ps, pr, fs, fr, ransac_distance) if start == "ransac"
                else _fgr_pair(ps, pr, fs, fr, fgr_distance))
        out.append(_icp_point_to_plane(ps, pr, init, icp_threshold, tukey_k, icp_iterations)[:3])
    return np.stack(out).astype(np.float32)


def open3d_scan_pair(src, ref, voxel_size: float, seed: int = 0, viewpoints=None) -> np.ndarray:
    """Open3D's recipe for one pair of scans ``src (N, 3)`` onto ``ref (M, 3)`` (caller's units): voxel
    downsampling first, normals (radius ``2 × voxel``; turned toward each scan's sensor when ``viewpoints`` gives
    the two sensor positions ``(3,)``, in each scan's coordinates), FPFH (radius ``5 × voxel``), RANSAC on feature
    matches (distance ``1.5 × voxel``), then Tukey point-to-plane ICP (threshold ``1.5 × voxel``) → ``(4, 4)``."""
    import open3d as o3d
    o3d.utility.random.seed(seed)
    downs, feats = [], []
    for k, points in enumerate((src, ref)):
        pc = _o3d_cloud(np.asarray(points, np.float64)).voxel_down_sample(voxel_size)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel_size, max_nn=30))
        if viewpoints is not None:
            pc.orient_normals_towards_camera_location(np.asarray(viewpoints[k], np.float64))
        downs.append(pc)
        feats.append(_fpfh(pc, 5 * voxel_size, 100))
    init = _ransac_pair(downs[0], downs[1], feats[0], feats[1], 1.5 * voxel_size)
    return _icp_point_to_plane(downs[0], downs[1], init, 1.5 * voxel_size, 1.5 * voxel_size, ICP_ITERATIONS)


def open3d_multiway(clouds, voxel_size: float, seed: int = 0, progress=None, order: str = "free") -> np.ndarray:
    """Open3D's multiway registration recipe (its tutorial, with a global start for every pair).

    Each scan ``clouds[i] (N_i, 3)`` is voxel-downsampled, gets normals (radius ``2 × voxel``) and FPFH
    features (radius ``5 × voxel``); every pair is registered by RANSAC on feature matches (distance
    ``1.5 × voxel``, edge-length and distance checkers, 100k iterations, confidence 0.999) and point-to-plane ICP
    (coarse ``15 × voxel``, fine ``1.5 × voxel``); Levenberg–Marquardt with edge pruning at 0.25.

    Which edges are certain: ``order="free"`` (the default, for files in no particular order) takes the
    maximum spanning tree of the pairs' ICP fitness as the certain edges and the initial poses, every other
    pair an uncertain loop closure; ``order="file"`` is the tutorial's sequence rule (neighbours in the given
    order are odometry edges), right only when consecutive files overlap. Returns the poses ``(S, 4, 4)``
    mapping each scan into the first scan's frame; ``progress(done, total)`` after each pair.
    """
    import open3d as o3d
    from rpmnet_jax.pose_graphs import pose_graph
    if order not in ("free", "file"):
        raise ValueError(f"order must be 'free' or 'file', got {order!r}")
    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    downs, feats = [], []
    for points in clouds:
        pc = _o3d_cloud(np.asarray(points, np.float64)).voxel_down_sample(voxel_size)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel_size, max_nn=30))
        feats.append(_fpfh(pc, 5 * voxel_size, 100))
        downs.append(pc)
    coarse, fine = 15 * voxel_size, 1.5 * voxel_size
    num = len(downs)
    pairs, transforms, infos, fitness = [], [], [], []
    for i in range(num):
        for j in range(i + 1, num):
            ransac = _ransac_pair(downs[i], downs[j], feats[i], feats[j], fine)
            icp_coarse = reg.registration_icp(downs[i], downs[j], coarse, ransac,
                                              reg.TransformationEstimationPointToPlane())
            icp_fine = reg.registration_icp(downs[i], downs[j], fine, icp_coarse.transformation,
                                            reg.TransformationEstimationPointToPlane())
            pairs.append((i, j))
            transforms.append(np.asarray(icp_fine.transformation))
            fitness.append(icp_fine.fitness)
            infos.append(reg.get_information_matrix_from_point_clouds(downs[i], downs[j], fine, transforms[-1]))
            if progress is not None:
                progress(len(pairs), num * (num - 1) // 2)
    pairs = np.array(pairs, int).reshape(-1, 2)
    if order == "file":
        certain = pairs[:, 1] == pairs[:, 0] + 1
        poses = [np.eye(4)]
        for e in np.nonzero(certain)[0]:  # odometry: scan j+1 from scan j
            poses.append(poses[-1] @ np.linalg.inv(transforms[e]))
    else:
        certain = pose_graph.spanning_forest(num, pairs, fitness)
        poses = pose_graph.spanning_tree_poses(num, pairs, transforms, fitness, anchor=0)
    graph = reg.PoseGraph()
    for pose in poses:
        graph.nodes.append(reg.PoseGraphNode(np.asarray(pose)))
    for (i, j), t, info, sure in zip(pairs, transforms, infos, certain):
        graph.edges.append(reg.PoseGraphEdge(int(i), int(j), t, info, uncertain=not sure))
    reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                            reg.GlobalOptimizationConvergenceCriteria(),
                            reg.GlobalOptimizationOption(max_correspondence_distance=fine, edge_prune_threshold=0.25,
                                                         reference_node=0))
    return np.stack([np.asarray(node.pose) for node in graph.nodes])


def kiss_matcher_available() -> str | None:
    """``None`` if KISS-Matcher and small_gicp import, else why not (one line)."""
    try:
        import kiss_matcher  # noqa: F401
        import small_gicp  # noqa: F401
    except Exception as e:  # ImportError, or a missing system library
        return f"KISS-Matcher + small_gicp unavailable ({type(e).__name__}); pip install kiss-matcher small_gicp"
    return None


KISS_MIN_VOXEL = 5e-3  # KISSMatcherConfig refuses a smaller voxel


def kiss_small_gicp_pair(src, ref, voxel_size: float, threads: int = 2) -> np.ndarray:
    """KISS-Matcher's global registration, then small_gicp's GICP: ``src (N, 3)`` onto ``ref (M, 3)`` →
    ``(4, 4)``, as their documentation sets them: KISS-Matcher at ``resolution = voxel_size`` (its
    ``KISSMatcherConfig(voxel)``: normals 3×, FPFH 5× the voxel), small_gicp's ``align`` with GICP,
    ``downsampling_resolution = voxel_size`` and a correspondence distance of 4× (its example's 0.25 m and
    1.0 m). KISS-Matcher refuses voxels under 5 mm (it assumes metres), so a smaller one is taken in a unit 10ⁿ
    times smaller (every size of its config is a multiple of the voxel, so this changes nothing else). Both
    take coordinates as given: far from the origin (a national grid), shift the clouds first (KISS-Matcher
    works in float32, small_gicp's voxel grid drops points beyond its 21-bit range)."""
    import kiss_matcher
    import small_gicp
    src, ref = np.asarray(src, np.float64)[:, :3], np.asarray(ref, np.float64)[:, :3]
    unit = 10.0 ** max(0, int(np.ceil(np.log10(KISS_MIN_VOXEL / voxel_size))))
    matcher = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel_size * unit))
    solution = matcher.estimate((src * unit).astype(np.float32), (ref * unit).astype(np.float32))
    init = np.eye(4)
    if solution.valid:
        init[:3, :3], init[:3, 3] = np.asarray(solution.rotation), np.asarray(solution.translation) / unit
    result = small_gicp.align(ref, src, init, registration_type="GICP", downsampling_resolution=voxel_size,
                              max_correspondence_distance=4 * voxel_size, num_threads=threads)
    return np.asarray(result.T_target_source)
