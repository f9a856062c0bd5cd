"""``ScanOptions``: the defaults are valid, every bad value is a ``ValueError`` naming its field, the object is
frozen."""

import dataclasses

import pytest

import rpmnet_jax
from rpmnet_jax.multiway import options


def test_defaults_are_valid_and_the_public_name_is_this_class():
    o = options.ScanOptions()
    assert rpmnet_jax.ScanOptions is options.ScanOptions
    assert o.refine in options.REFINES and o.voxel_size is None and o.max_correspondence_distance is None
    assert options.ScanOptions(voxel_size=0.01, max_correspondence_distance=0.02, refine_rounds=0, refine="none",
                               min_fitness=0.0, min_overlap=1.0, num_points=3, all_pairs_up_to=2).voxel_size == 0.01
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.num_points = 3


@pytest.mark.parametrize("field,value", [
    ("voxel_size", 0.0), ("voxel_size", -1.0), ("max_correspondence_distance", 0.0), ("num_points", 2),
    ("num_iters", 0), ("batch_size", 0), ("all_pairs_up_to", 1), ("neighbours", 0), ("refine_rounds", -1),
    ("refine_points", 2), ("min_fitness", -0.1), ("min_fitness", 1.5), ("min_overlap", 1.01),
    ("max_plane_residual", 0.0), ("edge_sigma_deg", 0.0), ("edge_sigma_fraction", -0.1), ("refine", "gicp"),
    ("voxel_size", float("nan")), ("min_overlap", float("nan"))])
def test_each_bad_value_is_an_error_naming_its_field(field, value):
    with pytest.raises(ValueError, match=rf"ScanOptions\.{field} must"):
        options.ScanOptions(**{field: value})
