"""A user's cloud made usable: kept rows and errors of ``clean_cloud``, the robust centre, and radii that one
stray point does not inflate."""

import numpy as np
import pytest

from rpmnet_jax.data import synthetic
from rpmnet_jax.geometry import cloud


def _shape(seed=0, n=256, label=36):
    pts = synthetic.sample_shape(np.random.default_rng(seed), label, n)
    return pts[:, :3].astype(np.float64), pts[:, 3:].astype(np.float64)


def test_clean_cloud_reports_the_kept_rows():
    pts, nrm = _shape(n=50)
    pts[[3, 17]] = np.nan
    nrm[40] = np.inf
    with pytest.warns(UserWarning, match="dropped 3 points"):
        got, got_n, rows = cloud.clean_cloud("c", pts, nrm)
    np.testing.assert_array_equal(rows, [i for i in range(50) if i not in (3, 17, 40)])
    np.testing.assert_array_equal(got, pts[rows])
    np.testing.assert_allclose(got_n, nrm[rows])  # renormalised unit normals: float64 round-off


@pytest.mark.filterwarnings("ignore:scan 7. dropped")  # too_few: NaN rows, warned before the error
@pytest.mark.parametrize("case,message", [
    ("shape", "expected points of shape"), ("normals_shape", "do not match"), ("too_few", "at least 3"),
    ("coincident", "degenerate"), ("collinear", "degenerate"), ("zero_normals", "zero length")])
def test_clean_cloud_names_the_cloud_in_its_errors(case, message):
    rng = np.random.default_rng(0)
    pts, nrm = rng.normal(size=(20, 3)), None
    if case == "shape":
        pts = pts[:, :2]
    elif case == "normals_shape":
        nrm = rng.normal(size=(19, 3))
    elif case == "too_few":
        pts[2:] = np.nan  # 2 usable points left
    elif case == "coincident":
        pts[:] = [1.0, 2.0, 3.0]
    elif case == "collinear":
        pts = np.outer(np.arange(20.0), [1.0, 2.0, 3.0])
    else:
        nrm = rng.normal(size=(20, 3))
        nrm[5] = 0.0
    with pytest.raises(ValueError, match=f"scan 7: .*{message}"):
        cloud.clean_cloud("scan 7", pts, nrm)


def test_clean_clouds_keep_their_centroid_and_radius():
    """On 1,220 real ModelNet40 clouds no point lies beyond ``STRAY_FACTOR`` × the quantile: a clean cloud is all
    core, its centre the plain centroid and its robust radius the plain radius."""
    pts, _ = _shape()
    centre, core = cloud.robust_centre(pts)
    assert core.all()
    np.testing.assert_array_equal(centre, pts.mean(axis=0))
    assert cloud.robust_radius(pts) == cloud.radius(pts)


def test_one_stray_point_moves_neither_the_robust_centre_nor_the_robust_radius():
    pts, _ = _shape()
    size = cloud.radius(pts)
    dirty = np.insert(pts, 77, pts.mean(0) + 100 * size * np.array([0.6, 0.0, 0.8]), axis=0)
    centre, core = cloud.robust_centre(dirty)
    assert np.flatnonzero(~core).tolist() == [77]
    np.testing.assert_array_equal(centre, pts.mean(axis=0))
    assert cloud.robust_radius(dirty) == cloud.robust_radius(pts)
    assert cloud.radius(dirty) > 50 * size  # the plain radius is the stray's distance


def test_radius_about_a_given_centre():
    pts = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0, 3.0, 0]])
    assert cloud.radius(pts) == pytest.approx(2.0)  # about the centroid (0, 1, 0): the third point
    assert cloud.radius(pts, np.zeros(3)) == 3.0


def test_huge_finite_values_are_kept_when_their_sum_overflows():
    """The one-pass finiteness test (a finite total) falls back to the per-row test when the total overflows: no
    finite row is dropped for it."""
    pts = np.random.default_rng(0).uniform(-1, 1, (50, 3)) * 1e307
    pts[:, 0] += 1.7e308  # every x near the float64 limit: their sum is inf
    assert not np.isfinite(np.sum(pts))
    got, _, rows = cloud.clean_cloud("c", pts, None)
    np.testing.assert_array_equal(rows, np.arange(50))
    np.testing.assert_array_equal(got, pts)
