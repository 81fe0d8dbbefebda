"""Triangle meshes as binary little-endian PLY files.

`write_ply_mesh` writes float32 vertex positions, optional 8-bit RGB vertex colours and
triangles as `list uchar int vertex_indices`; `read_ply_mesh` reads any binary little-endian
PLY with a `vertex` element (x, y, z and any other scalar properties) followed by a `face`
element of triangles, which includes every file `write_ply_mesh` writes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from surgsplat.errors import DataError

_FORMAT = "binary_little_endian"
_SCALAR_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "<i2", "int16": "<i2", "ushort": "<u2", "uint16": "<u2",
    "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
    "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8",
}


def write_ply_mesh(path: str | Path, vertices: np.ndarray, faces: np.ndarray,
                   colors: np.ndarray | None = None) -> Path:
    """Write a triangle mesh; vertices [V, 3] float (stored as float32), faces [F, 3] int
    vertex indices, colors [V, 3] uint8 RGB or float in [0, 1] (optional)."""
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
    face_rows = np.empty(len(faces), dtype=[("count", "u1"), ("indices", "<i4", (3,))])
    face_rows["count"] = 3
    face_rows["indices"] = faces
    header = ["ply", f"format {_FORMAT} 1.0", f"element vertex {len(vertices)}",
              "property float x", "property float y", "property float z"]
    if colors is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices",
               "end_header"]
    with path.open("wb") as file:
        file.write(("\n".join(header) + "\n").encode("ascii"))
        file.write(vertex_rows.tobytes())
        file.write(face_rows.tobytes())
    return path


def read_ply_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a binary little-endian triangle mesh: (vertices [V, 3] float32, faces [F, 3] int64)."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise DataError(path, f"cannot be read ({err})") from err
    end = data.find(b"end_header")
    newline = data.find(b"\n", end) if end >= 0 else -1
    if not data.startswith(b"ply") or newline < 0:
        raise DataError(path, "not a PLY file: expected 'ply' ... 'end_header' and a newline")
    body_start = newline + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    vertex_count, vertex_dtype, face_count, face_dtype = _parse_header(path, header)
    vertex_bytes = vertex_count * vertex_dtype.itemsize
    needed = vertex_bytes + face_count * face_dtype.itemsize
    if len(data) - body_start < needed:
        raise DataError(path, f"truncated: header announces {vertex_count} vertices and "
                              f"{face_count} faces ({needed} bytes), file holds "
                              f"{len(data) - body_start}")
    vertex_rows = np.frombuffer(data, dtype=vertex_dtype, count=vertex_count, offset=body_start)
    face_rows = np.frombuffer(data, dtype=face_dtype, count=face_count,
                              offset=body_start + vertex_bytes)
    if face_count and (face_rows["count"] != 3).any():
        raise DataError(path, "holds faces that are not triangles; only triangle meshes are read")
    vertices = np.stack([vertex_rows[name] for name in "xyz"], axis=1).astype(np.float32)
    faces = face_rows["indices"].astype(np.int64).reshape(face_count, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= vertex_count):
        raise DataError(path, f"face indices outside [0, {vertex_count})")
    return vertices, faces


def _parse_header(path: Path, lines: list[str]) -> tuple[int, np.dtype, int, np.dtype]:
    """(vertex count, vertex record dtype, face count, face record dtype) from header lines."""
    elements: list[tuple[str, int, list[list[str]]]] = []
    file_format = None
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3:
            file_format = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            elements[-1][2].append(words[1:])
        else:
            raise DataError(path, f"unexpected PLY header line {line!r}")
    if file_format != _FORMAT:
        raise DataError(path, f"PLY format {file_format!r} is not supported; expected {_FORMAT}")
    names = [name for name, _, _ in elements]
    if names != ["vertex", "face"]:
        raise DataError(path, f"expected elements ['vertex', 'face'] in that order, got {names}")
    (_, vertex_count, vertex_props), (_, face_count, face_props) = elements
    vertex_fields = []
    for prop in vertex_props:
        if len(prop) != 2 or prop[0] not in _SCALAR_TYPES:
            raise DataError(path, f"unsupported vertex property {' '.join(prop)!r}")
        vertex_fields.append((prop[1], _SCALAR_TYPES[prop[0]]))
    if not {"x", "y", "z"} <= {name for name, _ in vertex_fields}:
        raise DataError(path, "vertex element lacks x, y and z properties")
    if (len(face_props) != 1 or len(face_props[0]) != 4 or face_props[0][0] != "list"
            or face_props[0][1] not in _SCALAR_TYPES or face_props[0][2] not in _SCALAR_TYPES):
        raise DataError(path, "face element must hold exactly one 'property list <count type> "
                              "<index type> vertex_indices'")
    count_type, index_type = (_SCALAR_TYPES[word] for word in face_props[0][1:3])
    face_dtype = np.dtype([("count", count_type), ("indices", index_type, (3,))])
    return vertex_count, np.dtype(vertex_fields), face_count, face_dtype
