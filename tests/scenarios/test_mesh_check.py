"""Meshes the judge cannot be exact on give one line naming the file and the problem; meshes it
can take otherwise (open, with droppable degenerate faces) give one line of warning (scenarios.mesh_check)."""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest
import trimesh

from scenarios.mesh_check import MAX_FACES, MeshWarning
from scenarios.obstacle_file import UP, load_obstacle
from scenarios.world import MeshObstacle, WorldError

TETRA = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"


def binary_stl(path, faces: int):
    """A binary STL of ``faces`` faces (all zero, the file sparse: nothing is written past the header)."""
    with open(path, "wb") as handle:
        handle.write(b"\0" * 80 + struct.pack("<I", faces))
        handle.truncate(84 + 50 * faces)


@pytest.mark.parametrize("name, content, problem", [
    ("empty.obj", "# nothing\n", "no geometry"),
    ("noface.ply", "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
                   "element face 0\nproperty list uchar int vertex_indices\nend_header\n", "no geometry"),
    ("nan.obj", TETRA.replace("v 1 0 0", "v nan 0 0"), "NaN"),
    ("inf.obj", TETRA.replace("v 1 0 0", "v inf 0 0"), "NaN or infinite"),
    ("flat.obj", "v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "degenerate"),
    ("stray.obj", TETRA + "v 5 5 5\nv 6 6 6\nf 5 6 6\n", "degenerate faces"),
    ("noise.stl", bytes(range(256)) * 3, "no geometry"),
    ("huge.stl", "10^7", f"{MAX_FACES:,}"),
])
def test_bad_mesh_files_give_one_line_naming_the_file_and_the_problem(tmp_path, name, content, problem):
    path = tmp_path / name
    if content == "10^7":
        binary_stl(path, 10_000_000)
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    with pytest.raises(WorldError) as err:
        load_obstacle(path)
    message = str(err.value)
    assert name in message and "\n" not in message and problem in message


def test_an_open_or_inconsistently_wound_mesh_is_a_surface_with_one_warning(tmp_path):
    open_path = tmp_path / "open.obj"
    open_path.write_text(TETRA.rsplit("f", 1)[0])  # one face missing
    fin = tmp_path / "fin.obj"
    fin.write_text(TETRA + "v 1 1 0\nf 1 2 5\n")  # a third face on the edge 1-2
    turned = tmp_path / "turned.obj"
    turned.write_text(TETRA.replace("f 2 3 4", "f 2 4 3"))  # one face wound against the others
    for path in (open_path, fin, turned):
        with pytest.warns(MeshWarning) as caught:
            mesh = load_obstacle(path)
        assert len(caught) == 1 and path.name in str(caught[0].message) and "\n" not in str(caught[0].message)
        assert not mesh.closed


def test_degenerate_faces_on_the_surface_are_dropped_with_a_warning(tmp_path):
    path = tmp_path / "sliver.obj"
    path.write_text(TETRA + "v 0.5 0 0\nf 1 5 2\n")  # collinear along the tetrahedron's edge 1-2
    with pytest.warns(MeshWarning, match="dropped 1 degenerate"):
        mesh = load_obstacle(path)
    assert len(mesh.faces) == 4 and mesh.closed


def test_a_closed_mesh_is_closed_whatever_its_winding_and_vertex_sharing(tmp_path):
    box = trimesh.creation.box(extents=(1, 2, 3))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        inward = MeshObstacle(box.vertices, box.faces[:, ::-1])
        box.export(tmp_path / "box.stl")  # STL repeats each vertex per face
        from_file = load_obstacle(tmp_path / "box.stl")
    assert inward.closed and from_file.closed
    # turned outwards: the volume the faces bound is positive
    tri = inward.triangles
    assert np.sum(tri[:, 0] * np.cross(tri[:, 1], tri[:, 2])) / 6 == pytest.approx(6.0)


def test_solids_touching_at_a_face_or_an_edge_are_closed_and_their_insides_inside(tmp_path):
    """Boxes written as one mesh whose shared corners merge: an edge in four faces (two each way) is
    no hole, and the winding number counts each box's inside (a point in the seam is on the surface)."""
    a = trimesh.creation.box(bounds=[(0, 0, 0), (1, 1, 1)])
    b = trimesh.creation.box(bounds=[(1, 0, 0), (2, 1, 1)])  # shares a's face x = 1
    c = trimesh.creation.box(bounds=[(2, 1, 0), (3, 2, 1)])  # shares b's edge x = 2, y = 1
    trimesh.util.concatenate([a, b, c]).export(tmp_path / "blocks.stl")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        mesh = load_obstacle(tmp_path / "blocks.stl")
    assert len(mesh.vertices) == 8 + 4 + 6 and mesh.closed  # 8 + 8 + 8 corners less 4 and 2 shared
    inside = mesh.index.inside(np.array([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [2.5, 1.5, 0.5], [2.5, 0.5, 0.5],
                                         [1.5, 1.5, 0.5], [1.5, 0.5, 1.5]]))
    assert inside.tolist() == [True, True, True, False, False, False]


def test_each_up_axis_is_turned_to_plus_z_by_a_rotation_and_a_glTF_box_stands_where_its_file_says(tmp_path):
    for name, turn in UP.items():
        axis = np.zeros(3)
        axis["xyz".index(name[-1])] = -1.0 if name.startswith("-") else 1.0
        np.testing.assert_array_equal(turn @ axis, [0.0, 0.0, 1.0])
        assert np.allclose(turn @ turn.T, np.eye(3)) and np.linalg.det(turn) == pytest.approx(1.0)
    # a 1 x 2 x 3 box whose file says: 5 m up (+y), 4 m towards the viewer (+z), 1 m along x
    box = trimesh.creation.box(extents=(1.0, 3.0, 2.0)).apply_translation((1.0, 5.0, 4.0))
    box.export(tmp_path / "crate.glb")
    mesh = load_obstacle(tmp_path / "crate.glb", offset=(0.0, 0.0, 0.5), up="y")
    in_cm = load_obstacle(tmp_path / "crate.glb", offset=(0.0, 0.0, 0.5), up="y", units="cm")
    np.testing.assert_allclose(in_cm.vertices, 0.01 * (mesh.vertices - [0, 0, 0.5]) + [0, 0, 0.5], atol=1e-12)
    lower, upper = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    np.testing.assert_allclose((lower + upper) / 2, [1.0, -4.0, 5.5], atol=1e-6)  # +z of the file is -y here
    np.testing.assert_allclose(upper - lower, [1.0, 2.0, 3.0], atol=1e-6)
    assert mesh.closed and np.sum(mesh.triangles[:, 0] * np.cross(mesh.triangles[:, 1], mesh.triangles[:, 2])) > 0
    with pytest.raises(WorldError, match="up axis 'w'"):
        load_obstacle(tmp_path / "crate.glb", up="w")
