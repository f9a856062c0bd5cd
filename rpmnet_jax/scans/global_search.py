"""Global initialisation: the network started from rotation hypotheses that cover SO(3), in one batched call.

The network registers reliably only inside a basin around the identity (it was trained on rotations of up to
45° per Euler axis; ``python -m experiments.basin`` measures it). A finite rotation group whose covering
radius lies inside that basin puts every rotation within reach of at least one hypothesis: the
icosahedral group (60 rotations) leaves no rotation farther than 44.3° from one of them, the octahedral
group (24) no farther than 62.7°. Every hypothesis runs through :func:`rpmnet_jax.registration.register_from`
(reference features and source neighbourhoods computed once), and each answer is scored by its fitness.
"""

from __future__ import annotations

import functools

import numpy as np

HYPOTHESIS_SETS = {"icosahedral": "I", "octahedral": "O"}


@functools.lru_cache(maxsize=None)
def rotation_hypotheses(kind: str = "icosahedral") -> np.ndarray:
    """``(H, 3, 3)`` rotations of a finite group (the identity first): 60 icosahedral or 24 octahedral."""
    from scipy.spatial.transform import Rotation

    if kind not in HYPOTHESIS_SETS:
        raise ValueError(f"hypotheses must be one of {sorted(HYPOTHESIS_SETS)}, got {kind!r}")
    mats = Rotation.create_group(HYPOTHESIS_SETS[kind]).as_matrix()
    first = int(np.argmin(np.linalg.norm(mats - np.eye(3), axis=(1, 2))))
    order = [first] + [i for i in range(len(mats)) if i != first]
    out = mats[order]
    out.setflags(write=False)
    return out


def initial_transforms(kind: str = "icosahedral") -> np.ndarray:
    """``(H, 3, 4)`` float32 starts ``[R_h | 0]`` for :func:`rpmnet_jax.registration.register_from`.

    The clouds are centred on their own centroids before registration, so rotating about the origin keeps
    the source where the network expects it.
    """
    rots = rotation_hypotheses(kind)
    return np.concatenate([rots, np.zeros((len(rots), 3, 1))], axis=2).astype(np.float32)
