"""Unit normals in two int16 (the octahedral map): every normal back within MAX_ERROR radians, the axes and the
folded lower half included; NaN kept NaN; the compiled reading of a row (which unpack uses) within the bound too,
and unit vectors read as they are."""

import numba
import numpy as np

from rpmnet_jax.geometry import packed_normals


def _random_normals(count, seed=0):
    n = np.random.default_rng(seed).normal(size=(count, 3))
    axes = np.concatenate([np.eye(3), -np.eye(3), [[1.0, 1.0, -1.0], [-1.0, 1e-9, -1.0], [1e-12, -1.0, -1e-12]]])
    n = np.concatenate([axes, n])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _angles(a, b):
    return np.arccos(np.clip(np.sum(a * b, axis=1), -1.0, 1.0))


def test_every_normal_comes_back_within_the_bound_in_four_bytes():
    normals = _random_normals(1_000_000)
    codes = packed_normals.pack(normals)
    assert codes.dtype == np.int16 and codes.shape == (len(normals), 2) and codes.nbytes == 4 * len(normals)
    back = packed_normals.unpack(codes, np.float64)
    assert np.abs(np.linalg.norm(back, axis=1) - 1.0).max() < 1e-12
    worst = _angles(normals, back).max()
    assert worst < packed_normals.MAX_ERROR
    assert worst > packed_normals.MAX_ERROR / 10  # rounded, not kept: the bound is not loose by orders
    np.testing.assert_allclose(packed_normals.unpack(codes[:6], np.float64), normals[:6], atol=1e-12)  # the axes
    assert packed_normals.unpack(codes).dtype == np.float32


def test_a_normal_that_is_not_finite_comes_back_nan():
    normals = np.array([[0.0, 0.0, 1.0], [np.nan, 0.0, 1.0], [0.0, np.inf, 0.0], [0.0, 0.0, 0.0],
                        [0.0, 0.0, -np.inf], [1.0, 0.0, np.inf]])
    back = packed_normals.unpack(packed_normals.pack(normals))
    assert np.all(np.isfinite(back[0])) and np.all(np.isnan(back[1:]))


@numba.njit
def _rows(normals):
    out, n = np.empty((len(normals), 3)), np.empty(3)
    for k in range(len(normals)):
        packed_normals.row(normals, k, n)
        out[k] = n
    return out


def test_a_compiled_row_reads_codes_and_unit_vectors_alike():
    normals = _random_normals(10_000, seed=1)
    normals[7] = np.nan
    codes = packed_normals.pack(normals)
    read = _rows(codes)  # unpack reads each row so too: checked here against the normals packed, not itself
    assert np.all(np.isnan(read[7])) and np.isfinite(np.delete(read, 7, axis=0)).all()
    assert np.delete(_angles(read, normals), 7).max() < packed_normals.MAX_ERROR
    as_float32 = normals.astype(np.float32)
    np.testing.assert_array_equal(_rows(as_float32), as_float32.astype(np.float64))


def test_unit_reads_either_kind_and_only_the_rows_asked():
    normals = _random_normals(100, seed=2).astype(np.float32)
    codes = packed_normals.pack(normals)
    rows = np.array([5, 3, 99])
    assert packed_normals.unit(normals) is normals
    np.testing.assert_array_equal(packed_normals.unit(normals, rows), normals[rows])
    np.testing.assert_array_equal(packed_normals.unit(codes, rows), packed_normals.unpack(codes[rows]))
    assert packed_normals.is_packed(codes) and not packed_normals.is_packed(normals)
