"""Which pairs of many scans to register, whatever their file order: a cheap overlap estimate for every pair
(:func:`overlap_scores`), then each scan's best ``k`` plus a maximum spanning tree (:func:`select_pairs`):
O(S·k) registrations instead of O(S²).

The estimate is a bag of words of local shape, as image retrieval's (Sivic & Zisserman 2003): the SPFH
(:mod:`rpmnet_jax.classical.fpfh`, Darboux-frame angles, rotation invariant) of ``keypoints`` seeded points per
scan over every ``stride``-th point within ``radius``; a vocabulary of ``words`` centres by k-means over a
sample of them from all scans; per scan the share of its keypoints nearest each word; for a pair the
intersection of their histograms (``Σ_w min(h_i, h_j)``, in ``[0, 1]``). Scans seen from near viewpoints see
the same parts of the surface, so their histograms agree.

Measured (issue 37), scans prepared as ``align_scans`` prepares them. recall@k: share of each scan's true ``k``
best partners (most points within 2 voxels under the true poses) among its ``k`` best-scored; ≥50%: share of
the pairs :func:`select_pairs` gives at ``k = 4`` whose true overlap is at least half; one core, CPU seconds:

===========================  ============  ===========  =====  ======  =======
set (scans)                  estimator     recall@4/8   ≥50%   cost    seconds
===========================  ============  ===========  =====  ======  =======
simulated range scans (60)   bag of words  0.55 / 0.62  95%    O(S)    0.8
..                           pooled FPFH   0.35 / 0.46  83%    O(S)    0.6
..                           FPFH matches  0.32 / 0.38  66%    O(S²)   3.7
..                           FPFH+RANSAC   0.59 / 0.65  98%    O(S²)   6.3
simulated range scans (240)  bag of words  0.54 / 0.63  99%    O(S)    2.6
bunny (10)                   bag of words  0.65 / 0.91  63%    O(S)    0.3
===========================  ============  ===========  =====  ======  =======

FPFH+RANSAC: a coarse registration of 300 keypoints per pair, scored by its fitness (≈75 s at 240 scans).
Pooled network features are not rotation invariant (they see coordinates): a turned copy of a scan scored below
all 59 others. At ``k = 6`` the selection holds about 3.8·S pairs, 90–99% of them overlapping by half. The estimator
and ``k`` (``ScanOptions.neighbours``) were chosen on these sets (tuning data: numbers on that data are not held-out);
the constants below are not recorded as tuned.
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.geometry import cloud, kdtree, sampling
from rpmnet_jax.classical import fpfh
from rpmnet_jax.pose_graphs import pose_graph

WORDS = 128  # vocabulary size
KEYPOINTS = 1000  # descriptors per scan
RELATIVE_RADIUS = 0.15  # descriptor radius, share of the median robust scan radius (7.5 default voxels)
MAX_NN = 32  # neighbours per descriptor
STRIDE = 4  # the neighbours are among every STRIDE-th point
VOCABULARY_SAMPLE = 8192  # descriptors the vocabulary is fitted on, drawn evenly from all scans
KMEANS_ITERATIONS = 15


def keypoint_spfh(points: np.ndarray, normals: np.ndarray, radius: float, *, keypoints: int = KEYPOINTS,
                  max_nn: int = MAX_NN, stride: int = STRIDE, seed: int = 0) -> np.ndarray:
    """SPFH ``(min(keypoints, V), 33)`` of seeded rows of ``points, normals (V, 3)``, each over its ``max_nn``
    nearest points within ``radius`` among every ``stride``-th row (itself excluded). The rows depend on ``V``
    and ``seed`` only: a rotated scan gets the same keypoints and the same descriptors."""
    rows = sampling.sample_indices(np.random.default_rng(seed), len(points), keypoints)
    centres, around, around_normals = points[rows], points[::stride], normals[::stride]
    k = min(max_nn + 1, len(around))
    dist, idx = kdtree.KdTree(around).query(centres, k=k, distance_upper_bound=radius)
    dist, idx = dist.reshape(len(rows), k), idx.reshape(len(rows), k)
    valid = np.isfinite(dist) & (dist > 0)  # the keypoint itself (distance 0) is no neighbour
    own = np.arange(len(rows))[:, None]
    idx = np.concatenate([own, np.where(valid, idx + len(rows), own)], axis=1)
    valid = np.concatenate([np.ones_like(own, bool), valid], axis=1)
    return fpfh.spfh(np.concatenate([centres, around]), np.concatenate([normals[rows], around_normals]), idx, valid)


def _nearest(x: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Row of ``centres (W, D)`` nearest each of ``x (N, D)``: ``(N,)``."""
    return np.argmin(np.einsum("wd,wd->w", centres, centres)[None] - 2.0 * x @ centres.T, axis=1)


