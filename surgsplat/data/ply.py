"""Triangle meshes as binary little-endian PLY files, read and written with plyfile.

`write_ply_mesh` writes float32 vertex positions, optional 8-bit RGB vertex colours and triangles
as `list uchar int vertex_indices`; `read_ply_mesh` reads any PLY (binary or ASCII) whose `vertex`
element has x, y and z and whose `face` element holds triangles as `vertex_indices` (or
`vertex_index`), which includes every file `write_ply_mesh` writes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from surgsplat.errors import DataError


def write_ply_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
                   colors: np.ndarray | None = None) -> Path:
    """Write a triangle mesh; vertices [V, 3] float (stored as float32), faces [F, 3] int vertex
    indices, colors [V, 3] uint8 RGB or float in [0, 1] (optional)."""
    path = Path(path)
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must have shape [V, 3], got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"faces must have shape [F, 3], got {faces.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"face indices must lie in [0, {len(vertices)})")
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != vertices.shape:
            raise ValueError(f"colors must have shape {vertices.shape}, got {colors.shape}")
        if colors.dtype != np.uint8:
            colors = np.clip(np.rint(colors * 255.0), 0, 255).astype(np.uint8)
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vertex_rows = np.empty(len(vertices), dtype=fields)
    for axis, name in enumerate("xyz"):
        vertex_rows[name] = vertices[:, axis]
    if colors is not None:
        for channel, name in enumerate(("red", "green", "blue")):
            vertex_rows[name] = colors[:, channel]
    face_rows = np.empty(len(faces), dtype=[("vertex_indices", "<i4", (3,))])
    face_rows["vertex_indices"] = faces
    PlyData([PlyElement.describe(vertex_rows, "vertex"),
             PlyElement.describe(face_rows, "face", len_types={"vertex_indices": "u1"})],
            text=False, byte_order="<").write(str(path))
    return path


def read_ply_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh: (vertices [V, 3] float32, faces [F, 3] int64)."""
    path = Path(path)
    try:
        data = PlyData.read(str(path))
    except OSError as err:
        raise DataError(path, f"cannot be read ({err})") from err
    except Exception as err:  # plyfile reports malformed files with assorted exception types
        raise DataError(path, f"not a readable PLY mesh ({type(err).__name__}: {err})") from err
    names = [element.name for element in data.elements]
    if "vertex" not in names or "face" not in names:
        raise DataError(path, f"expected 'vertex' and 'face' elements, got {names}")
    vertex, face = data["vertex"], data["face"]
    if not {"x", "y", "z"} <= {prop.name for prop in vertex.properties}:
        raise DataError(path, "vertex element lacks x, y and z properties")
    vertices = np.stack([vertex[name] for name in "xyz"], axis=1).astype(np.float32)
    key = next((name for name in ("vertex_indices", "vertex_index")
                if name in {prop.name for prop in face.properties}), None)
    if key is None:
        raise DataError(path, "face element has no vertex_indices list")
    rows = face[key]
    if len(rows) and any(len(row) != 3 for row in rows):
        raise DataError(path, "holds faces that are not triangles; only triangle meshes are read")
    faces = np.asarray(np.stack(rows) if len(rows) else np.zeros((0, 3)), dtype=np.int64)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise DataError(path, f"face indices outside [0, {len(vertices)})")
    return vertices, faces
