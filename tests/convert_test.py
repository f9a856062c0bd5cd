import jax
import numpy as np
import pytest

import rpmnet_jax
from rpmnet_jax.weights import convert

from conftest import require_fixtures


def _official_state_dict():
    with np.load(require_fixtures() / "parity_partial.npz") as data:
        return {k[len("param/"):]: data[k] for k in data.files if k.startswith("param/")}


def test_round_trip_official_names_and_shapes():
    sd = _official_state_dict()
    back = convert.params_to_torch(convert.params_from_torch(sd))
    assert set(back) == set(sd)
    for k in sd:
        assert back[k].shape == sd[k].shape, k
        np.testing.assert_array_equal(back[k], sd[k])


def test_structure_matches_init_params():
    params = convert.params_from_torch(_official_state_dict())
    fresh = rpmnet_jax.init_params(jax.random.PRNGKey(0))
    shapes = lambda t: jax.tree_util.tree_map(lambda x: tuple(np.shape(x)), t)
    assert shapes(params) == shapes(fresh)


def test_npz_with_and_without_prefix_and_state_dict_wrapper(tmp_path):
    sd = _official_state_dict()
    np.savez(tmp_path / "plain.npz", **sd)
    a = convert.params_from_torch(tmp_path / "plain.npz")
    b = convert.params_from_torch(require_fixtures() / "parity_partial.npz")
    c = convert.params_from_torch({"state_dict": {f"module.{k}": v for k, v in sd.items()}})
    for other in (b, c):
        jax.tree_util.tree_map(np.testing.assert_array_equal, a, other)


def test_pth_checkpoint(tmp_path):
    torch = pytest.importorskip("torch")
    sd = {k: torch.from_numpy(v) for k, v in _official_state_dict().items()}
    torch.save({"state_dict": sd, "step": 3}, tmp_path / "model.pth")
    params = convert.params_from_torch(tmp_path / "model.pth")
    np.testing.assert_array_equal(params["feat_extractor"]["prepool_0"]["kernel"],
                                  sd["feat_extractor.prepool.0.weight"].numpy()[:, :, 0, 0].T)


def test_fresh_params_convert_both_ways():
    params = rpmnet_jax.init_params(jax.random.PRNGKey(1), rpmnet_jax.RPMNetConfig(anneal="constant"))
    back = convert.params_from_torch(convert.params_to_torch(params))
    jax.tree_util.tree_map(np.testing.assert_array_equal, back, params)


def test_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        convert.params_from_torch(tmp_path / "missing.npz")
    with pytest.raises(ValueError, match="no RPM-Net parameters"):
        convert.params_from_torch({"foo.weight": np.zeros(3)})
    with pytest.raises(ValueError, match="unknown weights format"):
        (tmp_path / "w.txt").write_text("x")
        convert.params_from_torch(tmp_path / "w.txt")
    with pytest.raises(ValueError, match="lack the module"):
        convert.params_from_torch({"feat_extractor.prepool.0.bias": np.zeros(3)})
