"""Where a scanner stood: whether a scan looks taken from a point (its frame origin, as a scanner writes its
points), and whether that point lies inside the scan (a scene seen from inside, not an object in front of it).

A scan is taken from its frame origin when it surrounds it (the origin inside the scan's box, its far points at
least ``SURROUND_RATIO`` × as far as its near ones), or when its points lie farther apart the farther they are from
the origin, as a scanner's angular sampling makes them (the log-log slope of spacing over distance, from the
medians of the near and the far half, at least ``SENSOR_SLOPE``). A whole object centred on its frame origin often
surrounds it too (97 of ModelNet40's 150 test shapes): ``align`` uses the spacing rule alone.
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.geometry import kdtree

# A scan is taken from its frame origin when it surrounds it (the origin inside the scan's box, the far points at
# least SURROUND_RATIO × as far as the near ones: KITTI sweeps 4.5×, statues around a turntable's origin 1.4-2.9×)
# or when its spacing grows with the distance from it (slope at least SENSOR_SLOPE: the desk's RGB-D frames
# 0.53-0.65, simulated room stations 1.8-2.3; statues around their turntable's origin -0.27-0.36, the bunny's
# highest; random subsets of LiDAR sweeps only 0.15-0.33: the subset evens the spacing out). Chosen between those
# (the benchmark's sets, the bunny's 11 scans, the room; tuning data: not held-out)
SURROUND_RATIO = 3.0
SENSOR_SLOPE = 0.45
SENSOR_RANGE_RATIO = 1.5  # an origin far from every point (a national grid's) sees them all at one distance
SLOPE_SAMPLE = 2000  # points whose spacing is measured


def taken_from(points: np.ndarray, origin: np.ndarray, surround: bool = True,
               tree: kdtree.KdTree | None = None) -> bool:
    """Whether ``points (N, 3)`` look taken by a scanner at ``origin (3,)``: they surround it (with ``surround``),
    or their spacing grows with the distance from it (see the module docstring and the constants). Without
    ``surround`` a whole object centred on its origin is never taken for a scan (ModelNet40's test shapes: 97 of
    150 surround their origin, their slopes are at most 0.14). ``tree``: a k-d tree of ``points`` when there is
    one."""
    rows = np.random.default_rng(0).choice(len(points), min(SLOPE_SAMPLE, len(points)), replace=False)
    distance = np.linalg.norm(points[rows] - origin, axis=1)
    near, far = np.quantile(distance, [0.1, 0.9])
    if not far >= SENSOR_RANGE_RATIO * near:
        return False
    if surround and far >= SURROUND_RATIO * near and inside(points, origin):
        return True
    spacing = (tree or kdtree.KdTree(points)).query(points[rows], k=2)[0][:, 1]
    ok = (spacing > 0) & (distance > 0)
    x, y = np.log(distance[ok]), np.log(spacing[ok])
    farther = x > np.median(x)  # medians of the far and the near half: a few stray points do not tilt it
    if farther.all() or not farther.any():
        return False
    rise = np.median(y[farther]) - np.median(y[~farther])
    return bool(rise >= SENSOR_SLOPE * (np.median(x[farther]) - np.median(x[~farther])))


def inside(points: np.ndarray, sensor: np.ndarray) -> bool:
    """Whether ``sensor (3,)`` lies inside the bounding box of ``points (N, 3)`` (of their 1st to 99th percentiles:
    a stray point does not widen it): a scan taken from inside a scene (a room, a street), not of an object in
    front of it."""
    lo, hi = np.quantile(points, [0.01, 0.99], axis=0)
    return bool(np.all((lo < sensor) & (sensor < hi)))
