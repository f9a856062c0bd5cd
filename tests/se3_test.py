import jax.numpy as jnp
import numpy as np
import pytest

from rpmnet_jax.ops import se3

from conftest import random_transform


def _homog(t):
    return np.concatenate([t, np.broadcast_to([0, 0, 0, 1], t.shape[:-2] + (1, 4))], axis=-2)


@pytest.mark.parametrize("batch_shape", [(), (4,), (2, 3)])
def test_compose_inverse_round_trip(batch_shape):
    rng = np.random.default_rng(0)
    n = int(np.prod(batch_shape)) if batch_shape else 1
    a = random_transform(rng, n).reshape(batch_shape + (3, 4)).astype(np.float32)
    b = random_transform(rng, n).reshape(batch_shape + (3, 4)).astype(np.float32)
    ident = se3.identity(batch_shape)
    # float32 transforms with unit rotations and translations up to 0.5: ~100 float32 eps
    np.testing.assert_allclose(se3.compose(a, se3.inverse(a)), ident, atol=1e-5)
    np.testing.assert_allclose(se3.compose(se3.inverse(a), a), ident, atol=1e-5)
    np.testing.assert_allclose(se3.compose(a, ident), a, atol=1e-6)
    np.testing.assert_allclose(_homog(np.asarray(se3.compose(a, b))), _homog(a) @ _homog(b), atol=1e-5)
    np.testing.assert_allclose(se3.to_homogeneous(a), _homog(a), atol=0)


def test_apply_matches_homogeneous_and_compose():
    rng = np.random.default_rng(1)
    a, b = random_transform(rng, 2).astype(np.float32)[:, None]
    pts = rng.normal(size=(1, 10, 3)).astype(np.float32)
    expected = (np.concatenate([pts, np.ones((1, 10, 1))], -1) @ _homog(a).transpose(0, 2, 1))[..., :3]
    # float32 points of unit scale (normal draws, up to ~3): ~100 float32 eps
    np.testing.assert_allclose(se3.apply(a, pts), expected, atol=1e-5)
    np.testing.assert_allclose(se3.apply(se3.compose(a, b), pts), se3.apply(a, se3.apply(b, pts)), atol=1e-5)
    np.testing.assert_allclose(se3.apply(se3.inverse(a), se3.apply(a, pts)), pts, atol=1e-5)
    # rotate ignores translation
    np.testing.assert_allclose(se3.rotate(a, pts), se3.apply(a, pts) - a[..., :3, 3][:, None], atol=1e-5)


