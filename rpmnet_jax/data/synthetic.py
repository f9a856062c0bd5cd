"""Synthetic shapes with analytic normals, written in the ModelNet40 HDF5 layout.

Five families (superquadrics, boxes, cylinders, tori, composite tables) × 8 variants = 40 categories,
interleaved so that both halves of the category list (the train/val and test halves) hold every family.
Each cloud is centred and scaled into the unit sphere, then randomly rotated, as ModelNet shapes are
normalised.
"""

from __future__ import annotations

import os

import numpy as np

from rpmnet_jax.data import modelnet40
from rpmnet_jax.ops import se3

FAMILIES = ("superquadric", "box", "cylinder", "torus", "table")
NUM_VARIANTS = 8
CATEGORY_NAMES = [f"{FAMILIES[c % 5]}_{c // 5}" for c in range(5 * NUM_VARIANTS)]


def _signed_pow(x, e):
    return np.sign(x) * np.abs(x) ** e


def superquadric(rng: np.random.Generator, n: int, variant: int) -> np.ndarray:
    """Superquadric surface points and normals ``(n, 6)``; exponents grow boxier with the variant."""
    a, b, c = rng.uniform(0.4, 1.0, 3)
    e1, e2 = np.clip(0.3 + 0.2 * variant + rng.uniform(-0.1, 0.1, 2), 0.2, 1.8)
    eta = np.arcsin(rng.uniform(-1, 1, n))
    omega = rng.uniform(-np.pi, np.pi, n)
    ce, se, co, so = np.cos(eta), np.sin(eta), np.cos(omega), np.sin(omega)
    xyz = np.stack([a * _signed_pow(ce, e1) * _signed_pow(co, e2), b * _signed_pow(ce, e1) * _signed_pow(so, e2),
                    c * _signed_pow(se, e1)], -1)
    normals = np.stack([_signed_pow(ce, 2 - e1) * _signed_pow(co, 2 - e2) / a,
                        _signed_pow(ce, 2 - e1) * _signed_pow(so, 2 - e2) / b, _signed_pow(se, 2 - e1) / c], -1)
    return np.concatenate([xyz, normals], -1)


