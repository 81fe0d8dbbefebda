"""Camera rays and their intersection with the tissue height field.

The ray through pixel (u, v) passes through its centre (u + 0.5, v + 0.5) of the pinhole
K = [[f, 0, W/2], [0, f, H/2], [0, 0, 1]]; in camera space it is described by (xn, yn) =
(x/z, y/z), so its point at camera depth s is s * (xn, yn, 1). In the world (where the height
field lives) the camera centre is o and the ray direction d = R (xn, yn, 1) (R camera-to-world),
so the point at camera depth s is o + s d. The tissue hit solves
g(s) = o_z + s d_z - h(o_x + s d_x, o_y + s d_y, t) = 0, which is increasing in s for this
phantom and its camera paths (see `surface`; the tests check it), by the Illinois variant of
regula falsi on a bracket that holds the root for every ray.
"""

from __future__ import annotations

import numpy as np

from surgsplat.data.phantom.surface import TissueSurface

NEAR_MM = 10.0
"""Lower end of the root bracket: nearer than any tissue."""
FAR_MM = 400.0
"""Upper end of the root bracket: farther than any tissue."""
TOLERANCE_MM = 1e-7
"""Root-finding stops when every ray's |g(z)| is below this."""
MAX_ITERATIONS = 60
"""Root finding gives up after this many steps (it needs about 6)."""


def pixel_rays(width: int, height: int, focal: float) -> tuple[np.ndarray, np.ndarray]:
    """(xn, yn), each [H, W] float64: x/z and y/z of the ray through each pixel centre."""
    u = (np.arange(width) + 0.5 - width / 2.0) / focal
    v = (np.arange(height) + 0.5 - height / 2.0) / focal
    xn, yn = np.meshgrid(u, v)
    return xn, yn


def intersect_surface(surface: TissueSurface, t: float, origin: np.ndarray,
                      directions: np.ndarray) -> np.ndarray:
    """Camera depth s [...] mm where the rays o + s d first meet the tissue at time t.

    origin: [3] camera centre in the world, mm; directions: [..., 3] world ray directions
    whose camera-space z component is 1.
    """
    ox, oy, oz = (float(v) for v in origin)
    dx, dy, dz = (np.ascontiguousarray(directions[..., k]) for k in range(3))

    def residual(s: np.ndarray) -> np.ndarray:
        return oz + s * dz - surface.height(ox + s * dx, oy + s * dy, t)

    lo = np.full(dx.shape, NEAR_MM)
    hi = np.full(dx.shape, FAR_MM)
    g_lo, g_hi = residual(lo), residual(hi)
    if (g_lo >= 0).any() or (g_hi <= 0).any():
        raise RuntimeError(f"tissue leaves the depth bracket [{NEAR_MM}, {FAR_MM}] mm at t={t:g}")
    kept_side = np.zeros(dx.shape, dtype=np.int8)  # +1: hi moved last step, -1: lo moved
    for _ in range(MAX_ITERATIONS):
        z = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        g = residual(z)
        if np.abs(g).max() < TOLERANCE_MM:
            return z
        above = g > 0
        # Illinois: when the same end moves twice in a row, halve the other end's residual so
        # the secant stops creeping towards the root from one side.
        g_lo = np.where(above & (kept_side == 1), 0.5 * g_lo, g_lo)
        g_hi = np.where(~above & (kept_side == -1), 0.5 * g_hi, g_hi)
        hi, g_hi = np.where(above, z, hi), np.where(above, g, g_hi)
        lo, g_lo = np.where(above, lo, z), np.where(above, g_lo, g)
        kept_side = np.where(above, 1, -1).astype(np.int8)
    raise RuntimeError(f"tissue intersection did not converge in {MAX_ITERATIONS} steps at t={t:g}")
