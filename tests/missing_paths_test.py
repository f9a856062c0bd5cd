"""A path that is not there, given to ``rpmnet-register`` or ``rpmnet-register-scans``: one line saying so, exit 2,
nothing written, whatever the path's extension (none: a folder of scans; ``.e57``: read by libE57)."""

import numpy as np
import pytest

from rpmnet_jax.cli import register, register_scans
from rpmnet_jax.io import clouds as cloud_io


def _refused(capsys, main, args, outputs, message) -> None:
    rc = main(args)
    err = capsys.readouterr().err
    assert rc == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not any(o.exists() for o in outputs)


@pytest.mark.parametrize("name", ["scans", "missing.ply", "missing.pcd", "missing.e57"])
def test_missing_path_is_said_as_such(tmp_path, capsys, name):
    if name.endswith(".e57"):
        pytest.importorskip("pye57")
    cloud_io.write_cloud(str(tmp_path / "a.xyz"), np.random.default_rng(0).normal(size=(100, 3)))
    a, missing = str(tmp_path / "a.xyz"), str(tmp_path / name)
    conf, merged, transform = tmp_path / "p.conf", tmp_path / "m.ply", tmp_path / "T.txt"
    message = f"{missing}: no such file or folder"
    _refused(capsys, register_scans.main, [a, missing, "--out-poses", str(conf), "--out-merged", str(merged)],
             [conf, merged], message)
    _refused(capsys, register_scans.main, [missing, "--out-poses", str(conf)], [conf], message)
    _refused(capsys, register.main, [missing, a, "--out-transform", str(transform)], [transform], message)
    _refused(capsys, register.main, [a, missing, "--out-transform", str(transform)], [transform], message)


def test_folder_without_an_extension_and_a_broken_e57(tmp_path, capsys):
    cloud_io.write_cloud(str(tmp_path / "a.xyz"), np.random.default_rng(0).normal(size=(100, 3)))
    (tmp_path / "scans").mkdir()
    transform, conf = tmp_path / "T.txt", tmp_path / "p.conf"
    _refused(capsys, register.main, [str(tmp_path / "scans"), str(tmp_path / "a.xyz"), "--out-transform",
                                     str(transform)], [transform], "is a folder, not a point-cloud file")
    pytest.importorskip("pye57")
    (tmp_path / "b.e57").write_bytes(b"not an e57 file")
    _refused(capsys, register_scans.main, [str(tmp_path / "a.xyz"), str(tmp_path / "b.e57"), "--out-poses",
                                           str(conf)], [conf], "cannot read as E57")


def test_an_output_without_an_extension_is_an_unknown_format(tmp_path, capsys):
    cloud_io.write_cloud(str(tmp_path / "a.xyz"), np.random.default_rng(0).normal(size=(100, 3)))
    a, conf, merged = str(tmp_path / "a.xyz"), tmp_path / "p.conf", tmp_path / "merged"
    _refused(capsys, register_scans.main, [a, a, "--out-poses", str(conf), "--out-merged", str(merged)],
             [conf, merged], "merged: unknown point-cloud format '(none)'")
