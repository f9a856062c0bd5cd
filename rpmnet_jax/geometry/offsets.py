"""Large coordinates (a national grid, a site's survey frame) moved near the origin and back.

Every estimation step works in a frame moved by ``-shift`` (:func:`common_shift`: near the scans' middle), so an
ICP that linearises about the origin, a damping relative to a trace or a float32 network never sees coordinates
of millions of metres; answers are then expressed in the caller's frame again (:func:`unshift_transforms`,
:func:`unshift_information`). With ``Sₛ`` the translation by ``s``: a transform ``T'`` between shifted frames is
``T = Sₛ T' S₋ₛ`` between the caller's.
"""

from __future__ import annotations

import numpy as np

from rpmnet_jax.ops import se3

SHIFT_QUANTUM = 1.0  # the shift is rounded to whole caller's units: scans within half a unit of the origin (objects
# in metres) are not moved at all, and a set moved by whole units (into a grid) is moved back by exactly as much, so
# its scans reach every later step as the same numbers up to the rounding of the grid coordinates themselves


def common_shift(clouds) -> np.ndarray:
    """``(3,)`` float64: the coordinate-wise median of the scans' medians (finite rows of each ``(N_i, 3)``),
    rounded to ``SHIFT_QUANTUM`` (zero where that is not finite)."""
    medians = []
    for c in clouds:
        c = np.asarray(c)
        if c.ndim != 2 or c.shape[-1] != 3 or not len(c):
            return np.zeros(3)  # the caller's checks name the bad scan
        medians.append(np.nanmedian(np.asarray(c[:: max(1, len(c) // 4096)], np.float64), axis=0))
    middle = np.nanmedian(np.stack(medians), axis=0) if medians else np.zeros(3)
    if not np.all(np.isfinite(middle)):
        return np.zeros(3)
    return np.round(middle / SHIFT_QUANTUM) * SHIFT_QUANTUM


def unshift_transforms(transforms: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``(..., 4, 4)`` transforms between frames moved by ``-shift (3,)`` → the same motions between the caller's
    frames: ``S(shift) T S(-shift)`` (NaN stays NaN)."""
    out = np.array(transforms, np.float64)
    rot = out[..., :3, :3]
    out[..., :3, 3] += shift - rot @ shift
    return out


def unshift_information(information: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """``(6, 6)`` information of ``T' · Exp(ξ')`` (``ξ = (ω, v)``) in the moved frames → that of ``T · Exp(ξ)``
    in the caller's: ``ξ' = Ad(S(-shift)) ξ``, so ``Λ = Adᵀ Λ' Ad`` with ``Ad = [[I, 0], [-[shift]×, I]]``."""
    ad = se3.pivot_adjoint(shift)
    return ad.T @ information @ ad