def _box_surface(rng, n, size, centre=(0.0, 0.0, 0.0), faces=range(6)):
    size = np.asarray(size, float)
    faces = list(faces)
    areas = np.array([np.prod(np.delete(size, f // 2)) for f in faces])
    choice = rng.choice(len(faces), n, p=areas / areas.sum())
    out = np.empty((n, 6))
    for j, f in enumerate(faces):
        m = choice == j
        axis, sign = f // 2, 1.0 if f % 2 else -1.0
        pts = rng.uniform(-0.5, 0.5, (m.sum(), 3)) * size
        pts[:, axis] = sign * size[axis] / 2
        normal = np.zeros(3)
        normal[axis] = sign
        out[m, :3], out[m, 3:] = pts + centre, normal
    return out


def box(rng: np.random.Generator, n: int, variant: int) -> np.ndarray:
    """Cuboid with face normals; the variant sets how elongated it is."""
    size = rng.uniform(0.3, 1.0, 3) * np.array([1.0, 1.0, 1.0 + 0.25 * variant])
    return _box_surface(rng, n, size)


def _cylinder_surface(rng, n, radius, height, centre=(0.0, 0.0, 0.0), caps=(True, True)):
    side, cap = 2 * np.pi * radius * height, np.pi * radius**2
    parts = np.array([side, cap * caps[0], cap * caps[1]])
    choice = rng.choice(3, n, p=parts / parts.sum())
    theta = rng.uniform(0, 2 * np.pi, n)
    out = np.empty((n, 6))
    s = choice == 0
    out[s] = np.stack([radius * np.cos(theta[s]), radius * np.sin(theta[s]), rng.uniform(-height / 2, height / 2, s.sum()),
                       np.cos(theta[s]), np.sin(theta[s]), np.zeros(s.sum())], -1)
    for k, z in ((1, -1.0), (2, 1.0)):
        m = choice == k
        r = radius * np.sqrt(rng.uniform(0, 1, m.sum()))
        out[m] = np.stack([r * np.cos(theta[m]), r * np.sin(theta[m]), np.full(m.sum(), z * height / 2),
                           np.zeros(m.sum()), np.zeros(m.sum()), np.full(m.sum(), z)], -1)
    out[:, :3] += centre
    return out


def cylinder(rng: np.random.Generator, n: int, variant: int) -> np.ndarray:
    """Closed cylinder; the variant sets height over radius."""
    radius = rng.uniform(0.3, 0.6)
    return _cylinder_surface(rng, n, radius, radius * (0.5 + 0.5 * variant) * rng.uniform(0.8, 1.2))


def torus(rng: np.random.Generator, n: int, variant: int) -> np.ndarray:
    """Torus sampled uniformly by area (rejection on the tube angle)."""
    big = 1.0
    small = big * (0.15 + 0.08 * variant) * rng.uniform(0.9, 1.1)
    v = np.empty(0)
    while v.size < n:
        cand = rng.uniform(0, 2 * np.pi, 2 * n)
        keep = rng.uniform(0, big + small, 2 * n) < big + small * np.cos(cand)
        v = np.concatenate([v, cand[keep]])
    v, u = v[:n], rng.uniform(0, 2 * np.pi, n)
    xyz = np.stack([(big + small * np.cos(v)) * np.cos(u), (big + small * np.cos(v)) * np.sin(u), small * np.sin(v)], -1)
    normals = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], -1)
    return np.concatenate([xyz, normals], -1)


def table(rng: np.random.Generator, n: int, variant: int) -> np.ndarray:
    """Composite: a box top on four cylinder legs (variants: proportions)."""
    w, d = rng.uniform(0.8, 1.2), rng.uniform(0.5, 1.0)
    top_t, leg_h, leg_r = 0.08 + 0.01 * variant, 0.4 + 0.08 * variant, 0.04 + 0.005 * variant
    top = (w * d * 2 + 2 * top_t * (w + d))
    leg = 2 * np.pi * leg_r * leg_h + np.pi * leg_r**2
    counts = rng.multinomial(n, np.array([top] + [leg] * 4) / (top + 4 * leg))
    parts = [_box_surface(rng, counts[0], (w, d, top_t), (0, 0, leg_h / 2 + top_t / 2))]
    for i, (sx, sy) in enumerate([(1, 1), (1, -1), (-1, 1), (-1, -1)]):
        centre = (sx * (w / 2 - 2 * leg_r), sy * (d / 2 - 2 * leg_r), 0.0)
        parts.append(_cylinder_surface(rng, counts[i + 1], leg_r, leg_h, centre, caps=(True, False)))
    return np.concatenate(parts)


_GENERATORS = {"superquadric": superquadric, "box": box, "cylinder": cylinder, "torus": torus, "table": table}


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation ``(3, 3)`` (normalised Gaussian quaternion)."""
    return se3.quaternion_to_matrix(rng.normal(size=4))


def sample_shape(rng: np.random.Generator, label: int, n: int = 2048) -> np.ndarray:
    """One shape of category ``label`` as ``(n, 6)`` float32: xyz in the unit sphere, unit normals."""
    family, variant = FAMILIES[label % 5], label // 5
    cloud = _GENERATORS[family](rng, n, variant)
    xyz, normals = cloud[:, :3], cloud[:, 3:]
    xyz = xyz - (xyz.max(0) + xyz.min(0)) / 2
    xyz = xyz / np.linalg.norm(xyz, axis=1).max()
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    rot = random_rotation(rng)
    return np.concatenate([xyz @ rot.T, normals @ rot.T], -1).astype(np.float32)


def ring_views(world, count: int) -> tuple[list, np.ndarray]:
    """``count`` partial views ``(N_i, 3)`` of the centred points ``world (N, 3)`` (~0.2 across), each the side
    seen from a direction ``360°/count`` further round the z axis, in its own frame (rotated by up to ~``3
    count``°, moved by a few mm), and their poses ``(count, 4, 4)`` (view → world): neighbours overlap most, every
    view overlaps the next. Made for scan-set tests and for fitting the edge doubt model."""
    from scipy.spatial.transform import Rotation

    world = np.asarray(world, np.float64)
    clouds, poses = [], []
    for k in range(count):
        angle = 2 * np.pi * k / count
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_euler("xyz", [2 * k, 3 * k, -2 * k], degrees=True).as_matrix()
        pose[:3, 3] = [0.004 * k, -0.002 * k, 0.003 * k]
        keep = world[:, :2] @ [np.cos(angle), np.sin(angle)] > -0.01
        clouds.append((world[keep] - pose[:3, 3]) @ pose[:3, :3])
        poses.append(pose)
    return clouds, np.stack(poses)


def make_split(num: int, seed: int, n: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """``num`` shapes ``(num, n, 6)`` cycling through the 40 categories, and their labels."""
    labels = np.arange(num) % len(CATEGORY_NAMES)
    shapes = [sample_shape(np.random.default_rng([seed, i]), int(lab), n) for i, lab in enumerate(labels)]
    return (np.stack(shapes) if shapes else np.zeros((0, n, 6), np.float32)), labels


def write_dataset(out_dir, num_train: int = 400, num_test: int = 100, seed: int = 0, n: int = 2048) -> str:
    """Writes a ModelNet40-format folder ``out_dir/modelnet40_ply_hdf5_2048``; returns its path."""
    folder = os.path.join(os.fspath(out_dir), "modelnet40_ply_hdf5_2048")
    for subset, num, sub_seed in (("train", num_train, seed * 2 + 1), ("test", num_test, seed * 2 + 2)):
        clouds, labels = make_split(num, sub_seed, n)
        modelnet40.write_split(folder, subset, clouds, labels)
    modelnet40.write_shape_names(folder, CATEGORY_NAMES)
    return folder


def ensure_dataset(out_dir, num_train: int = 400, num_test: int = 100, seed: int = 0) -> str:
    """The synthetic set at ``out_dir`` (written there first if it is not there yet); returns ``out_dir``."""
    if not os.path.isfile(os.path.join(os.fspath(out_dir), "modelnet40_ply_hdf5_2048", "shape_names.txt")):
        write_dataset(out_dir, num_train, num_test, seed=seed)
    return os.fspath(out_dir)
