"""The knobs of :func:`rpmnet_jax.align_scans` as one frozen options object, checked when it is made."""

from __future__ import annotations

import dataclasses

from rpmnet_jax import input_checks as checks
from rpmnet_jax.multiway import sizes

REFINES = ("icp", "joint", "none")
EDGE_DOUBTS = ("weigh", "reject", "off")


@dataclasses.dataclass(frozen=True)
class ScanOptions:
    """How :func:`rpmnet_jax.align_scans` registers many scans (see :mod:`rpmnet_jax.multiway.scan_alignment`).

    Sizes (caller's units; ``None``: from the data, :mod:`rpmnet_jax.multiway.sizes`): ``voxel_size`` (default 2%
    of the median robust scan radius for objects, 1% for scans seen from inside a scene),
    ``max_correspondence_distance`` (the inlier threshold of fitness and overlap, default 2.5 voxels).
    Candidate pairs: every pair up to ``all_pairs_up_to`` scans, beyond that each scan with its ``neighbours``
    best partners by a cheap overlap estimate (whatever the order of the scans), plus a spanning tree. Pair
    edges: ``classical`` (FPFH + RANSAC, then a short ICP) on every candidate pair, the
    network on the candidate pairs those leave between separate groups of scans (without ``classical``: the
    network on every candidate pair): ``num_points`` per scan and ``num_iters`` network iterations,
    ``batch_size`` pairs per call. ``edge_doubt`` (:mod:`rpmnet_jax.multiway.edge_doubt`): ``"weigh"`` ranks the
    classical answers in the pose graph's consensus by fitness × (1 − ``p_wrong``), ``"reject"`` also keeps out
    those at ``p_wrong`` ≥ the model's ``reject_threshold``, ``"off"`` ranks by fitness alone; the report of scans
    resting on likely wrong edges is made in every case.
    Accepting an edge: fitness ≥ ``min_fitness`` (pair edges, and a scan's placement onto the merged placed scans) or ≥
    ``min_overlap`` (a placed scan's edges to each scan placed before it, and refinement edges: one scan may overlap a
    few), a pair edge's balanced fitness (each normal direction weighing the same, so a scene's ground cannot carry
    it) ≥ ``min_balanced_fitness`` where the scans are a scene's (seen from inside) and the median scan holds much in
    one normal direction (``multiway.sizes.DOMINANT_SHARE``: a ground), median point-to-plane distance ≤
    ``max_plane_residual`` × the correspondence distance (default by kind:
    :func:`rpmnet_jax.multiway.sizes.plane_residual`; the object bar 0.1 chosen on the 10 bunny scans, between their
    right answers, ≤ 0.06×, and wrong ones, ≥ 0.13×: tuning data, numbers on that data are not held-out). Which
    defaults saw which data: ``docs/tuning.md``.
    Refinement: ``refine="joint"`` (default) moves all poses together on the points of every pair predicted to
    overlap by ``min_overlap``, of those each scan's ``refine_neighbours`` most overlapping ones (1,000 points per
    scan of a pair; multi-view point-to-plane,
    :mod:`rpmnet_jax.pose_graphs.joint_refine`); ``refine="icp"``: ``refine_rounds`` rounds of pairwise ICP edges
    on up to ``refine_points`` points for those pairs, each round a robust pose graph. Edge noise floor:
    ``edge_sigma_deg`` (rotation) and ``edge_sigma_fraction`` × the correspondence distance (translation), per
    axis. ``refine_voxel_size`` (caller's units; ``None``: the registration's scans): the refinement (``joint`` or
    ``icp``) runs once on the registration's scans, then again on the scans prepared at this voxel, its
    correspondence distance scaled with it (a scene
    registered at its coarse default voxel, refined at a finer one: the simulated town's held-out 100 stations,
    median drift 7.4 → 0.6 cm at 0.2 m, ``docs/real_scans.md``). Deterministic for a ``seed``.
    """

    classical: bool = True  # pair edges; chosen on the 10 bunny scans (tuning data: numbers on them are not held-out)
    # weigh: chosen on the 'held-out' rings of a box, checked on the bunny and other scan sets (tuning data: numbers
    # on that data are not held-out)
    edge_doubt: str = "weigh"
    all_pairs_up_to: int = 12
    # 6 and refine_neighbours 8: chosen on 60 and 240 simulated range scans, the 60-scan bunny and horse campaign sets
    # and the 10 bunny scans (tuning data: numbers on that data are not held-out)
    neighbours: int = 6
    voxel_size: float | None = None  # sizes
    max_correspondence_distance: float | None = None
    min_fitness: float = 0.3  # accepting an edge
    min_overlap: float = 0.2
    max_plane_residual: float | None = None  # None: 0.1 for objects, 0.06 for scenes (multiway.sizes)
    min_balanced_fitness: float = sizes.BALANCED_FITNESS  # pair edges and placements of a scene with a ground
    num_points: int = 256  # the network's pair edges
    num_iters: int = 3
    batch_size: int = 16
    refine: str = "joint"  # refinement; chosen on 12 simulated and the 10 real bunny scans (tuning data: not held-out)
    refine_rounds: int = 2
    refine_neighbours: int = 8
    refine_points: int = 3000
    refine_voxel_size: float | None = None
    edge_sigma_deg: float = 0.25  # edge noise floor
    edge_sigma_fraction: float = 0.1
    seed: int = 0

    def __post_init__(self):
        for name in ("voxel_size", "max_correspondence_distance", "refine_voxel_size"):
            checks.require_positive(f"ScanOptions.{name}", getattr(self, name), optional=True)
        checks.require_positive("ScanOptions.max_plane_residual", self.max_plane_residual, optional=True)
        for name in ("edge_sigma_deg", "edge_sigma_fraction"):
            checks.require_positive(f"ScanOptions.{name}", getattr(self, name))
        for name, least in (("num_points", 3), ("num_iters", 1), ("batch_size", 1), ("all_pairs_up_to", 2),
                            ("neighbours", 1), ("refine_rounds", 0), ("refine_neighbours", 1), ("refine_points", 3)):
            checks.require_at_least(f"ScanOptions.{name}", getattr(self, name), least)
        for name in ("min_fitness", "min_overlap", "min_balanced_fitness"):
            checks.require_fraction(f"ScanOptions.{name}", getattr(self, name))
        checks.require_choice("ScanOptions.refine", self.refine, REFINES)
        checks.require_choice("ScanOptions.edge_doubt", self.edge_doubt, EDGE_DOUBTS)
