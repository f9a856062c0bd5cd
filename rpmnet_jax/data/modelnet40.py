"""ModelNet40 (PointNet HDF5 release) with the paper's three protocols, host-side NumPy only.

``val`` and ``test`` reproduce the official deterministic test-time transforms exactly: each seeded
transform starts a legacy ``RandomState(idx)`` stream (the official code re-seeds NumPy's global generator
with the sample index; we use a private generator, so callers' global NumPy state is never touched).
``train`` draws every sample from ``RandomState([seed, epoch, idx])``: random per epoch, reproducible.
"""

from __future__ import annotations

import math
import os
from typing import Callable

import h5py
import numpy as np

from rpmnet_jax.data import views as views_lib

PROTOCOLS = ("clean", "noisy", "partial")
SPLITS = ("train", "val", "test")
FOLDER = "modelnet40_ply_hdf5_2048"
_MISSING_HELP = (
    "ModelNet40 comes from the PointNet release `modelnet40_ply_hdf5_2048` (folder with ply_data_*.h5, "
    "shape_names.txt, train_files.txt, test_files.txt). To run without it, generate the synthetic dataset "
    "in the same format: `python -m experiments.make_synthetic --out DIR` and pass DIR as the root "
    "(or use --synthetic in the experiment scripts).")


def resolve_root(root) -> str:
    """The folder holding ``shape_names.txt``: ``root`` itself or ``root/modelnet40_ply_hdf5_2048``."""
    root = os.fspath(root)
    for candidate in (root, os.path.join(root, FOLDER)):
        if os.path.isfile(os.path.join(candidate, "shape_names.txt")):
            return candidate
    if not os.path.isdir(root):
        raise FileNotFoundError(f"dataset folder {root!r} does not exist. {_MISSING_HELP}")
    raise FileNotFoundError(f"{root!r} is not a ModelNet40 folder: no shape_names.txt in it or in "
                            f"{os.path.join(root, FOLDER)!r}. {_MISSING_HELP}")


def read_split(root, subset: str) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``points (N, 2048, 6)`` float32 (xyz + normals), ``labels (N,)`` int64, class names, of a file list."""
    root = resolve_root(root)
    with open(os.path.join(root, "shape_names.txt")) as f:
        names = [line.strip() for line in f if line.strip()]
    list_path = os.path.join(root, f"{subset}_files.txt")
    if not os.path.isfile(list_path):
        raise FileNotFoundError(f"missing file list {list_path!r}. {_MISSING_HELP}")
    with open(list_path) as f:
        files = [line.strip().replace(f"data/{FOLDER}/", "") for line in f if line.strip()]
    points, labels = [], []
    for name in files:
        path = os.path.join(root, name)
        if not os.path.isfile(path):
            raise FileNotFoundError(f"{list_path!r} lists {name!r} but {path!r} does not exist")
        with h5py.File(path, "r") as h5:
            for key in ("data", "label"):
                if key not in h5:
                    raise KeyError(f"{path!r} has no HDF5 dataset {key!r}")
            if "normal" not in h5:
                raise ValueError(f"{path!r} has no 'normal' dataset: RPM-Net needs clouds with normals "
                                 "(the PointNet modelnet40_ply_hdf5_2048 release has them)")
            points.append(np.concatenate([h5["data"][:], h5["normal"][:]], axis=-1).astype(np.float32))
            labels.append(h5["label"][:].reshape(-1).astype(np.int64))
    if not points:
        raise ValueError(f"{list_path!r} lists no files")
    return np.concatenate(points), np.concatenate(labels), names


# --- the official transforms, as functions of an explicit legacy RandomState -------------------------

def write_split(folder, subset: str, points: np.ndarray, labels: np.ndarray, compress: bool = False) -> str:
    """Writes ``points (N, P, 6)`` (xyz + normals, stored in their dtype) and ``labels (N,)`` as
    ``folder/ply_data_{subset}0.h5`` and its ``{subset}_files.txt`` (what :func:`read_split` reads);
    ``compress``: gzip with byte shuffle. Returns the h5 path."""
    folder = os.fspath(folder)
    os.makedirs(folder, exist_ok=True)
    fname = f"ply_data_{subset}0.h5"
    tmp = os.path.join(folder, fname + ".tmp")
    opts = dict(compression="gzip", shuffle=True) if compress else {}
    with h5py.File(tmp, "w") as h5:
        h5.create_dataset("data", data=points[..., :3], **opts)
        h5.create_dataset("normal", data=points[..., 3:], **opts)
        h5.create_dataset("label", data=np.asarray(labels)[:, None].astype(np.uint8))
    os.replace(tmp, os.path.join(folder, fname))
    with open(os.path.join(folder, f"{subset}_files.txt"), "w") as f:
        f.write(f"data/{FOLDER}/{fname}\n")
    return os.path.join(folder, fname)


def write_shape_names(folder, names) -> None:
    """``folder/shape_names.txt``: the category names, a line each (written last, it marks a folder complete)."""
    with open(os.path.join(os.fspath(folder), "shape_names.txt"), "w") as f:
        f.write("\n".join(names) + "\n")


def euler_transform(rng: np.random.RandomState, rot_mag: float, trans_mag: float) -> np.ndarray:
    """Random ``(3, 4)`` float32 transform: Euler angles up to ``rot_mag`` degrees, translation ±trans_mag."""
    ax, ay, az = (rng.uniform() * np.pi * rot_mag / 180.0 for _ in range(3))
    cx, cy, cz, sx, sy, sz = np.cos(ax), np.cos(ay), np.cos(az), np.sin(ax), np.sin(ay), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    trans = rng.uniform(-trans_mag, trans_mag, 3)
    return np.concatenate([rx @ ry @ rz, trans[:, None]], axis=1).astype(np.float32)


def _rotate_rows(vectors: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """``vectors (N, 3) @ rot.T`` summed left to right in the input dtype (bit-exact whatever the BLAS)."""
    return (vectors[:, 0:1] * rot[:, 0] + vectors[:, 1:2] * rot[:, 1]) + vectors[:, 2:3] * rot[:, 2]


def _fma(a, b, c):
    """float32 fused multiply-add ``a * b + c`` (the product is exact in float64)."""
    return (a.astype(np.float64) * b.astype(np.float64) + c).astype(np.float32)


def _rotate_rows_fma(vectors: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """``vectors (N, 3) @ rot.T`` as an FMA chain: the rounding of the official float32 GEMM, on any BLAS."""
    acc = vectors[:, 0:1] * rot[:, 0]
    acc = _fma(vectors[:, 1:2], rot[:, 1], acc)
    return _fma(vectors[:, 2:3], rot[:, 2], acc)


def apply_transform(transform: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Moves ``points (N, 6)`` (xyz and normals) by ``transform (3, 4)``."""
    rot, trans = transform[:3, :3], transform[:3, 3]
    xyz = _rotate_rows_fma(points[:, :3], rot) + trans[None, :]
    normals = _rotate_rows_fma(points[:, 3:6], rot)
    return np.concatenate([xyz, normals], axis=-1)


