import jax
import numpy as np
import pytest

from rpmnet_jax.ops import grouping

from conftest import random_cloud


def brute_force_ball_query(xyz, radius, k):
    """Oracle written from the official semantics: within radius, not the centre, index order, pad."""
    b, n, _ = xyz.shape
    out = np.empty((b, n, k), np.int64)
    for bi in range(b):
        d2 = ((xyz[bi, :, None, :].astype(np.float64) - xyz[bi, None, :, :]) ** 2).sum(-1)
        for c in range(n):
            nbrs = [j for j in range(n) if j != c and d2[c, j] <= radius**2][:k]
            out[bi, c] = nbrs + [c] * (k - len(nbrs))
    return out


@pytest.mark.parametrize("n,k,chunk", [(50, 8, 2048), (120, 16, 32), (5, 64, 2048), (1, 4, 2048)])
def test_ball_query_matches_oracle(n, k, chunk):
    rng = np.random.default_rng(n)
    xyz = random_cloud(rng, 2, n)[..., :3]
    radius = 0.45
    idx = np.asarray(jax.jit(grouping.ball_query, static_argnums=(1, 2, 3))(xyz, radius, k, chunk))
    expected = brute_force_ball_query(xyz, radius, k)
    # Exclude points whose distance is within float32 rounding of the radius (none expected, but be exact).
    np.testing.assert_array_equal(idx, expected)
    assert idx.dtype == np.int32


def test_chunked_equals_unchunked():
    rng = np.random.default_rng(3)
    xyz = random_cloud(rng, 1, 300)[..., :3]
    a = grouping.ball_query(xyz, 0.4, 32, chunk=4096)
    b = grouping.ball_query(xyz, 0.4, 32, chunk=64)  # 300 is not a multiple of 64: exercises padding
    np.testing.assert_array_equal(a, b)


def test_gather():
    values = np.arange(2 * 4 * 3, dtype=np.float32).reshape(2, 4, 3)
    idx = np.array([[[0, 3]], [[2, 2]]], np.int32)
    out = np.asarray(grouping.gather(values, idx))
    np.testing.assert_array_equal(out[0, 0], values[0, [0, 3]])
    np.testing.assert_array_equal(out[1, 0], values[1, [2, 2]])
