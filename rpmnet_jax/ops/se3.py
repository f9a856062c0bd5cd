"""Rigid transforms stored as ``(*, 3, 4)`` matrices ``[R | t]``; any leading batch axes.

The one set of rigid-transform helpers: they take JAX arrays (traceable, any dtype) or NumPy arrays (computed
in NumPy, so float64 host-side metrics stay float64, and NumPy callers never import JAX).
"""

import numpy as np


def _xp(*arrays):
    if all(isinstance(a, np.ndarray) for a in arrays):
        return np
    import jax.numpy as jnp  # only for JAX callers: the classical pipeline runs without importing JAX
    return jnp


def identity(batch_shape=(), dtype="float32"):
    """Identity transform of shape ``(*batch_shape, 3, 4)`` (a JAX array)."""
    import jax.numpy as jnp
    eye = jnp.eye(3, 4, dtype=dtype)
    return jnp.broadcast_to(eye, tuple(batch_shape) + (3, 4))


def apply(transform, xyz):
    """Maps points ``xyz (*, N, 3)`` by ``transform (*, 3, 4)``: ``R x + t``."""
    rot, trans = transform[..., :3, :3], transform[..., :3, 3]
    return xyz @ _xp(transform, xyz).swapaxes(rot, -1, -2) + trans[..., None, :]


def rotate(transform, vectors):
    """Rotates direction vectors ``(*, N, 3)`` (normals, offsets) by the rotation of ``transform``."""
    rot = transform[..., :3, :3]
    return vectors @ _xp(transform, vectors).swapaxes(rot, -1, -2)


def compose(a, b):
    """``a ∘ b`` (apply ``b`` first) for ``(*, 3, 4)`` transforms."""
    rot_a, t_a = a[..., :3, :3], a[..., :3, 3]
    rot_b, t_b = b[..., :3, :3], b[..., :3, 3]
    rot = rot_a @ rot_b
    trans = (rot_a @ t_b[..., None])[..., 0] + t_a
    return _xp(a, b).concatenate([rot, trans[..., None]], axis=-1)


def inverse(transform):
    """Inverse of a ``(*, 3, 4)`` rigid transform."""
    xp = _xp(transform)
    rot_t = xp.swapaxes(transform[..., :3, :3], -1, -2)
    trans = -(rot_t @ transform[..., :3, 3:4])
    return xp.concatenate([rot_t, trans], axis=-1)


def to_homogeneous(transform):
    """``(*, 3, 4)`` → ``(*, 4, 4)`` (a ``(*, 4, 4)`` input is returned as it is)."""
    if transform.shape[-2] == 4:
        return transform
    xp = _xp(transform)
    bottom = xp.broadcast_to(xp.asarray([0.0, 0.0, 0.0, 1.0], transform.dtype), transform.shape[:-2] + (1, 4))
    return xp.concatenate([transform, bottom], axis=-2)


def hat(omega):
    """Skew matrices ``(*, 3, 3)`` of vectors ``omega (*, 3)``: ``hat(w) @ x = w × x``."""
    xp = _xp(omega)
    x, y, z = omega[..., 0], omega[..., 1], omega[..., 2]
    zero = xp.zeros_like(x)
    return xp.stack([xp.stack([zero, -z, y], -1), xp.stack([z, zero, -x], -1), xp.stack([-y, x, zero], -1)], -2)


def pivot_adjoint(centre) -> np.ndarray:
    """``(6, 6)`` ``[[I, 0], [-[c]×, I]]`` (NumPy, float64): the twist ``(ω, v)`` about the origin as a twist about
    ``centre (3,)`` (``v' = v + ω × c``), the adjoint of a translation by ``-c``; an information matrix moves as
    ``Bᵀ Λ B``."""
    b = np.eye(6)
    b[3:, :3] = -np.asarray(hat(np.asarray(centre, np.float64)))
    return b