def inverse_transform(transform: np.ndarray) -> np.ndarray:
    """Inverse of a rigid ``(3, 4)`` transform."""
    rot_t = np.swapaxes(transform[:3, :3], -1, -2)
    trans = _rotate_rows(-transform[None, :3, 3], rot_t)[0]
    return np.concatenate([rot_t, trans[:, None]], axis=-1)


def resample(rng: np.random.RandomState, points: np.ndarray, k: int) -> np.ndarray:
    """``k`` points without repeats if possible, else every point at least once."""
    n = points.shape[0]
    if k <= n:
        return points[rng.choice(n, k, replace=False), :]
    idx = np.concatenate([rng.choice(n, n, replace=False), rng.choice(n, k - n, replace=True)])
    return points[idx, :]


def jitter(rng: np.random.RandomState, points: np.ndarray, scale=0.01, clip=0.05) -> np.ndarray:
    noise = np.clip(rng.normal(0.0, scale=scale, size=(points.shape[0], 3)), a_min=-clip, a_max=clip)
    points = points.copy()
    points[:, :3] += noise
    return points


def crop(rng: np.random.RandomState, points: np.ndarray, p_keep: float) -> np.ndarray:
    """Keeps the points on one side of a random plane, ~``p_keep`` of them."""
    phi = rng.uniform(0.0, 2 * np.pi)
    cos_theta = rng.uniform(-1.0, 1.0)
    theta = np.arccos(cos_theta)
    direction = np.stack((np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)), axis=-1)
    centred = points[:, :3] - np.mean(points[:, :3], axis=0)
    dist = np.dot(centred, direction)
    if p_keep == 0.5:
        mask = dist > 0
    else:
        mask = dist > np.percentile(dist, (1.0 - p_keep) * 100)
    return points[mask, :]


