"""Rigid transforms stored as ``(*, 3, 4)`` matrices ``[R | t]``; any leading batch axes."""

import jax.numpy as jnp


def identity(batch_shape=(), dtype=jnp.float32):
    """Identity transform of shape ``(*batch_shape, 3, 4)``."""
    eye = jnp.eye(3, 4, dtype=dtype)
    return jnp.broadcast_to(eye, tuple(batch_shape) + (3, 4))


def apply(transform, xyz):
    """Maps points ``xyz (*, N, 3)`` by ``transform (*, 3, 4)``: ``R x + t``."""
    rot, trans = transform[..., :3, :3], transform[..., :3, 3]
    return xyz @ jnp.swapaxes(rot, -1, -2) + trans[..., None, :]


def rotate(transform, vectors):
    """Rotates direction vectors ``(*, N, 3)`` (normals, offsets) by the rotation of ``transform``."""
    rot = transform[..., :3, :3]
    return vectors @ jnp.swapaxes(rot, -1, -2)


def compose(a, b):
    """``a ∘ b`` (apply ``b`` first) for ``(*, 3, 4)`` transforms."""
    rot_a, t_a = a[..., :3, :3], a[..., :3, 3]
    rot_b, t_b = b[..., :3, :3], b[..., :3, 3]
    rot = rot_a @ rot_b
    trans = (rot_a @ t_b[..., None])[..., 0] + t_a
    return jnp.concatenate([rot, trans[..., None]], axis=-1)


def inverse(transform):
    """Inverse of a ``(*, 3, 4)`` rigid transform."""
    rot_t = jnp.swapaxes(transform[..., :3, :3], -1, -2)
    trans = -(rot_t @ transform[..., :3, 3:4])
    return jnp.concatenate([rot_t, trans], axis=-1)


def to_homogeneous(transform):
    """``(*, 3, 4)`` → ``(*, 4, 4)``."""
    bottom = jnp.broadcast_to(jnp.array([0.0, 0.0, 0.0, 1.0], transform.dtype),
                              transform.shape[:-2] + (1, 4))
    return jnp.concatenate([transform, bottom], axis=-2)
