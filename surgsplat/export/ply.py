"""Gaussians as a standard 3D Gaussian Splatting PLY file (the layout of the 3DGS reference code,
which splat viewers and editors such as SuperSplat, the antimatter15 / gsplat.js web viewers,
nerfstudio's and Polycam's splat tools open).

One binary little-endian `vertex` element, float32 properties in this order:
x, y, z (position); nx, ny, nz (zeros, unused by 3DGS); f_dc_0..2 (degree-0 SH colour);
f_rest_0..f_rest_{3(K-1)-1} (higher SH degrees, channel-major: all of red's K-1 coefficients,
then green's, then blue's); opacity (a logit: opacity = sigmoid(value)); scale_0..2 (logs of the
scales); rot_0..3 (unit quaternion w, x, y, z). Positions and scales are in the scene's unit
(millimetres for the phantom), in surgsplat's world frame (OpenCV axes of the first camera).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from plyfile import PlyData, PlyElement, PlyParseError

from surgsplat.atomic import write_atomic
from surgsplat.errors import DataError
from surgsplat.model.state import GaussianState

POSITION = ("x", "y", "z")
NORMAL = ("nx", "ny", "nz")
DC = ("f_dc_0", "f_dc_1", "f_dc_2")
SCALE = ("scale_0", "scale_1", "scale_2")
ROTATION = ("rot_0", "rot_1", "rot_2", "rot_3")
OPACITY_EPS = 1e-6
"""Opacities are clamped to [eps, 1 - eps] before taking the logit."""


def rest_names(num_coeffs: int) -> list[str]:
    """f_rest_* property names for K = num_coeffs SH coefficients per channel."""
    return [f"f_rest_{i}" for i in range(3 * (num_coeffs - 1))]


def write_gaussian_ply(state: GaussianState, path: Path) -> None:
    """Write the N Gaussians of `state` (see the module docstring) to `path`, atomically."""
    with torch.no_grad():
        sh = state.sh.detach().float()  # [N, K, 3]
        rest = sh[:, 1:, :].transpose(1, 2).reshape(sh.shape[0], -1)  # [N, 3 (K-1)]
        opacity = state.opacities.detach().float().clamp(OPACITY_EPS, 1 - OPACITY_EPS)
        columns = {
            **_named(POSITION, state.means), **_named(NORMAL, torch.zeros_like(state.means)),
            **_named(DC, sh[:, 0, :]), **_named(rest_names(sh.shape[1]), rest),
            "opacity": torch.logit(opacity),
            **_named(SCALE, state.scales.detach().float().log()),
            **_named(ROTATION, torch.nn.functional.normalize(state.quats.detach().float(), dim=-1)),
        }
    vertices = np.empty(sh.shape[0], dtype=[(name, "<f4") for name in columns])
    for name, values in columns.items():
        vertices[name] = values.detach().cpu().numpy()
    data = PlyData([PlyElement.describe(vertices, "vertex")], text=False, byte_order="<")
    write_atomic(Path(path), data.write)


def read_gaussian_ply(path: Path) -> GaussianState:
    """The Gaussians of a 3DGS PLY file; DataError naming the file when it is not one."""
    path = Path(path)
    try:
        data = PlyData.read(str(path))
    except (OSError, ValueError, PlyParseError) as err:
        raise DataError(path, f"cannot be read as a PLY file ({err})") from err
    if "vertex" not in data:
        raise DataError(path, "has no 'vertex' element: not a 3D Gaussian Splatting PLY")
    vertex = data["vertex"]
    names = set(vertex.data.dtype.names)
    missing = [n for n in (*POSITION, *DC, "opacity", *SCALE, *ROTATION) if n not in names]
    if missing:
        raise DataError(path, f"lacks the 3DGS properties {missing}")
    rest_count = sum(1 for name in names if name.startswith("f_rest_"))
    num_coeffs = rest_count // 3 + 1
    degree = round(num_coeffs ** 0.5) - 1
    if rest_count % 3 or (degree + 1) ** 2 != num_coeffs:
        raise DataError(path, f"has {rest_count} f_rest_* properties; expected 3 ((d+1)^2 - 1)")

    def stack(columns) -> torch.Tensor:  # [N, len(columns)] (degree-0 files have no f_rest_*)
        arrays = [np.asarray(vertex[c], dtype=np.float32) for c in columns]
        return torch.from_numpy(np.stack(arrays, axis=1) if arrays
                                else np.zeros((vertex.count, 0), dtype=np.float32))

    rest = stack(rest_names(num_coeffs)).reshape(vertex.count, 3, num_coeffs - 1).transpose(1, 2)
    return GaussianState(means=stack(POSITION), scales=stack(SCALE).exp(),
                         quats=stack(ROTATION), opacities=torch.sigmoid(stack(("opacity",))[:, 0]),
                         sh=torch.cat([stack(DC)[:, None, :], rest], dim=1), sh_degree=degree)


def _named(names, values: torch.Tensor) -> dict[str, torch.Tensor]:
    """One column per name from values [N, len(names)]."""
    return {name: values[:, i] for i, name in enumerate(names)}
