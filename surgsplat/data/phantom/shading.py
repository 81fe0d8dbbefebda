"""Illumination of the phantom: an endoscope's point light at the camera centre.

Radiance = exposure(t) * (reference / r)^2 * (albedo * (ambient + diffuse * cos) + specular *
cos^shininess), with r the distance to the light and cos = n . l. The light sits at the camera
centre, so the Blinn-Phong half vector equals the light direction and n . h = n . l.
Stored images are this radiance clipped to [0, 1] (no gamma), so albedo and shading are exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Material:
    """How a surface reflects the light."""

    diffuse: float
    """Lambertian weight multiplying the albedo."""
    specular: float
    """Weight of the white Blinn-Phong highlight."""
    shininess: float
    """Blinn-Phong exponent: larger = smaller, sharper highlight."""


WET_TISSUE = Material(diffuse=1.0, specular=0.45, shininess=60.0)
METAL = Material(diffuse=0.55, specular=0.9, shininess=25.0)
SHAFT_RGB = np.array([0.22, 0.22, 0.24])
"""Albedo of the tool's dark shaft."""
JAW_RGB = np.array([0.62, 0.62, 0.64])
"""Albedo of the tool's steel jaws."""


@dataclass(frozen=True)
class Light:
    """The near-field point light at the camera centre."""

    intensity: float = 1.2
    """Radiance scale at the reference distance."""
    reference_mm: float = 85.0
    """Distance at which the inverse-square falloff equals 1."""
    ambient: float = 0.04
    """Light reaching every surface regardless of orientation, as a fraction of the albedo."""


@dataclass(frozen=True)
class Exposure:
    """The camera's smooth per-frame exposure factor 1 + amplitude * sin(2 pi cycles t + phase)."""

    amplitude: float = 0.15
    """Largest relative change (0.15 gives factors in [0.85, 1.15])."""
    cycles: float = 1.5
    """Oscillations per sequence."""
    phase: float = 0.0
    """Phase at t = 0, radians."""

    def factor(self, t: float) -> float:
        return float(1.0 + self.amplitude * np.sin(2 * np.pi * self.cycles * t + self.phase))


def shade(points: np.ndarray, normals: np.ndarray, albedo: np.ndarray, material: Material,
          light: Light, exposure: float) -> np.ndarray:
    """Radiance [..., 3] (unclipped) of surface points [..., 3] mm with unit normals [..., 3]
    and albedo [..., 3]."""
    distance = np.linalg.norm(points, axis=-1, keepdims=True)  # [..., 1]
    cos = np.clip(-np.einsum("...i,...i->...", normals, points)[..., None] / distance, 0.0, 1.0)
    falloff = light.intensity * (light.reference_mm / distance) ** 2
    highlight = material.specular * cos ** material.shininess
    lit = albedo * (light.ambient + material.diffuse * cos) + highlight
    return exposure * falloff * lit
