"""Shared test helpers: fixture location, float64 context, random clouds and poses, random network weights,
synthetic scans."""

import contextlib
import os
import pathlib

import jax
import numpy as np
import pytest

from rpmnet_jax.ops import se3

FIXTURES = pathlib.Path(os.environ.get("RPMNET_FIXTURES",
                                       pathlib.Path(__file__).resolve().parents[2] / "shared" / "fixtures"))
DATA = FIXTURES.parent / "data"


_CACHE_ENVS = ("JAX_COMPILATION_CACHE_DIR", "RPMNET_COMPILATION_CACHE")  # JAX's, and the one the project's CLIs read


@pytest.hookimpl(trylast=True)  # after pytest's tmp_path plugin has set up its folder
def pytest_configure(config):
    """One persistent compilation cache per test run, the CLI subprocesses' included (never the user's own
    cache): the tests that build the same computation (the training step, the float64 gradients of a fixture)
    compile it once. The folder lies in pytest's temporary folder, which pytest prunes."""
    folder = str(config._tmp_path_factory.getbasetemp() / "xla-cache")
    config._rpmnet_jax_saved = ({k: os.environ.get(k) for k in _CACHE_ENVS}, jax.config.jax_compilation_cache_dir)
    for key in _CACHE_ENVS:
        os.environ[key] = folder
    jax.config.update("jax_compilation_cache_dir", folder)


def pytest_unconfigure(config):
    saved = getattr(config, "_rpmnet_jax_saved", None)
    if saved is None:
        return
    env, setting = saved
    for key, value in env.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    jax.config.update("jax_compilation_cache_dir", setting)


def require(path, what: str) -> pathlib.Path:
    """``path`` if it exists; else the test skips, or fails when ``CI=true`` (CI must never pass without it)."""
    path = pathlib.Path(path)
    if not path.exists():
        unavailable(f"{what} not found at {path}", "the test data must be there")
    return path


def unavailable(message: str, why: str = "what the test needs must be installed") -> None:
    """Skips the test, or fails it when ``CI=true`` (CI must never pass without what it needs)."""
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail(f"{message} (CI=true: {why})")
    pytest.skip(message)


def require_fixtures():
    return require(FIXTURES, "parity fixtures (set RPMNET_FIXTURES to the shared/fixtures folder)")


@contextlib.contextmanager
def float64():
    """Enables float64 inside the block (for finite-difference gradient checks)."""
    if hasattr(jax, "enable_x64"):
        with jax.enable_x64(True):
            yield
    else:  # older JAX
        from jax.experimental import enable_x64
        with enable_x64():
            yield


