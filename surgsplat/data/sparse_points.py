"""The sparse points of a scene (layout.SPARSE_POINTS_FILE): from structure from motion at
import, the initial points of a scene without depth.

A binary little-endian PLY point cloud (plyfile) whose `vertex` element has float x, y, z (world
frame, scene units) and 8-bit red, green, blue.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from plyfile import PlyData, PlyElement

from surgsplat.data.layout import SPARSE_POINTS_FILE
from surgsplat.errors import DataError


def write_sparse_points(root: Path, points: np.ndarray, colors: np.ndarray) -> Path:
    """Write points [M, 3] (scene units) and colors [M, 3] uint8 RGB to root/SPARSE_POINTS_FILE."""
    if points.ndim != 2 or points.shape[1] != 3 or colors.shape != points.shape:
        raise ValueError(f"expected points and colors of shape [M, 3], got {points.shape} and "
                         f"{colors.shape}")
    rows = np.empty(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                        ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for axis, name in enumerate("xyz"):
        rows[name] = points[:, axis]
    for channel, name in enumerate(("red", "green", "blue")):
        rows[name] = colors[:, channel]
    path = Path(root) / SPARSE_POINTS_FILE
    PlyData([PlyElement.describe(rows, "vertex")], text=False, byte_order="<").write(str(path))
    return path


def read_sparse_points(root: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(points [M, 3] float32 in scene units, colors [M, 3] float32 RGB in [0, 1]) of
    root/SPARSE_POINTS_FILE, None when the scene has none; DataError unless the file holds
    at least one finite point with x, y, z, red, green and blue."""
    path = Path(root) / SPARSE_POINTS_FILE
    if not path.is_file():
        return None
    try:
        vertex = PlyData.read(str(path))["vertex"]
    except OSError as err:
        raise DataError(path, f"cannot be read ({err})") from err
    except Exception as err:  # plyfile reports malformed files with assorted exception types
        raise DataError(path, f"not a readable PLY point cloud with a 'vertex' element "
                              f"({type(err).__name__}: {err})") from err
    names = {prop.name for prop in vertex.properties}
    missing = [n for n in ("x", "y", "z", "red", "green", "blue") if n not in names]
    if missing:
        raise DataError(path, f"vertex element lacks {', '.join(missing)}")
    points = np.stack([vertex[n] for n in "xyz"], axis=1).astype(np.float32)
    colors = np.stack([vertex[n] for n in ("red", "green", "blue")], axis=1)
    if len(points) == 0 or not np.isfinite(points).all():
        raise DataError(path, f"expected at least one point with finite coordinates, got "
                              f"{len(points)} points")
    if colors.dtype != np.uint8:
        raise DataError(path, f"colours must be 8-bit (uchar), got {colors.dtype}")
    return points, colors.astype(np.float32) / 255.0