def vocabulary(descriptors, words: int = WORDS, *, sample: int = VOCABULARY_SAMPLE,
               iterations: int = KMEANS_ITERATIONS, seed: int = 0) -> np.ndarray:
    """``(min(words, n), D)`` k-means centres (Lloyd, a fixed number of ``iterations`` from seeded rows) of up
    to ``sample`` rows drawn evenly from each array of ``descriptors`` (a list of ``(N_s, D)``)."""
    rng = np.random.default_rng(seed)
    per_scan = max(1, sample // len(descriptors))
    x = np.concatenate([d[sampling.sample_indices(rng, len(d), per_scan)] for d in descriptors])
    centres = x[rng.choice(len(x), min(words, len(x)), replace=False)]
    for _ in range(iterations):
        label = _nearest(x, centres)
        counts = np.bincount(label, minlength=len(centres))
        sums = np.stack([np.bincount(label, x[:, c], len(centres)) for c in range(x.shape[1])], axis=1)
        centres = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], centres)  # empty: kept
    return centres


def word_histograms(descriptors, centres: np.ndarray) -> np.ndarray:
    """``(S, W)``: per array of ``descriptors`` the share of its rows nearest each of ``centres (W, D)``."""
    out = np.stack([np.bincount(_nearest(d, centres), minlength=len(centres)) for d in descriptors]).astype(float)
    return out / np.maximum(out.sum(axis=1, keepdims=True), 1.0)


def intersections(histograms: np.ndarray, chunk: int = 64) -> np.ndarray:
    """``(S, S)`` histogram intersection ``Σ_w min(h_i, h_j)`` of the rows of ``histograms (S, W)``."""
    h = np.asarray(histograms, np.float64)
    return np.concatenate([np.minimum(h[i:i + chunk, None], h[None]).sum(-1) for i in range(0, len(h), chunk)])


def overlap_scores(scans, *, words: int = WORDS, keypoints: int = KEYPOINTS, radius: float | None = None,
                   max_nn: int = MAX_NN, stride: int = STRIDE, seed: int = 0) -> np.ndarray:
    """``(S, S)`` symmetric scores in ``[0, 1]`` (1 on the diagonal), higher where two of ``scans`` (a list of
    :class:`~rpmnet_jax.pair_edges.edges.Scan`) are more likely to overlap: the intersection of their bags of SPFH
    words (module docstring). Rotation invariant per scan; the vocabulary is fitted on these scans, so a score
    depends on the whole set. ``radius``: caller's units, default ``RELATIVE_RADIUS`` × the median robust scan
    radius. Deterministic for a ``seed``."""
    if len(scans) < 2:
        raise ValueError(f"need at least two scans, got {len(scans)}")
    if radius is None:
        radius = RELATIVE_RADIUS * float(np.median([cloud.robust_radius(s.points) for s in scans]))
    descriptors = [np.sqrt(keypoint_spfh(s.points, s.normals, radius, keypoints=keypoints, max_nn=max_nn,
                                         stride=stride, seed=seed)) for s in scans]  # Hellinger: sqrt of counts
    return intersections(word_histograms(descriptors, vocabulary(descriptors, words, seed=seed)))


