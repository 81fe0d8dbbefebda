"""The deforming tissue: a height field z = h(x, y, t) in camera space, millimetres.

The camera sits at the origin looking down +z (OpenCV axes, y down). Tissue points are
labelled by material coordinates (X, Y) = (x, y) - breathing shift(t); the texture and the
motion terms are attached to them, so they move with the tissue. The height is

    h = base depth + tilt . (X, Y) + sum of gentle waves + breathing dz(t)
        - pulling bump(t) around the grasp point + cutting groove(t) along the cut line,

whose slope |grad h| stays below 1.3 outside the cut (which lies near the optical axis, where
rays run almost along z). The camera rays' slopes |(x/z, y/z)| stay below 0.72 for the presets'
field of view, so z - h(z x/z, z y/z) increases along every ray (the tests check this) and
the first hit is the only one.
"""

from __future__ import annotations

import numpy as np

from surgsplat.data.phantom.motion import MotionProgram, smoothstep

BASE_DEPTH_MM = 90.0
"""Depth of the tissue's mean plane on the optical axis."""
WAVE_COUNT = 5
"""Number of sinusoidal waves that make the surface uneven."""
WAVE_SLOPE_TOTAL = 0.4
"""Sum of the waves' maximum slopes (bounds their combined slope)."""
BREATH_CYCLES = 2.0
"""Breathing cycles per sequence."""
BREATH_AMPLITUDE_MM = (0.8, 0.6, 1.2)
"""Breathing amplitude of the (x, y) shift and of the depth change."""
BUMP_SIGMA_MM = 11.0
"""Width of the tissue bump lifted by the grasping tool."""
CUT_LENGTH_MM = 40.0
"""Length of the cut line."""
GROOVE_DEPTH_MM = 3.5
"""Depth of the fully opened groove."""
GROOVE_WIDTH_MM = (2.5, 4.0)
"""Gaussian width of the groove's cross-section when it starts and when fully open."""
GROOVE_RAMP = 0.35
"""Fraction of the cut line behind the cut front over which the groove opens fully."""
GROOVE_TAPER = 0.2
"""Fraction of the cut line at each end over which the groove fades out."""
GRADIENT_STEP_MM = 1e-3
"""Step of the central differences that give the surface slope."""


