"""Illumination of the phantom: an endoscope's point light, at the camera centre by default.

Radiance = exposure(t) * (reference / r)^2 * (albedo * (ambient + diffuse * cos) + specular *
cos_h^shininess), with r the distance to the light, cos = n . l and cos_h = n . h for the
Blinn-Phong half vector h of the light and view directions. With the light at the camera centre
h equals the light direction, so cos_h = cos. Stored images are this radiance clipped to [0, 1]
(no gamma), so albedo and shading are exact: image = albedo * shading + specular before the clip,
with shading = exposure * (reference / r)^2 * (ambient + diffuse * cos) (`diffuse_shading`).

A `LightingProgram` makes the light change over the clip (`LIGHTINGS`): "standard" is the
default light and exposure; "livar" the same with the true shading written to gt/shading;
"hivar" a light whose intensity and the camera's exposure each vary by more than 2x and which
sits off the camera centre, circling the optical axis, so the shading moves across the tissue.
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


@dataclass(frozen=True)
class LightingProgram:
    """How the light changes over the clip."""

    name: str
    """One of LIGHTINGS."""
    exposure_amplitude: float
    """Amplitude of the camera's exposure factor (see Exposure)."""
    intensity: float
    """Light intensity at the reference distance (Light.intensity) before its variation."""
    intensity_amplitude: float = 0.0
    """Relative amplitude of the intensity's variation 1 + a sin(2 pi cycles t + phase)."""
    intensity_cycles: float = 1.0
    """Oscillations of the intensity per sequence."""
    offset_mm: float = 0.0
    """Distance of the light from the camera centre, in the image plane (0 = at the centre)."""
    offset_turns: float = 0.0
    """Turns of the offset light about the optical axis over the sequence."""
    writes_shading: bool = False
    """Write the true shading of every frame to gt/shading."""

    def intensity_factor(self, t: float, phase: float) -> float:
        """The intensity's relative factor at time t."""
        return float(1.0 + self.intensity_amplitude
                     * np.sin(2 * np.pi * self.intensity_cycles * t + phase))

    def light_position(self, t: float, angle: float) -> np.ndarray | None:
        """[3] camera-space light position mm at time t (None = the camera centre), starting at
        `angle` radians about the optical axis."""
        if self.offset_mm == 0.0:
            return None
        turn = angle + 2 * np.pi * self.offset_turns * t
        return np.array([self.offset_mm * np.cos(turn), self.offset_mm * np.sin(turn), 0.0])


LIGHTINGS = {
    "standard": LightingProgram("standard", exposure_amplitude=0.15, intensity=1.2),
    "livar": LightingProgram("livar", exposure_amplitude=0.15, intensity=1.2,
                             writes_shading=True),
    "hivar": LightingProgram("hivar", exposure_amplitude=0.4, intensity=0.8,
                             intensity_amplitude=0.4, intensity_cycles=1.0, offset_mm=6.0,
                             offset_turns=0.5, writes_shading=True),
}
"""Lighting programs by name. hivar's exposure spans [0.6, 1.4] (2.3x) and its intensity
[0.6, 1.4] (2.3x); its lower base intensity keeps the brightest frames from saturating."""


def _light_geometry(points: np.ndarray, normals: np.ndarray, light: Light,
                    light_position: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(falloff, cos, cos_h), each [..., 1], of surface points [..., 3] mm with unit normals
    [..., 3] lit from `light_position` [3] mm (None = the camera centre)."""
    if light_position is None:
        distance = np.linalg.norm(points, axis=-1, keepdims=True)  # [..., 1]
        cos = np.clip(-np.einsum("...i,...i->...", normals, points)[..., None] / distance,
                      0.0, 1.0)
        cos_h = cos
    else:
        to_light = light_position - points  # [..., 3]
        distance = np.linalg.norm(to_light, axis=-1, keepdims=True)
        to_light = to_light / distance
        to_camera = -points / np.linalg.norm(points, axis=-1, keepdims=True)
        half = to_light + to_camera
        half /= np.linalg.norm(half, axis=-1, keepdims=True)
        cos = np.clip(np.einsum("...i,...i->...", normals, to_light)[..., None], 0.0, 1.0)
        cos_h = np.clip(np.einsum("...i,...i->...", normals, half)[..., None], 0.0, 1.0)
    falloff = light.intensity * (light.reference_mm / distance) ** 2
    return falloff, cos, cos_h


def shade(points: np.ndarray, normals: np.ndarray, albedo: np.ndarray, material: Material,
          light: Light, exposure: float, light_position: np.ndarray | None = None) -> np.ndarray:
    """Radiance [..., 3] (unclipped) of surface points [..., 3] mm with unit normals [..., 3]
    and albedo [..., 3], lit from `light_position` [3] mm in camera space (None = the camera
    centre)."""
    falloff, cos, cos_h = _light_geometry(points, normals, light, light_position)
    highlight = material.specular * cos_h ** material.shininess
    lit = albedo * (light.ambient + material.diffuse * cos) + highlight
    return exposure * falloff * lit


def diffuse_shading(points: np.ndarray, normals: np.ndarray, material: Material, light: Light,
                    exposure: float, light_position: np.ndarray | None = None) -> np.ndarray:
    """[...] the factor multiplying the albedo in `shade`'s radiance (the true shading)."""
    falloff, cos, _ = _light_geometry(points, normals, light, light_position)
    return (exposure * falloff * (light.ambient + material.diffuse * cos))[..., 0]