def exp(twist):
    """SE(3) exponential of twists ``twist (*, 6) = (ω, v)`` (rotation first, as GTSAM's ``Pose3``) →
    ``(*, 3, 4)`` ``[R | V v]``: the matrix exponential of ``[[hat(ω), v], [0, 0]]``.

    ``R = I + a K + b K²`` (Rodrigues), ``V = I + b K + c K²`` with ``K = hat(ω)``, ``θ = |ω|``,
    ``a = sin θ / θ``, ``b = (1 - cos θ) / θ²``, ``c = (θ - sin θ) / θ³``; below ``θ² = sqrt(eps)`` of the
    dtype the coefficients are their Taylor series, so the values and (JAX) gradients are finite at ``θ = 0``.
    """
    xp = _xp(twist)
    if not xp.issubdtype(twist.dtype, xp.floating):
        twist = twist.astype(xp.float64 if xp is np else xp.float32)
    omega, v = twist[..., :3], twist[..., 3:]
    t = xp.sum(omega * omega, axis=-1)
    small = t < float(xp.finfo(twist.dtype).eps) ** 0.5
    t_safe = xp.where(small, xp.ones_like(t), t)  # the double-where: no 0/0 on either branch (nor its gradient)
    theta = xp.sqrt(t_safe)
    sin, half_sin = xp.sin(theta), xp.sin(0.5 * theta)
    a = xp.where(small, 1 - t / 6 + t * t / 120, sin / theta)
    b = xp.where(small, 0.5 - t / 24 + t * t / 720, 2 * half_sin * half_sin / t_safe)
    c = xp.where(small, 1 / 6 - t / 120 + t * t / 5040, (theta - sin) / (t_safe * theta))
    k = hat(omega)
    k2 = k @ k
    eye = xp.eye(3, dtype=twist.dtype)
    rot = eye + a[..., None, None] * k + b[..., None, None] * k2
    trans = ((eye + b[..., None, None] * k + c[..., None, None] * k2) @ v[..., None])[..., 0]
    return xp.concatenate([rot, trans[..., None]], axis=-1)


def rotation_angle_deg(rot):
    """Angle in degrees of rotations ``(*, 3, 3)`` (NumPy float64), as ``atan2(sin, cos)`` with
    ``sin = |vee(R - Rᵀ)| / 2`` and ``cos = (tr R - 1) / 2``: the arccos of the cosine alone loses precision
    near 0° and 180° (an orthogonality defect d of a float32 R reads as ~sqrt(d) rad; here as ~d)."""
    rot = np.asarray(rot, np.float64)
    cos = 0.5 * (rot[..., 0, 0] + rot[..., 1, 1] + rot[..., 2, 2] - 1.0)
    skew = np.stack([rot[..., 2, 1] - rot[..., 1, 2], rot[..., 0, 2] - rot[..., 2, 0],
                     rot[..., 1, 0] - rot[..., 0, 1]], axis=-1)
    return np.degrees(np.arctan2(0.5 * np.linalg.norm(skew, axis=-1), cos))


def distinct_rotations(rotations, min_angle_deg: float, limit: int | None = None) -> list:
    """Indices into ``rotations (N, 3, 3)`` (NumPy, ranked best first), greedily: each kept rotation lies at least
    ``min_angle_deg`` from every better kept one; at most ``limit`` (default all)."""
    rotations = np.asarray(rotations, np.float64)
    alive = np.ones(len(rotations), bool)
    kept: list[int] = []
    while alive.any() and (limit is None or len(kept) < limit):
        i = int(np.flatnonzero(alive)[0])
        kept.append(i)
        alive &= rotation_angle_deg(rotations @ rotations[i].T) >= min_angle_deg  # all angles to it at once
    return kept


def quaternion_to_matrix(q):
    """Rotation matrices ``(*, 3, 3)`` of quaternions ``q (*, 4)`` ordered ``(w, x, y, z)`` (normalised here)."""
    xp = _xp(q)
    q = q / xp.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = (q[..., i] for i in range(4))
    rows = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    return xp.stack([xp.stack(r, axis=-1) for r in rows], axis=-2)
