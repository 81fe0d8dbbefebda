"""PLY meshes: what write_ply_mesh writes, read_ply_mesh reads back; bad files are DataErrors."""

from pathlib import Path

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from surgsplat.data.ply import read_ply_mesh, write_ply_mesh
from surgsplat.errors import DataError


def random_mesh(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    vertices = rng.normal(0.0, 50.0, (40, 3))
    faces = rng.integers(0, 40, (70, 3))
    return vertices, faces


@pytest.mark.parametrize("with_colors", [False, True])
def test_round_trip(tmp_path: Path, with_colors: bool):
    vertices, faces = random_mesh()
    colors = np.random.default_rng(1).random((40, 3)) if with_colors else None
    path = write_ply_mesh(tmp_path / "m.ply", vertices, faces, colors)
    read_vertices, read_faces = read_ply_mesh(path)
    assert read_vertices.dtype == np.float32 and read_vertices.shape == (40, 3)
    np.testing.assert_array_equal(read_vertices, vertices.astype(np.float32))
    np.testing.assert_array_equal(read_faces, faces)
    header = path.read_bytes().split(b"end_header")[0]
    assert b"binary_little_endian" in header and (b"red" in header) == with_colors


def test_empty_mesh_round_trip(tmp_path: Path):
    path = write_ply_mesh(tmp_path / "e.ply", np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    vertices, faces = read_ply_mesh(path)
    assert vertices.shape == (0, 3) and faces.shape == (0, 3)


def test_bad_files_raise_data_error(tmp_path: Path):
    vertices, faces = random_mesh()
    good = write_ply_mesh(tmp_path / "good.ply", vertices, faces).read_bytes()
    header, body = good.split(b"end_header\n")
    cases = {
        "missing.ply": None,
        "text.ply": b"hello world\n",
        "ascii.ply": header.replace(b"binary_little_endian", b"ascii") + b"end_header\n" + body,
        "truncated.ply": good[:-10],
        "no_faces.ply": header.split(b"element face")[0] + b"end_header\n" + body,
        "bad_index.ply": good[:-4] + np.int32(999).tobytes(),
    }
    for name, content in cases.items():
        path = tmp_path / name
        if content is not None:
            path.write_bytes(content)
        with pytest.raises(DataError) as err:
            read_ply_mesh(path)
        assert name in str(err.value)


def test_quads_are_rejected(tmp_path: Path):
    vertices = np.zeros(4, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    quad = np.empty(1, dtype=[("vertex_indices", object)])
    quad["vertex_indices"][0] = np.array([0, 1, 2, 3], dtype=np.int32)
    PlyData([PlyElement.describe(vertices, "vertex"), PlyElement.describe(quad, "face")],
            text=False, byte_order="<").write(str(tmp_path / "q.ply"))
    with pytest.raises(DataError, match="not triangles"):
        read_ply_mesh(tmp_path / "q.ply")


def test_write_rejects_bad_arrays(tmp_path: Path):
    vertices, faces = random_mesh()
    with pytest.raises(ValueError):
        write_ply_mesh(tmp_path / "a.ply", vertices[:, :2], faces)
    with pytest.raises(ValueError):
        write_ply_mesh(tmp_path / "b.ply", vertices, faces + 40)
