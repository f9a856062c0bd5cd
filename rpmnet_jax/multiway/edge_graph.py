"""Steps 2–3 of :func:`rpmnet_jax.align_scans` on the pair edges as a graph: each classical answer rated by the
edge doubt model and screened, the robust pose graph of the edges, and the scans whose poses rest on doubt.

An edge's ``p_wrong`` (:class:`~rpmnet_jax.pair_edges.edges.Edge`) is set here; edges not rated carry 0 (sure).
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.geometry import visibility
from rpmnet_jax.multiway import edge_doubt
from rpmnet_jax.pose_graphs import pose_graph

WEAK_LINK = 0.5  # × the median balanced fitness of a campaign's pair edges: an edge below it joins scans only where
# stronger edges join them too. Wrong edges of a town whose streets look alike match the ground and little else. On
# 1,000 stations of the simulated site (seed 3, tuning data) the robust graph kept 10 wrong edges, 8 of them
# bridges (no cycle confirms them) that carried groups of 1 to 281 stations: 7 of those 8 and 1 of the 246 right
# bridges lie below 0.5 × the median (0.82). The right pair edges' 5th percentile is 0.66, the wrong ones' median 0.21


def screened(answers_per_pair, max_dist: float, good, reject: bool, visible=None) -> list:
    """Each pair's good answers (``good(edge)``), each with its ``p_wrong``, less those at ``p_wrong ≥
    reject_threshold`` when ``reject`` and those ``visible(edge)`` refuses (an answer that puts one scan in the
    space the other's sensor saw through): ``[[edge, ...] per pair]``."""
    model = edge_doubt.load()
    found = []
    for answers, p in zip(answers_per_pair, edge_doubt.p_wrong_of_pairs(answers_per_pair, max_dist, model)):
        rated = [e._replace(p_wrong=float(q)) for e, q in zip(answers, p)]
        found.append([e for e in rated if good(e) and not (reject and e.p_wrong >= model.reject_threshold)
                      and (visible is None or visible(e))])
    return found


class FreeSpace:
    """``free_space(edge) -> bool``: whether the edge keeps each scan out of the other's free space
    (:mod:`rpmnet_jax.geometry.visibility`, on the scans' grid of ``voxel``: ``points[k] (V_k, 3)``, the only part
    of a scan it keeps), each scan's range image made once; ``free_space.clear(i, j, transform)`` the same for any
    transform of scan ``i`` into scan ``j``'s frame, at ``bar`` (default ``visibility.MAX_FREE_SPACE_SHARE``, an
    answer's). Scans without known sensors pass."""

    def __init__(self, points, sensors, voxel: float):
        self.sensors, self.margin, self.voxel = sensors, visibility.margin(voxel), voxel
        self.points = [p if v is not None else None for p, v in zip(points, sensors)]  # only what is checked
        self.images = {}

    def release_images(self) -> None:
        """Lets the range images go, made again where next needed (~3 ms a scan; a site's 1,000 stations: 250 MB
        held between the stages otherwise)."""
        self.images = {}

    def compact(self) -> None:
        """Lets the range images go and holds the points in float32, its own copies (the registration's scans it
        shared them with go next): a site's finer scans need the memory (1,000 stations: 180 -> 90 MB; the
        rounding, < 0.1 mm at 1 km, lies far inside the check's margin)."""
        self.release_images()
        self.points = [None if p is None else np.asarray(p, np.float32) for p in self.points]

    def image(self, k: int):
        if k not in self.images:
            self.images[k] = visibility.range_image(self.points[k], self.sensors[k], self.voxel)
        return self.images[k]

    def clear(self, i: int, j: int, transform: np.ndarray, bar: float | None = None) -> bool:
        if self.sensors[i] is None or self.sensors[j] is None:
            return True
        bar = visibility.MAX_FREE_SPACE_SHARE if bar is None else bar
        return visibility.violation(self.points[i], self.image(i), self.points[j], self.image(j), transform,
                                    self.margin) <= bar

    def __call__(self, e) -> bool:
        return self.clear(e.source, e.target, e.transform)


def doubt_weights(edges) -> list:
    """``[fitness × (1 − p_wrong), ...]``: how the consensus ranks ``edges`` with ``edge_doubt="weigh"``."""
    return [e.fitness * (1.0 - e.p_wrong) for e in edges]


def resting_on_doubt(num_scans: int, kept_edges, anchor: int, threshold: float | None = None) -> list:
    """The scans whose every path to ``anchor`` over ``kept_edges`` crosses one with ``p_wrong`` at or above
    ``threshold`` (default the edge doubt model's)."""
    threshold = edge_doubt.load().threshold if threshold is None else threshold
    flagged = [e.p_wrong >= threshold for e in kept_edges]
    pairs = [(e.source, e.target) for e in kept_edges]
    return np.flatnonzero(edge_doubt.resting_on_flagged(num_scans, pairs, flagged, anchor)).tolist()


def edge_information(info: np.ndarray, rot_sigma: float, trans_sigma: float) -> np.ndarray:
    """``(inv(info) + C)⁻¹`` with ``C`` the diagonal noise floor, computed without inverting a singular ``info``."""
    c_inv = np.diag([rot_sigma ** -2] * 3 + [trans_sigma ** -2] * 3)
    return c_inv - c_inv @ np.linalg.solve(info + c_inv, c_inv)


def solve(num_scans: int, edges, anchor: int, noise: tuple, seed: int, weights=None) -> tuple:
    """Robust pose graph of ``edges`` (``noise``: the floor's rotation and translation sigmas), its consensus
    ranking them by ``weights`` (default their fitness): (poses ``(S, 4, 4)``, NaN off the anchor's component of
    the kept edges; kept edges of that component; rejected edges)."""
    pairs = [(e.source, e.target) for e in edges]
    used = pose_graph.component(num_scans, pairs, anchor)
    info = [edge_information(e.information, *noise) for e in edges]
    sol = pose_graph.optimize(num_scans, pairs, [e.transform for e in edges], info, anchor,
                              weights=[e.fitness for e in edges] if weights is None else weights, seed=seed)
    rejected = [e for e, ok in zip(edges, sol.inlier) if used[e.source] and not ok]
    kept = [e for e, ok in zip(edges, sol.inlier) if ok]
    nodes = pose_graph.component(num_scans, [(e.source, e.target) for e in kept], anchor)
    poses = np.where(nodes[:, None, None], sol.poses, np.nan)
    return poses, [e for e in kept if nodes[e.source]], rejected


def weak_bar(edges) -> float:
    """:data:`WEAK_LINK` × the median balanced fitness of ``edges`` (0 without edges)."""
    return WEAK_LINK * float(np.median([e.balanced_fitness for e in edges])) if edges else 0.0


def strong_parts(num_scans: int, edges, bar: float) -> np.ndarray:
    """``(S,)`` component labels of the scans joined by the ``edges`` whose balanced fitness is at least ``bar``."""
    return pose_graph.components(num_scans, [(e.source, e.target) for e in edges if e.balanced_fitness >= bar])


def without_weak_links(num_scans: int, poses: np.ndarray, kept, bar: float) -> tuple:
    """A solved graph (``poses (S, 4, 4)``, ``kept`` edges) less its weak links: the kept edges below ``bar``
    (balanced fitness) that join scans no kept edge at or above it joins (:func:`cut`)."""
    labels = strong_parts(num_scans, kept, bar)
    return cut(num_scans, poses, kept, [e.balanced_fitness < bar and labels[e.source] != labels[e.target]
                                        for e in kept])


def cut(num_scans: int, poses: np.ndarray, kept, drop) -> tuple:
    """A solved graph (``poses (S, 4, 4)``, ``kept`` edges) less the kept edges where ``drop`` is true, without
    solving again (another solve would let in other edges that the dropped ones had kept out): only the part with
    the most scans of what stays joined keeps its poses as solved (a dropped bridge moved nothing on that side; a
    dropped edge in a loop did, and the refinement settles that). Returns (poses, NaN off that part; its kept edges; the dropped edges)."""
    if not any(drop):
        return poses, list(kept), []
    stay = [e for e, d in zip(kept, drop) if not d]
    labels = pose_graph.components(num_scans, [(e.source, e.target) for e in stay])
    placed = np.isfinite(poses[:, 0, 0])
    part = int(np.argmax(np.bincount(labels[placed])))
    keep = placed & (labels == part)
    poses = np.where(keep[:, None, None], poses, np.nan)
    return poses, [e for e in stay if keep[e.source]], [e for e, d in zip(kept, drop) if d]


def largest_component(num_scans: int, edges) -> int:
    """The first scan of the largest connected component of ``edges``."""
    labels = pose_graph.components(num_scans, [(e.source, e.target) for e in edges])
    return int(np.argmax(labels == np.argmax(np.bincount(labels))))
