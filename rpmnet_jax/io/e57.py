"""E57 files through ``pye57``: one cloud per scan in the scan's own frame, with its stored pose, its name,
colours and intensity; written with double-precision coordinates (``pye57``'s own writer stores float32).

A scan's pose maps its points into the file's common frame (``p @ R.T + t``, ``R`` from the stored quaternion
``w x y z``). Points whose ``cartesianInvalidState`` is set are NaN rows; NaN rows are written with it set.
"""

from __future__ import annotations

import uuid
from typing import NamedTuple

import numpy as np

from rpmnet_jax.io import columns as cols

INSTALL = "pip install 'rpmnet_jax[scanners]'"
_XYZ = ("cartesianX", "cartesianY", "cartesianZ")
_RGB = ("colorRed", "colorGreen", "colorBlue")


class Scan(NamedTuple):
    cloud: cols.Cloud  # in the scan's own frame
    name: str | None  # the scan's stored name, if any
    pose: np.ndarray | None  # (4, 4) scan -> file frame, when stored


def check_available(path: str) -> None:
    import importlib

    try:
        importlib.import_module("pye57")
    except ImportError:
        raise cols.CloudError(f"{path}: reading and writing E57 needs pye57: {INSTALL}") from None


def read_scans(path: str) -> list:
    """Every scan of an E57 file as a :class:`Scan` (points ``(N, 3)`` float64 in the scan's frame)."""
    cols.check_readable(path)
    check_available(path)
    import pye57
    from pye57 import libe57

    try:
        e57 = pye57.E57(path)
    except Exception as e:  # not an E57 file: libE57's message is many lines
        raise cols.unreadable(path, "E57", e) from None
    try:
        if e57.scan_count == 0:
            raise cols.CloudError(f"{path}: the E57 file has no scans")
        scans = []
        for index in range(e57.scan_count):
            header = e57.get_header(index)
            fields = set(header.point_fields)
            if not set(_XYZ) <= fields:
                raise cols.CloudError(f"{path}: scan {index} has no Cartesian coordinates (cartesianX/Y/Z; it has "
                                      f"{' '.join(sorted(fields))}); convert it to Cartesian first")
            n = header.point_count
            wanted = [f for f in _XYZ + _RGB + ("intensity", "cartesianInvalidState") if f in fields]
            data = {f: np.empty(n, np.int8 if f == "cartesianInvalidState" else np.float64) for f in wanted}
            buffers = libe57.VectorSourceDestBuffer()
            for f in wanted:
                buffers.append(libe57.SourceDestBuffer(e57.image_file, f, data[f], n, True, True))
            reader = header.points.reader(buffers)
            reader.read()
            reader.close()
            points = np.stack([data[f] for f in _XYZ], axis=1)
            if "cartesianInvalidState" in data:
                points[data["cartesianInvalidState"] != 0] = np.nan
            if n == 0:
                raise cols.CloudError(f"{path}: scan {index} has no points")
            colours = np.stack([data[f] for f in _RGB], axis=1) if set(_RGB) <= fields else None
            node = header.node
            name = node["name"].value() if node.isDefined("name") else None
            scans.append(Scan(cols.Cloud(points, None, colours, data.get("intensity")), name or None,
                              _pose(header) if header.has_pose() else None))
        return scans
    finally:
        e57.close()


def _pose(header) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    w, x, y, z = (float(v) for v in header.rotation)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat([x, y, z, w]).as_matrix() if (w, x, y, z) != (0, 0, 0, 0) else np.eye(3)
    pose[:3, 3] = header.translation
    return pose


def read(path: str) -> cols.Cloud:
    """The one scan of an E57 file, in the file's frame (moved by its stored pose)."""
    scans = read_scans(path)
    if len(scans) > 1:
        raise cols.CloudError(f"{path}: the E57 file holds {len(scans)} scans; rpmnet-register-scans takes it as a "
                              "scan set (rpmnet_jax.io.e57.read_scans reads them one by one)")
    cloud, _, pose = scans[0]
    return cloud if pose is None else cloud.moved(pose)


def write(path: str, scans) -> None:
    """Writes ``scans`` (:class:`Scan`, or plain :class:`~rpmnet_jax.io.columns.Cloud` s: no name, no pose) as
    one E57 file: float64 coordinates and intensity; colours as integers when whole numbers, else float64."""
    check_available(path)
    import pye57

    e57 = pye57.E57(path, mode="w")
    try:
        for scan in scans:
            scan = scan if isinstance(scan, Scan) else Scan(scan, None, None)
            _write_scan(e57, scan)
    finally:
        e57.close()


def _write_scan(e57, scan: Scan) -> None:
    from pye57 import libe57
    from scipy.spatial.transform import Rotation

    imf, cloud = e57.image_file, scan.cloud
    points = np.asarray(cloud.points, np.float64)
    bad = ~np.all(np.isfinite(points), axis=1)
    data = {f: np.where(bad, 0.0, points[:, k]) for k, f in enumerate(_XYZ)}
    node = libe57.StructureNode(imf)
    node.set("guid", libe57.StringNode(imf, "{%s}" % uuid.uuid4()))
    if scan.name:
        node.set("name", libe57.StringNode(imf, scan.name))
    if scan.pose is not None:
        pose = np.asarray(scan.pose, np.float64)
        x, y, z, w = Rotation.from_matrix(pose[:3, :3]).as_quat()
        pose_node, rotation, translation = (libe57.StructureNode(imf) for _ in range(3))
        for key, value in zip("wxyz", (w, x, y, z)):
            rotation.set(key, libe57.FloatNode(imf, float(value)))
        for key, value in zip("xyz", pose[:3, 3]):
            translation.set(key, libe57.FloatNode(imf, float(value)))
        pose_node.set("rotation", rotation)
        pose_node.set("translation", translation)
        node.set("pose", pose_node)
    prototype = libe57.StructureNode(imf)
    for f in _XYZ:
        prototype.set(f, libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE))
    if cloud.intensity is not None:
        data["intensity"] = np.ascontiguousarray(cloud.intensity, np.float64)
        prototype.set("intensity", libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE))
    if cloud.colours is not None:
        colours = np.asarray(cloud.colours, np.float64)
        whole = cols.integer_type(colours, ("u1", "u2"))
        top = {"u1": 255, "u2": 65535}.get(whole)
        for k, f in enumerate(_RGB):
            data[f] = np.ascontiguousarray(colours[:, k])  # libE57 reads the buffer's memory
            prototype.set(f, libe57.IntegerNode(imf, 0, 0, top) if top else
                          libe57.FloatNode(imf, 0.0, libe57.E57_DOUBLE))
    if bad.any():
        data["cartesianInvalidState"] = np.where(bad, 2, 0).astype(np.float64)
        prototype.set("cartesianInvalidState", libe57.IntegerNode(imf, 0, 0, 2))
    points_node = libe57.CompressedVectorNode(imf, prototype, libe57.VectorNode(imf, True))
    node.set("points", points_node)
    e57.data3d.append(node)
    buffers = libe57.VectorSourceDestBuffer()
    for f, values in data.items():
        buffers.append(libe57.SourceDestBuffer(imf, f, values, len(values), True, True))
    writer = points_node.writer(buffers)
    writer.write(len(points))
    writer.close()
