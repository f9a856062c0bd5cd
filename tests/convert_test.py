import jax
import numpy as np
import pytest

import rpmnet_jax
from rpmnet_jax.weights import convert

from conftest import crafted_checkpoint, require_fixtures


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
    """The official checkpoint layout (state dict, optimizer state, step) loads with the tensors-only reader."""
    torch = pytest.importorskip("torch")
    sd = {k: torch.from_numpy(v) for k, v in _official_state_dict().items()}
    weights = [torch.nn.Parameter(v.clone()) for v in sd.values()]
    adam = torch.optim.Adam(weights)
    sum(w.sum() for w in weights).backward()
    adam.step()
    torch.save({"state_dict": sd, "optimizer": adam.state_dict(), "step": 3}, tmp_path / "model.pth")
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


def test_crafted_pickle_is_refused_and_never_runs(tmp_path):
    pytest.importorskip("torch")
    marker = tmp_path / "ran"
    path = crafted_checkpoint(tmp_path / "evil.pth", marker)
    with pytest.raises(ValueError, match="refused") as e:
        rpmnet_jax.load_params(path)
    assert "\n" not in str(e.value) and "posix.system" in str(e.value)
    assert not marker.exists()
    plain = tmp_path / "evil.pt"  # a bare pickle, not torch's zip layout
    import pickle
    from conftest import _Payload
    plain.write_bytes(pickle.dumps(_Payload(marker)))
    with pytest.raises(ValueError, match="refused"):
        rpmnet_jax.load_params(str(plain))
    assert not marker.exists()