class TissueSurface:
    """The tissue height field of one phantom, deterministic from `seed`."""

    def __init__(self, seed: int, motion: MotionProgram):
        rng = np.random.default_rng([seed, 1])
        self.motion = motion
        self.tilt = np.array([rng.uniform(-0.15, 0.15),  # dz/dX, dz/dY: an oblique view
                              rng.choice([-1.0, 1.0]) * rng.uniform(0.15, 0.3)])
        wavelengths = rng.uniform(35.0, 80.0, WAVE_COUNT)
        angles = rng.uniform(0.0, np.pi, WAVE_COUNT)
        slopes = rng.dirichlet(np.ones(WAVE_COUNT)) * WAVE_SLOPE_TOTAL
        self.wave_amplitude = slopes * wavelengths / (2 * np.pi)  # [K] mm
        self.wave_vector = (2 * np.pi / wavelengths)[:, None] * np.stack(
            [np.cos(angles), np.sin(angles)], axis=1)  # [K, 2] rad/mm
        self.wave_phase = rng.uniform(0.0, 2 * np.pi, WAVE_COUNT)
        self.breath_phase = float(rng.uniform(0.0, 2 * np.pi))
        self.grasp = rng.uniform([-15.0, -10.0], [15.0, 10.0])  # material (X, Y) mm
        cut_centre = rng.uniform([-10.0, -8.0], [10.0, 8.0])
        cut_angle = rng.uniform(0.0, np.pi)
        self.cut_direction = np.array([np.cos(cut_angle), np.sin(cut_angle)])
        self.cut_start = cut_centre - 0.5 * CUT_LENGTH_MM * self.cut_direction  # material (X, Y)

    def breathing(self, t: float) -> tuple[np.ndarray, float]:
        """(shift [2] mm of material points in x, y, depth change mm) at time t."""
        angle = 2 * np.pi * BREATH_CYCLES * t + self.breath_phase
        ax, ay, az = BREATH_AMPLITUDE_MM
        return np.array([ax * np.sin(angle), ay * np.sin(angle + 0.6)]), az * np.sin(angle)

    def material(self, x: np.ndarray, y: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Material coordinates (X, Y) of the tissue point seen at camera-space (x, y)."""
        shift, _ = self.breathing(t)
        return x - shift[0], y - shift[1]

    def camera_xy(self, material_xy: np.ndarray, t: float) -> np.ndarray:
        """Camera-space (x, y) [2] of material point `material_xy` [2] at time t."""
        shift, _ = self.breathing(t)
        return material_xy + shift

    def height(self, x: np.ndarray, y: np.ndarray, t: float) -> np.ndarray:
        """Tissue depth z (mm) above camera-space (x, y) at time t; same shape as x."""
        X, Y = self.material(x, y, t)
        _, breath_dz = self.breathing(t)
        z = BASE_DEPTH_MM + breath_dz + self.tilt[0] * X + self.tilt[1] * Y
        wave = np.empty_like(z)  # in-place updates: this is the phantom's hot loop
        for amplitude, (kx, ky), phase in zip(self.wave_amplitude, self.wave_vector,
                                              self.wave_phase):
            np.multiply(X, kx, out=wave)
            wave += ky * Y + phase
            np.sin(wave, out=wave)
            wave *= amplitude
            z += wave
        lift = self.motion.lift_mm(t)
        if lift > 0:
            r2 = (X - self.grasp[0]) ** 2 + (Y - self.grasp[1]) ** 2
            z -= lift * np.exp(r2 * (-0.5 / BUMP_SIGMA_MM ** 2))
        if self.motion.cut_front(t) > 0:
            z += GROOVE_DEPTH_MM * self._groove_opening(X, Y, t)
        return z

    def opening(self, x: np.ndarray, y: np.ndarray, t: float) -> np.ndarray:
        """How open the cut is at camera-space (x, y): 0 = intact tissue, 1 = groove floor."""
        if self.motion.cut_front(t) <= 0:
            return np.zeros_like(x)
        return self._groove_opening(*self.material(x, y, t), t)

    def _groove_opening(self, X: np.ndarray, Y: np.ndarray, t: float) -> np.ndarray:
        dx, dy = X - self.cut_start[0], Y - self.cut_start[1]
        along = (dx * self.cut_direction[0] + dy * self.cut_direction[1]) / CUT_LENGTH_MM
        across = dx * self.cut_direction[1] - dy * self.cut_direction[0]  # mm
        low, high = GROOVE_WIDTH_MM
        # The taper is exactly 0 off the line's ends, and 8 widths aside exp(-32) ~ 1e-14.
        band = (along > 0.0) & (along < 1.0) & (np.abs(across) < 8 * high)
        along, across = along[band], across[band]
        opened = smoothstep((self.motion.cut_front(t) - along) / GROOVE_RAMP)
        taper = smoothstep(along / GROOVE_TAPER) * smoothstep((1.0 - along) / GROOVE_TAPER)
        width = low + (high - low) * opened
        opening = np.zeros_like(X)
        opening[band] = opened * taper * np.exp(-across ** 2 / (2 * width ** 2))
        return opening

    def gradient(self, x: np.ndarray, y: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(dh/dx, dh/dy) at camera-space (x, y), by central differences."""
        e = GRADIENT_STEP_MM
        hx = (self.height(x + e, y, t) - self.height(x - e, y, t)) / (2 * e)
        hy = (self.height(x, y + e, t) - self.height(x, y - e, t)) / (2 * e)
        return hx, hy

    def normals(self, x: np.ndarray, y: np.ndarray, t: float) -> np.ndarray:
        """Unit normals [..., 3] of the surface at camera-space (x, y), pointing to the camera."""
        hx, hy = self.gradient(x, y, t)
        n = np.stack([hx, hy, -np.ones_like(hx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def anchor(self, t: float) -> np.ndarray:
        """Camera-space point [3] the tool works at: the grasp point (pulling) or the cut front
        clipped to the cut line (cutting), on the surface."""
        if self.motion.name == "cutting":
            front = np.clip(self.motion.cut_front(t), 0.0, 1.0)
            material_xy = self.cut_start + front * CUT_LENGTH_MM * self.cut_direction
        else:
            material_xy = self.grasp
        x, y = self.camera_xy(material_xy, t)
        return np.array([x, y, float(self.height(np.array(x), np.array(y), t))])
