"""PCL .pcd clouds as obstacles (scenarios.pcd through scenarios.obstacle_file.load_obstacle).

Truths: files written here byte by byte (ascii text, binary records packed field by field with
struct in the layout the PCD format defines, LZF streams of literal runs), their coordinates known."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from scenarios.obstacle_file import load_obstacle
from scenarios.world import CloudObstacle, WorldError

XYZ = np.array([[1.0, 2.0, 3.0], [-0.5, 0.25, 4.0], [3.0, 0.0, 0.125]])


def header(fields, sizes, types, counts, points, data) -> bytes:
    lines = ["# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7", "FIELDS " + " ".join(fields),
             "SIZE " + " ".join(map(str, sizes)), "TYPE " + " ".join(types), "COUNT " + " ".join(map(str, counts)),
             f"WIDTH {points}", "HEIGHT 1", "VIEWPOINT 0 0 0 1 0 0 0", f"POINTS {points}", f"DATA {data}"]
    return ("\n".join(lines) + "\n").encode()


def test_an_ascii_cloud_with_other_fields_and_an_invalid_point(tmp_path):
    path = tmp_path / "scan.pcd"
    rows = [f"{x} {y} {z} 0.7 1 2 3" for x, y, z in XYZ] + ["nan nan nan 0 0 0 0"]
    path.write_bytes(header(["x", "y", "z", "intensity", "normal"], [4, 4, 4, 4, 4], "FFFFF", [1, 1, 1, 1, 3], 4,
                            "ascii") + "\n".join(rows).encode() + b"\n")
    with pytest.warns(UserWarning, match="dropped 1 invalid"):
        cloud = load_obstacle(path, offset=(1.0, 0.0, 0.0))
    assert isinstance(cloud, CloudObstacle)
    np.testing.assert_array_equal(cloud.points, XYZ + [1.0, 0.0, 0.0])


def test_a_binary_cloud_of_mixed_field_types_in_any_field_order(tmp_path):
    """Records: ring (uint16), z x (float32), rgb (uint8 x 4), y (float64), packed without padding."""
    path = tmp_path / "lidar.pcd"
    body = b"".join(struct.pack("<Hff4Bd", ring, z, x, 9, 8, 7, 6, y) for ring, (x, y, z) in enumerate(XYZ))
    path.write_bytes(header(["ring", "z", "x", "rgb", "y"], [2, 4, 4, 1, 8], "UFFUF", [1, 1, 1, 4, 1], len(XYZ),
                            "binary") + body)
    np.testing.assert_array_equal(load_obstacle(path).points, XYZ)


@pytest.mark.parametrize("change, problem", [
    (lambda raw: raw[:-5], "cannot read obstacle file"),
    (lambda raw: raw.replace(b"FIELDS x y z\n", b"FIELDS a b c\n"), "no x, y, z among the fields a b c"),
    (lambda raw: raw.replace(b"SIZE 4 4 4\n", b""), "header SIZE"),
    (lambda raw: raw.replace(b"DATA binary", b"DATA binary_compressed"), "compressed"),
    (lambda raw: raw.replace(b"DATA binary\n", b""), "header is not text"),
])
def test_a_bad_pcd_is_one_line_naming_the_file_and_the_problem(tmp_path, change, problem):
    path = tmp_path / "bad.pcd"
    body = b"".join(struct.pack("<3f", *p) for p in np.vstack([XYZ, XYZ[::-1], XYZ[:-1]]))
    path.write_bytes(change(header(["x", "y", "z"], [4, 4, 4], "FFF", [1, 1, 1], 5, "binary") + body[:60]))
    with pytest.raises(WorldError) as err:
        load_obstacle(path)
    assert "bad.pcd" in str(err.value) and problem in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("data", ["ascii", "binary"])
def test_a_file_cut_short_is_refused(tmp_path, data):
    """Four whole points where the header says five (a copy cut off, a record lost)."""
    path = tmp_path / "cut.pcd"
    body = ("\n".join(" ".join(map(str, p)) for p in XYZ[[0, 1, 2, 0]]) + "\n").encode() if data == "ascii" else \
        b"".join(struct.pack("<3f", *p) for p in XYZ[[0, 1, 2, 0]])
    path.write_bytes(header(["x", "y", "z"], [4, 4, 4], "FFF", [1, 1, 1], 5, data) + body)
    with pytest.raises(WorldError, match="POINTS 5, its data holds 4"):
        load_obstacle(path)


def test_a_cloud_of_invalid_points_only_is_refused(tmp_path):
    path = tmp_path / "empty.pcd"
    path.write_bytes(header(["x", "y", "z"], [4, 4, 4], "FFF", [1, 1, 1], 2, "ascii") + b"nan nan nan\nnan 0 0\n")
    with pytest.warns(UserWarning, match="dropped 2"), pytest.raises(WorldError, match="no point with finite"):
        load_obstacle(path)


def test_every_cloud_format_drops_its_invalid_points_with_one_warning(tmp_path):
    """A .npy and an .xyz of a depth image's organized cloud: pixels without a return are NaN."""
    rows = np.vstack([XYZ[:1], [[np.nan, np.nan, np.nan]], XYZ[1:], [[np.inf, 0.0, 1.0]]])
    np.save(tmp_path / "depth.npy", rows)
    np.savetxt(tmp_path / "depth.xyz", rows)
    for name in ("depth.npy", "depth.xyz"):
        with pytest.warns(UserWarning, match=f"{name}': dropped 2 invalid"):
            np.testing.assert_array_equal(load_obstacle(tmp_path / name).points, XYZ)


def literals(data: bytes) -> bytes:
    """LZF of ``data`` as literal runs alone (a control byte n - 1, then n <= 32 bytes): valid LZF."""
    return b"".join(bytes([len(data[i: i + 32]) - 1]) + data[i: i + 32] for i in range(0, len(data), 32))


def test_a_binary_compressed_cloud_reads_its_fields_one_after_the_other(tmp_path):
    """The fields stored whole one after another (x, then intensity, then y, then z), LZF-compressed."""
    path = tmp_path / "map.pcd"
    fields = (struct.pack("<3f", *XYZ[:, 0]) + struct.pack("<3H", 5, 6, 7) + struct.pack("<3d", *XYZ[:, 1])
              + struct.pack("<3f", *XYZ[:, 2]))
    packed = literals(fields)
    path.write_bytes(header(["x", "intensity", "y", "z"], [4, 2, 8, 4], "FUFF", [1, 1, 1, 1], len(XYZ),
                            "binary_compressed") + struct.pack("<II", len(packed), len(fields)) + packed)
    np.testing.assert_array_equal(load_obstacle(path).points, XYZ)
