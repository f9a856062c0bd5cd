"""Data: the ModelNet40 reader with the paper's protocols, the synthetic set, the batch loader."""

from rpmnet_jax.data.modelnet40 import (FOLDER, PROTOCOLS, SPLITS, ModelNet40, apply_transform, crop, euler_transform,
                                        inverse_transform, jitter, make_pair, read_split, resample, resolve_root)
from rpmnet_jax.data.subsets import Concat, Head, Spread

__all__ = ["FOLDER", "PROTOCOLS", "SPLITS", "Concat", "Head", "ModelNet40", "Spread", "apply_transform", "crop",
           "euler_transform", "inverse_transform", "jitter", "make_pair", "read_split", "resample", "resolve_root"]
