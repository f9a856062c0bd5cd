"""Pair results on disk: an edge comes back bit for bit, a write leaves no partial file, a changed scan or
setting gives a new name, a bad folder is a one-line error."""

import os

import numpy as np
import pytest

from rpmnet_jax.pair_edges import edges as edges_lib, pair_cache


def _edge(rng):
    info = rng.normal(size=(6, 6))
    return edges_lib.Edge(2, 5, rng.normal(size=(4, 4)), 0.7312345678901234, 1.1e-4, info @ info.T, 3.3e-5, "network")


def test_edges_come_back_bit_for_bit(tmp_path):
    cache = pair_cache.PairCache(tmp_path / "c")
    rng = np.random.default_rng(0)
    edges = [_edge(rng), _edge(rng)._replace(stage="classical", fitness=0.5)]  # a pair's two answers
    assert cache.load("network-2-5-x") is None and not (tmp_path / "c").exists()  # made on the first write
    cache.store("network-2-5-x", edges)
    cache.store("classical-0-1-x", [])  # a pair without an answer is a result too
    back = pair_cache.PairCache(tmp_path / "c").load("network-2-5-x")
    assert len(back) == 2 and pair_cache.PairCache(tmp_path / "c").load("classical-0-1-x") == []
    for b, edge in zip(back, edges):
        assert (b.source, b.target, b.stage) == (edge.source, edge.target, edge.stage)
        for name in ("transform", "information"):
            assert np.array_equal(getattr(b, name), getattr(edge, name))
        assert (b.fitness, b.inlier_rmse, b.plane_residual) == (edge.fitness, edge.inlier_rmse, edge.plane_residual)
    assert sorted(os.listdir(tmp_path / "c")) == ["classical-0-1-x.npz", "network-2-5-x.npz"]  # no temporary file
    assert cache.written == 2


def test_an_unreadable_file_is_a_miss_not_an_error(tmp_path):
    cache = pair_cache.PairCache(tmp_path)
    (tmp_path / "network-0-1-x.npz").write_bytes(b"not a zip")
    assert cache.load("network-0-1-x") is None and cache.reused == 0


def test_a_pickled_object_is_never_read(tmp_path):
    cache = pair_cache.PairCache(tmp_path)
    np.savez(tmp_path / "network-0-1-x.npz", source=np.array([object()], dtype=object))
    assert cache.load("network-0-1-x") is None


def test_names_follow_the_scans_contents_and_the_settings():
    rng = np.random.default_rng(1)
    points = rng.normal(size=(50, 3))
    scan = edges_lib.make_scan(points, rng.normal(size=(50, 3)))
    moved = edges_lib.make_scan(points + np.array([0, 0, 1e-12]), scan.normals)
    a, b = pair_cache.scan_digest(scan), pair_cache.scan_digest(moved)
    assert a != b and a == pair_cache.scan_digest(edges_lib.make_scan(points.copy(), scan.normals.copy()))
    name = pair_cache.edge_name("network", 0, 1, a, a, 256, 0)
    assert name.startswith("network-0-1-") and name == pair_cache.edge_name("network", 0, 1, a, a, 256, 0)
    assert len({name, pair_cache.edge_name("network", 0, 1, a, b, 256, 0),
                pair_cache.edge_name("network", 0, 1, a, a, 256, 1),
                pair_cache.edge_name("network", 1, 0, a, a, 256, 0)}) == 4
    params = {"a": {"w": np.ones(3, np.float32)}, "b": np.zeros(2, np.float32)}
    changed = {"a": {"w": np.array([1, 1, 1.0000001], np.float32)}, "b": np.zeros(2, np.float32)}
    assert pair_cache.params_digest(params) != pair_cache.params_digest(changed)


def test_a_bad_folder_is_a_value_error(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="is a file"):
        pair_cache.PairCache(tmp_path / "file")
    with pytest.raises(ValueError, match="does not exist"):
        pair_cache.PairCache(tmp_path / "missing" / "cache")


def test_a_change_to_the_code_that_computes_an_edge_starts_new_keys(tmp_path, monkeypatch):
    """The key holds a digest of the source of the code an edge depends on: one constant changed there (as an
    upgrade would) gives every edge a new name, so a resumed run recomputes instead of mixing old and new edges."""
    assert any(p.endswith(os.path.join("classical", "icp.py")) for p in pair_cache.source_files())
    assert any(p.endswith(os.path.join("pair_edges", "edges.py")) for p in pair_cache.source_files())
    module = tmp_path / "constants.py"
    module.write_text("DISTINCT_DEG = 10.0\n")
    monkeypatch.setattr(pair_cache, "source_files", lambda: [str(module)])
    monkeypatch.setattr(pair_cache, "_code", {})
    before = pair_cache.edge_name("classical", 0, 1, "a", "b", 0.1)
    assert pair_cache.edge_name("classical", 0, 1, "a", "b", 0.1) == before  # the same code: the same name
    module.write_text("DISTINCT_DEG = 12.0\n")
    monkeypatch.setattr(pair_cache, "_code", {})  # a new process after the upgrade
    assert pair_cache.edge_name("classical", 0, 1, "a", "b", 0.1) != before