class _Payload:
    """Unpickling this runs ``touch marker``: what a crafted checkpoint would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def crafted_checkpoint(path, marker) -> str:
    """A ``.pth`` whose unpickling would create ``marker``, next to real tensors (needs torch)."""
    import torch

    torch.save({"state_dict": {"feat_extractor.prepool.0.bias": torch.zeros(3)}, "x": _Payload(marker)}, path)
    return str(path)


def random_cloud(rng: np.random.Generator, batch: int, n: int, scale: float = 1.0) -> np.ndarray:
    """``(batch, n, 6)`` float32 points in a cube with random unit normals."""
    xyz = rng.uniform(-scale, scale, size=(batch, n, 3))
    normals = rng.normal(size=(batch, n, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return np.concatenate([xyz, normals], axis=-1).astype(np.float32)


def random_pose(rng: np.random.Generator, trans: float = 0.1) -> np.ndarray:
    """``(4, 4)`` uniformly random rotation with a normal translation of scale ``trans``."""
    from scipy.spatial.transform import Rotation

    pose = np.eye(4)
    pose[:3, :3] = Rotation.random(random_state=rng.integers(1 << 30)).as_matrix()
    pose[:3, 3] = rng.normal(size=3) * trans
    return pose


def random_transform(rng: np.random.Generator, batch: int, trans_mag: float = 0.5) -> np.ndarray:
    """``(batch, 3, 4)`` uniformly random rotations with translations in ±trans_mag."""
    rot = se3.quaternion_to_matrix(rng.normal(size=(batch, 4)))
    trans = rng.uniform(-trans_mag, trans_mag, size=(batch, 3, 1))
    return np.concatenate([rot, trans], axis=-1)


def asymmetric_shape(seed: int = 0, n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """``points, normals (n, 3)`` of a synthetic shape with no rotational symmetry: a box, an ellipsoid-like
    superquadric and a small cylinder at three different offsets, in the unit sphere."""
    from rpmnet_jax.data import synthetic

    rng = np.random.default_rng(seed)
    parts = [(1, 0.5, [0.0, 0.0, 0.0]), (0, 0.3, [0.55, 0.25, 0.1]), (2, 0.2, [-0.3, 0.45, -0.35])]
    pts, nrm = [], []
    for label, size, offset in parts:
        cloud = synthetic.sample_shape(rng, label, n // 3 + 1)
        pts.append(cloud[:, :3] * size + np.asarray(offset))
        nrm.append(cloud[:, 3:])
    pts, nrm = np.concatenate(pts)[:n].astype(np.float64), np.concatenate(nrm)[:n].astype(np.float64)
    pts -= pts.mean(0)
    return pts / np.linalg.norm(pts, axis=1).max(), nrm


def rotation_about(axis, degrees: float) -> np.ndarray:
    """``(3, 3)`` rotation by ``degrees`` about ``axis``."""
    from scipy.spatial.transform import Rotation

    axis = np.asarray(axis, np.float64)
    return Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis)).as_matrix()


def rotation_error_deg(rot_a, rot_b) -> float:
    """Angle in degrees between two rotations ``(3, 3)``."""
    return float(se3.rotation_angle_deg(np.asarray(rot_a).T @ np.asarray(rot_b)))


@pytest.fixture(scope="session")
def random_weights(tmp_path_factory) -> str:
    """Path of an ``.npz`` checkpoint of randomly initialised weights (``init_params`` at key 0): the pipelines
    run end to end without the shipped model. Jitted: the same weights, bit for bit, in a third of the eager
    time."""
    import rpmnet_jax
    from rpmnet_jax.weights import convert

    path = tmp_path_factory.mktemp("w") / "random.npz"
    np.savez(path, **convert.params_to_torch(jax.jit(rpmnet_jax.init_params)(jax.random.PRNGKey(0))))
    return str(path)


def synthetic_shape(seed=0, n=3000, label=36):
    """``(points (n, 3), normals (n, 3))`` float64 of a synthetic shape of category ``label``."""
    from rpmnet_jax.data import synthetic

    pts = synthetic.sample_shape(np.random.default_rng(seed), label, n)
    return pts[:, :3].astype(np.float64), pts[:, 3:].astype(np.float64)


def synthetic_scans():
    """Three overlapping partial views ``(N_i, 3)`` of one synthetic shape (~0.2 across), each in its own frame,
    and their poses ``(3, 4, 4)`` (scan → world)."""
    from scipy.spatial.transform import Rotation

    from rpmnet_jax.data import synthetic

    world = synthetic.sample_shape(np.random.default_rng(0), 36, 4000)[:, :3] * 0.1
    clouds, poses = [], []
    for k in range(3):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_euler("xyz", [5 * k, 20 * k, -10 * k], degrees=True).as_matrix()
        pose[:3, 3] = [0.01 * k, 0.0, -0.02 * k]
        keep = world[:, 0] > -0.03 + 0.02 * k
        clouds.append((world[keep] - pose[:3, 3]) @ pose[:3, :3])
        poses.append(pose)
    return clouds, np.stack(poses)


def cropped_pair(seed: int = 0, n: int = 1200):
    """Two overlapping 70% crops (cut in different directions) of disjoint halves of ``n`` samples of
    :func:`asymmetric_shape` as :class:`rpmnet_jax.pair_edges.edges.Scan` s (``(~0.35 n, 3)`` each); scan 1 lies in
    a frame turned by 40° and moved: ``truth (4, 4)`` maps scan 0 onto scan 1."""
    from rpmnet_jax.pair_edges import edges

    pts, nrm = asymmetric_shape(seed, n)
    truth = np.eye(4)
    truth[:3, :3], truth[:3, 3] = rotation_about([0.5, -0.3, 1.0], 40.0), [0.2, -0.1, 0.3]
    out = []
    for k, direction in enumerate(([1.0, 0.3, 0.1], [-0.2, 1.0, 0.4])):
        p, n_ = pts[k::2], nrm[k::2]
        d = p @ np.asarray(direction)
        keep = d > np.quantile(d, 0.3)
        motion = truth if k else np.eye(4)
        out.append(edges.make_scan(p[keep] @ motion[:3, :3].T + motion[:3, 3], n_[keep] @ motion[:3, :3].T))
    return out, truth


RING_LABEL = 36  # ring_scans' shape (a box); the edge doubt model's fit leaves it out


def ring_scans(count: int = 5, seed: int = 0, asymmetric: bool = False):
    """``count`` partial views ``(N_i, 3)`` of one synthetic shape (~0.2 across; with ``asymmetric``, of
    :func:`asymmetric_shape`, else of one that 180° turns about its axes map nearly onto itself), each seen
    from a direction ``360°/count`` further round, in its own frame (rotated by up to ~``3 count``°), and their poses
    ``(count, 4, 4)`` (scan → world): neighbours overlap most, every view overlaps the next
    (:func:`synthetic.ring_views`)."""
    from rpmnet_jax.data import synthetic

    if asymmetric:
        world = asymmetric_shape(seed, 4000)[0] * 0.1
    else:
        world = synthetic.sample_shape(np.random.default_rng(seed), RING_LABEL, 4000)[:, :3] * 0.1
    return synthetic.ring_views(world - world.mean(0), count)
