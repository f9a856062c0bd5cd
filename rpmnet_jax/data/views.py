"""Range-scan-like partial views: the points a camera sees, with self-occlusion (host-side NumPy/SciPy).

The paper's partial protocol keeps one side of a random plane. A scanner instead sees the surface facing it,
minus what the object hides from itself. :func:`view_pair` makes that kind of pair: two viewpoints at most
``max_angle`` apart around the shape, each keeping its visible points (hidden point removal, Katz, Tal and
Basri, "Direct visibility of point sets", SIGGRAPH 2007, as in Open3D's ``hidden_point_removal``).
"""

from __future__ import annotations

import numpy as np
from scipy import spatial


def visible(xyz: np.ndarray, camera: np.ndarray, radius_factor: float = 100.0) -> np.ndarray:
    """Mask ``(N,)`` of the points of ``xyz (N, 3)`` visible from ``camera (3,)`` (hidden point removal).

    Points are flipped through a sphere of radius ``radius_factor`` × the farthest point's distance around the
    camera; the visible ones are those on the convex hull of the flipped points and the camera.
    """
    rel = np.asarray(xyz, np.float64) - np.asarray(camera, np.float64)
    norm = np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-12)
    radius = radius_factor * float(norm.max())
    flipped = rel + 2.0 * (radius - norm) * rel / norm
    cloud = np.concatenate([flipped, np.zeros((1, 3))])
    try:
        hull = spatial.ConvexHull(cloud)
    except spatial.QhullError:  # flat or degenerate shapes: joggle the input
        hull = spatial.ConvexHull(cloud, qhull_options="QJ")
    mask = np.zeros(len(rel) + 1, bool)
    mask[hull.vertices] = True
    return mask[:-1]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def view_directions(rng: np.random.RandomState, max_angle: float) -> tuple[np.ndarray, np.ndarray]:
    """Two unit directions ``(3,)``: the first uniform on the sphere, the second at most ``max_angle`` degrees
    from it (angle uniform in ``[0, max_angle]``, about a uniform axis)."""
    first = _unit(rng.normal(size=3))
    axis = _unit(np.cross(first, _unit(rng.normal(size=3))))
    angle = np.deg2rad(rng.uniform(0.0, max_angle))
    second = first * np.cos(angle) + np.cross(axis, first) * np.sin(angle)
    return first, second


def view_pair(rng: np.random.RandomState, src: np.ndarray, ref: np.ndarray, max_angle: float = 90.0,
              distance: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    """The parts of ``src (N, 6)`` and ``ref (M, 6)`` (same pose) seen by cameras ``distance`` × the shape's
    radius from its centre, in two directions at most ``max_angle`` degrees apart."""
    centre = src[:, :3].mean(axis=0)
    scale = distance * float(np.linalg.norm(src[:, :3] - centre, axis=1).max())
    dir_src, dir_ref = view_directions(rng, max_angle)
    return (src[visible(src[:, :3], centre + scale * dir_src)],
            ref[visible(ref[:, :3], centre + scale * dir_ref)])