def _spanning_tree(scores: np.ndarray) -> list:
    """Maximum spanning tree of ``scores (S, S)`` (:func:`rpmnet_jax.pose_graphs.pose_graph.spanning_forest`):
    ``[(i, j)]``, ``i < j``; ties go to the lower pair."""
    i, j = np.triu_indices(len(scores), 1)
    tree = pose_graph.spanning_forest(len(scores), np.stack([i, j], axis=1), scores[i, j])
    return [(int(a), int(b)) for a, b in zip(i[tree], j[tree])]


def bridging_pairs(scores, labels, tried, k: int) -> list:
    """Pairs ``[(i, j), ...]``, ``i < j``, sorted, none of ``tried``: each scan outside the largest group of
    ``labels (S,)`` (ties: the lowest label) with its ``k`` best-scored partners in other groups (``scores (S, S)``,
    ties to the lower index). Where the best ``k`` of :func:`select_pairs` left the scans in separate groups,
    the next best partners across them."""
    labels = np.asarray(labels)
    scores = _symmetric(scores)
    largest = int(np.argmax(np.bincount(labels)))
    out = set()
    for i in np.flatnonzero(labels != largest):
        add_partners(out, scores[i], int(i), labels != labels[i], tried, k)
    return sorted(out)


def _symmetric(scores) -> np.ndarray:
    scores = np.asarray(scores, np.float64)
    return 0.5 * (scores + scores.T)


def add_partners(out: set, row: np.ndarray, i: int, allowed, tried, k: int) -> None:
    """Adds to ``out`` the pairs of scan ``i`` with its ``k`` best by ``row (S,)`` where ``allowed (S,)``, ties
    to the lower index, skipping itself and the pairs already in ``tried`` or ``out``."""
    picked = 0
    for j in np.argsort(-np.where(allowed, row, -np.inf), kind="stable"):
        if picked == k or not allowed[j]:
            return
        pair = (min(i, int(j)), max(i, int(j)))
        if j == i or pair in tried or pair in out:
            continue
        out.add(pair)
        picked += 1


def best_partners(scores, k: int):
    """``partners(scan) -> [scan, ...]``: its ``k`` best-scored partners by ``scores (S, S)`` (made symmetric),
    best first, ties to the lower index."""
    scores = 0.5 * (np.asarray(scores, np.float64) + np.asarray(scores, np.float64).T)

    def partners(i: int) -> list:
        order = [int(j) for j in np.argsort(-scores[i], kind="stable") if j != i]
        return order[:k]
    return partners


def select_pairs(scores, k: int) -> list:
    """Pairs ``[(i, j), ...]`` to register, ``i < j``, sorted: each scan with its ``k`` best-scored partners
    (``scores (S, S)`` symmetric, higher = more overlap; ties to the lower index) and the maximum spanning tree
    of ``scores`` (one connected graph even where the best ``k`` leave separate groups). At most ``S·k + S - 1``
    pairs; every scan has at least ``min(k, S - 1)`` partners."""
    scores = np.array(scores, np.float64)
    if scores.ndim != 2 or scores.shape[0] != scores.shape[1] or len(scores) < 2:
        raise ValueError(f"scores must be a square (S, S) array with S >= 2, got shape {scores.shape}")
    if not np.all(np.isfinite(scores)):
        raise ValueError("scores must be finite")
    if int(k) != k or k < 1:
        raise ValueError(f"k must be an integer >= 1, got {k}")
    scores = 0.5 * (scores + scores.T)
    np.fill_diagonal(scores, -np.inf)
    best = np.argsort(-scores, axis=1, kind="stable")[:, :min(int(k), len(scores) - 1)]
    pairs = {(min(a, int(b)), max(a, int(b))) for a, row in enumerate(best) for b in row}
    return sorted(pairs | set(_spanning_tree(scores)))
