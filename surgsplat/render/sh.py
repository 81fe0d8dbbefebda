"""Real spherical harmonics up to degree 3 for view-dependent colour (the 3DGS convention:
colour = sum_k c_k Y_k(d) + 0.5, clamped at 0)."""

from __future__ import annotations

import torch
from torch import Tensor

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
         -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def sh_basis(degree: int, dirs: Tensor) -> Tensor:
    """[N, 3] unit directions -> [N, (degree+1)^2] basis values."""
    x, y, z = dirs.unbind(-1)
    basis = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        basis += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        basis += [SH_C2[0] * xy, SH_C2[1] * yz, SH_C2[2] * (2 * zz - xx - yy),
                  SH_C2[3] * xz, SH_C2[4] * (xx - yy)]
    if degree >= 3:
        basis += [SH_C3[0] * y * (3 * xx - yy), SH_C3[1] * xy * z,
                  SH_C3[2] * y * (4 * zz - xx - yy), SH_C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
                  SH_C3[4] * x * (4 * zz - xx - yy), SH_C3[5] * z * (xx - yy),
                  SH_C3[6] * x * (xx - 3 * yy)]
    return torch.stack(basis, dim=-1)


def eval_sh(degree: int, coeffs: Tensor, dirs: Tensor) -> Tensor:
    """Colour [N, 3] of SH coefficients [N, K>=(degree+1)^2, 3] seen along unit dirs [N, 3]."""
    if not 0 <= degree <= 3:
        raise ValueError(f"spherical-harmonic degree must be 0..3, got {degree}")
    num = (degree + 1) ** 2
    if coeffs.shape[1] < num:
        raise ValueError(f"degree {degree} needs {num} SH coefficients, got {coeffs.shape[1]}")
    basis = sh_basis(degree, dirs)  # [N, num]
    return torch.clamp_min((basis[:, :, None] * coeffs[:, :num]).sum(1) + 0.5, 0.0)