def make_pair(points: np.ndarray, protocol: str, new_stream: Callable[[], np.random.RandomState], *,
              deterministic: bool, num_points: int = 1024, rot_mag: float = 45.0, trans_mag: float = 0.5,
              partial_keep=(0.7, 0.7), views: bool = False) -> dict:
    """One registration pair from a clean cloud ``points (M, 6)``, following the official pipeline.

    ``new_stream()`` is called wherever the official code re-seeds (it may return the same generator when
    not ``deterministic``, i.e. in training, where the official code never re-seeds). ``views`` (partial only,
    not official): each cloud keeps what a camera sees (:func:`views.view_pair`) instead of a half-space crop.
    """
    rng = None
    if protocol == "clean":
        rng = new_stream()  # FixedResampler / Resampler entry point
        if deterministic:
            reps, rem = divmod(num_points, points.shape[0])
            raw = np.concatenate([np.tile(points, (reps, 1)), points[:rem, :]], axis=0)
        else:
            raw = resample(rng, points, num_points)
        src, ref = raw.copy(), raw.copy()
    else:
        raw = points
        src, ref = points.copy(), points.copy()
        if protocol == "partial":
            keep = np.asarray(partial_keep, dtype=np.float32)
            rng = new_stream()
            if views:
                src, ref = views_lib.view_pair(rng, src, ref)
            else:
                src, ref = crop(rng, src, keep[0]), crop(rng, ref, keep[1])
    rng = new_stream()
    igt = euler_transform(rng, rot_mag, trans_mag)
    src = apply_transform(igt, src)
    if protocol != "clean":
        rng = new_stream()
        if protocol == "partial":
            keep = np.asarray(partial_keep, dtype=np.float32)
            sizes = (math.ceil(keep[0] * num_points), math.ceil(keep[1] * num_points))
        else:
            sizes = (num_points, num_points)
        src, ref = resample(rng, src, sizes[0]), resample(rng, ref, sizes[1])
        src, ref = jitter(rng, src), jitter(rng, ref)
    ref = rng.permutation(ref)
    src = rng.permutation(src)
    return {"points_src": src.astype(np.float32), "points_ref": ref.astype(np.float32),
            "transform_gt": inverse_transform(igt).astype(np.float32), "points_raw": raw.astype(np.float32)}


class ModelNet40:
    """Registration pairs from ModelNet40 under one of the paper's protocols.

    Args:
      root: the ``modelnet40_ply_hdf5_2048`` folder (or its parent).
      split: ``train`` (train files, first 20 categories), ``val`` (test files, first 20), ``test`` (test
        files, last 20: the paper's unseen categories).
      protocol: ``clean``, ``noisy`` or ``partial``.
      seed: training randomness; ``None`` draws fresh entropy once. Ignored for ``val``/``test``.
      categories: override the category names to keep (filtered in file order).
      views_share: ``train`` only, partial only: the share of pairs cut as camera views with self-occlusion
        (:mod:`views`) instead of the paper's half-space crop (0: the paper's protocol).

    ``ds[i]`` → dict of ``points_src (J, 6)``, ``points_ref (K, 6)``, ``transform_gt (3, 4)`` (maps source
    onto reference), ``points_raw``, ``label``, ``idx``; ``ds.get(i, epoch)`` draws training samples of an epoch.
    """

    def __init__(self, root, split: str, protocol: str, num_points: int = 1024, rot_mag: float = 45.0,
                 trans_mag: float = 0.5, partial_keep=(0.7, 0.7), seed: int | None = None, categories=None,
                 views_share: float = 0.0):
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        if protocol not in PROTOCOLS:
            raise ValueError(f"protocol must be one of {PROTOCOLS}, got {protocol!r}")
        if num_points < 1:
            raise ValueError(f"num_points must be >= 1, got {num_points}")
        if not 0.0 <= views_share <= 1.0:
            raise ValueError(f"views_share must be in [0, 1], got {views_share}")
        if views_share and (split != "train" or protocol != "partial"):
            raise ValueError(f"views_share applies to partial training pairs only, not to {split} {protocol}")
        points, labels, names = read_split(root, "train" if split == "train" else "test")
        if categories is None:
            categories = names[:20] if split in ("train", "val") else names[20:]
        unknown = [c for c in categories if c not in names]
        if unknown:
            raise ValueError(f"unknown categories {unknown}; shape_names.txt has {names}")
        keep = np.isin(labels, [names.index(c) for c in categories])
        self.points, self.labels = points[keep], labels[keep]
        self.class_names, self.categories = names, list(categories)
        self.split, self.protocol = split, protocol
        self.num_points, self.rot_mag, self.trans_mag = num_points, rot_mag, trans_mag
        self.partial_keep = tuple(partial_keep)
        self.views_share = float(views_share)
        self.seed = int(np.random.SeedSequence().entropy % 2**31) if seed is None else int(seed)

    @property
    def deterministic(self) -> bool:
        return self.split != "train"

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def get(self, idx: int, epoch: int = 0, draw: int | None = None) -> dict:
        """Sample ``idx``; for training, its draw of ``epoch`` seeded by ``draw`` (default ``idx``)."""
        if not 0 <= idx < len(self):
            raise IndexError(f"index {idx} out of range for {len(self)} samples")
        use_views = False
        if self.deterministic:
            new_stream = lambda: np.random.RandomState(idx)
        else:
            rng = np.random.RandomState([self.seed, int(epoch), idx if draw is None else int(draw)])
            new_stream = lambda: rng
            use_views = bool(self.views_share) and rng.uniform() < self.views_share
        sample = make_pair(self.points[idx], self.protocol, new_stream, deterministic=self.deterministic,
                           num_points=self.num_points, rot_mag=self.rot_mag, trans_mag=self.trans_mag,
                           partial_keep=self.partial_keep, views=use_views)
        sample["label"] = self.labels[idx]
        sample["idx"] = np.int32(idx)
        return sample

    def __getitem__(self, idx: int) -> dict:
        return self.get(int(idx))