def _expm_twist(twist):
    """Reference: scipy's matrix exponential of the 4×4 twist matrix (float64)."""
    from scipy.linalg import expm

    m = np.zeros((4, 4))
    w = twist[:3]
    m[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
    m[:3, 3] = twist[3:]
    return expm(m)[:3]


@pytest.mark.parametrize("magnitude", [0.0, 1e-9, 1e-5, 1e-3, 0.1, 1.0, 3.0])
def test_exp_matches_the_matrix_exponential(magnitude):
    """NumPy float64 to round-off at every angle (the series branch below sqrt(eps), the closed form above);
    JAX float32 to its precision; any batch shape."""
    rng = np.random.default_rng(7)
    twists = rng.normal(size=(2, 3, 6)) * magnitude
    expected = np.stack([_expm_twist(t) for t in twists.reshape(-1, 6)]).reshape(2, 3, 3, 4)
    got = se3.exp(twists)
    assert isinstance(got, np.ndarray) and got.dtype == np.float64 and got.shape == (2, 3, 3, 4)
    tol = 1e-14 * max(1.0, magnitude) ** 2  # round-off of both sides (entries grow with the twist)
    np.testing.assert_allclose(got, expected, rtol=0, atol=tol)
    np.testing.assert_allclose(se3.exp(jnp.asarray(twists, jnp.float32)), expected, atol=2e-6 * max(1.0, magnitude) ** 2)
    np.testing.assert_allclose(se3.exp(twists[0, 0]), expected[0, 0], rtol=0, atol=tol)


def test_exp_of_zero_is_identity_and_of_a_rotation_is_orthonormal():
    np.testing.assert_array_equal(se3.exp(np.zeros(6)), np.eye(3, 4))
    np.testing.assert_array_equal(se3.exp(np.zeros((4, 6), np.float32)), np.broadcast_to(np.eye(3, 4), (4, 3, 4)))
    rng = np.random.default_rng(8)
    directions = rng.normal(size=(50, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    omega = directions * np.array([[1e-7], [1e-2], [1.0], [3.0], [np.pi - 1e-6]] * 10)  # angles up to pi
    t = se3.exp(np.concatenate([omega, np.zeros((50, 3))], axis=1))
    rot = t[:, :, :3]
    np.testing.assert_allclose(rot @ np.swapaxes(rot, 1, 2), np.broadcast_to(np.eye(3), (50, 3, 3)), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-14)
    np.testing.assert_array_equal(t[:, :, 3], 0.0)
    from scipy.spatial.transform import Rotation
    np.testing.assert_allclose(rot, Rotation.from_rotvec(omega).as_matrix(), atol=1e-14)
    # the rotation angle is |ω|
    np.testing.assert_allclose(se3.rotation_angle_deg(rot), np.degrees(np.linalg.norm(omega, axis=1)), atol=1e-9)


def test_exp_gradient_is_finite_at_zero():
    import jax

    def f(twist):
        return jnp.sum(se3.apply(se3.exp(twist), jnp.ones((1, 3))) ** 2)

    for twist in (jnp.zeros(6), jnp.asarray([1e-4, 0, 0, 0, 0, 0]), jnp.asarray([0.5, -0.2, 0.1, 1.0, 0, 0])):
        g = jax.grad(f)(twist)
        assert np.all(np.isfinite(np.asarray(g)))
    # at zero: d/dω |x + ω × x + v|² = 2 x × (x + v) ... with x = 1, v = 0 the rotation gradient is 0
    np.testing.assert_allclose(jax.grad(f)(jnp.zeros(6)), [0, 0, 0, 2, 2, 2], atol=1e-6)


def _about_z(degrees):
    from conftest import rotation_about

    return rotation_about([0.0, 0.0, 1.0], degrees)


def test_distinct_rotations_keep_each_one_far_from_every_better_kept_one():
    """Greedy over the ranking: 5° from the best is dropped, 20° kept; 8° from a dropped one but 16° from the
    best is kept (only kept rotations count); exactly the minimum angle apart is distinct; ``limit`` stops early."""
    rots = np.stack([_about_z(0), _about_z(5), _about_z(20), _about_z(8), _about_z(16)])
    assert se3.distinct_rotations(rots, 10.0) == [0, 2]  # 16° lies 4° from the kept 20°
    rots = np.stack([_about_z(0), _about_z(8), _about_z(16)])
    assert se3.distinct_rotations(rots, 10.0) == [0, 2]
    assert se3.distinct_rotations(np.stack([_about_z(0), _about_z(45)]), 45.0) == [0, 1]
    assert se3.distinct_rotations(np.stack([_about_z(0), _about_z(90), _about_z(180)]), 10.0, limit=2) == [0, 1]
    assert se3.distinct_rotations(np.zeros((0, 3, 3)), 10.0) == []


def test_distinct_rotations_equal_a_pairwise_loop():
    """Against a plain loop over pairs with SciPy's rotation angle, on 200 random rotations."""
    from scipy.spatial.transform import Rotation

    rots = Rotation.random(200, random_state=0).as_matrix()
    want = []
    for i in range(len(rots)):
        if all(Rotation.from_matrix(rots[i] @ rots[k].T).magnitude() >= np.radians(60.0) for k in want):
            want.append(i)
    got = se3.distinct_rotations(rots, 60.0)
    assert got == want and 5 < len(got) < 200


def test_pivot_adjoint_moves_a_twist_to_a_pivot():
    """``pivot_adjoint(c) @ (ω, v)`` moves every point as ``(ω, v)`` does, with the rotation about ``c``:
    ``ω × x + v = ω × (x − c) + v'``; its inverse is the adjoint of ``-c``."""
    rng = np.random.default_rng(3)
    omega, v, c, x = rng.normal(size=(4, 3))
    moved = se3.pivot_adjoint(c) @ np.concatenate([omega, v])
    np.testing.assert_allclose(moved[:3], omega, atol=0)
    np.testing.assert_allclose(np.cross(omega, x - c) + moved[3:], np.cross(omega, x) + v, atol=1e-12)
    np.testing.assert_allclose(se3.pivot_adjoint(c) @ se3.pivot_adjoint(-c), np.eye(6), atol=1e-15)
