"""The phantom scene: tissue, tool, light and camera together, rendered one frame at a time.

Tissue and tool are defined in the world frame (the first frame's camera frame, see
`camera_path`); each frame is ray-cast from that frame's endoscope pose, and everything per
pixel (depth, normals, shading with the light at the camera) is in that frame's camera space.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from surgsplat.data.phantom.camera_path import camera_path
from surgsplat.data.phantom.motion import motion_program
from surgsplat.data.phantom.raycast import intersect_surface, pixel_rays
from surgsplat.data.phantom.shading import (JAW_RGB, LIGHTINGS, METAL, SHAFT_RGB, WET_TISSUE,
                                            Exposure, Light, diffuse_shading, shade)
from surgsplat.data.phantom.surface import BASE_DEPTH_MM, TissueSurface
from surgsplat.data.phantom.texture import CUT_RGB, TissueTexture
from surgsplat.data.phantom.tool import JAW, ToolGeometry, ToolPose, intersect_tool

TEXELS_PER_PIXEL = 1.4
"""Texture resolution relative to the pixel footprint on tissue at the base depth."""
TROCAR_DISTANCE_MM = 85.0
"""Distance of the tool's entry point from the optical axis."""
TROCAR_DEPTH_MM = -15.0
"""Depth of the tool's entry point (behind the camera centre)."""
RETRACT_MM = 75.0
"""How far the tool is pulled back along its shaft when fully withdrawn (then out of view)."""
HOVER_MM = 1.0
"""The jaws' middle sits this far in front of the tissue point the tool works at."""
CUT_ALBEDO_WEIGHT = 0.8
"""How far the albedo inside a fully opened cut moves towards the cut tissue colour."""


@dataclass(frozen=True)
class PhantomFrame:
    """Everything rendered for one frame."""

    image: np.ndarray  # [H, W, 3] float32 in [0, 1]: the camera frame
    tissue_image: np.ndarray  # [H, W, 3] float32 in [0, 1]: the same frame without the tool
    depth: np.ndarray  # [H, W] float32 mm: the nearest surface (the tool where it is)
    tissue_depth: np.ndarray  # [H, W] float32 mm: the tissue, also behind the tool
    albedo: np.ndarray  # [H, W, 3] float32 in [0, 1]: tissue albedo
    normals: np.ndarray  # [H, W, 3] float32: unit camera-space tissue normals, facing the camera
    tool_mask: np.ndarray  # [H, W] bool: True where the tool is nearer than the tissue
    exposure: float  # the frame's exposure factor
    world_to_camera: np.ndarray  # [4, 4] float64: the frame's endoscope pose
    shading: np.ndarray  # [H, W] float32: the tissue's true shading (tissue_image = albedo *
    # shading + specular, before the clip to [0, 1])
    light_intensity: float  # the light's intensity at the reference distance this frame


class PhantomScene:
    """A deterministic phantom of `num_frames` frames at `width` x `height` pixels."""

    def __init__(self, width: int, height: int, focal: float, num_frames: int, motion: str,
                 seed: int, camera: str = "static", lighting: str = "standard"):
        self.width, self.height, self.focal = width, height, float(focal)
        self.num_frames = num_frames
        self.motion = motion_program(motion)
        self.camera_path = camera_path(camera)
        self.surface = TissueSurface(seed, self.motion)
        self.texture = TissueTexture(seed, BASE_DEPTH_MM / self.focal / TEXELS_PER_PIXEL)
        self.geometry = ToolGeometry()
        self.lighting = LIGHTINGS[lighting]
        self.light = Light(intensity=self.lighting.intensity)
        rng = np.random.default_rng([seed, 3])
        self.exposure = Exposure(amplitude=self.lighting.exposure_amplitude,
                                 phase=float(rng.uniform(0.0, 2 * np.pi)))
        trocar_angle = rng.uniform(np.radians(-160.0), np.radians(-20.0))  # upper half of view
        self.trocar = np.array([TROCAR_DISTANCE_MM * np.cos(trocar_angle),
                                TROCAR_DISTANCE_MM * np.sin(trocar_angle), TROCAR_DEPTH_MM])
        self.roll = float(rng.uniform(np.radians(-40.0), np.radians(40.0)))
        self.xn, self.yn = pixel_rays(width, height, focal)  # [H, W] each
        self.light_phase, self.light_angle = np.random.default_rng([seed, 5]).uniform(
            0.0, 2 * np.pi, size=2)  # the lighting program's intensity phase and start angle

    def time(self, index: int) -> float:
        """Time of frame `index`: index / number of frames."""
        return index / self.num_frames

    def world_to_camera(self, index: int) -> np.ndarray:
        """[4, 4] float64 pose of frame `index`'s camera."""
        return self.camera_path.world_to_camera(self.time(index))

    def tool_pose(self, t: float) -> ToolPose:
        """The tool at time t in the world: its shaft points from the trocar at the tissue
        point it works at, slid back along itself by the motion's insertion."""
        anchor = self.surface.anchor(t)
        back = self.trocar - anchor
        back /= np.linalg.norm(back)
        reach = 0.5 * self.geometry.jaw_length + RETRACT_MM * self.motion.insertion(t)
        joint = anchor + reach * back - np.array([0.0, 0.0, HOVER_MM])
        forward = -back
        facing = np.array([0.0, 0.0, 1.0]) - forward[2] * forward  # view axis, across the shaft
        facing /= np.linalg.norm(facing)
        side = np.cross(forward, facing)
        hinge = np.cos(self.roll) * facing + np.sin(self.roll) * side
        return ToolPose(joint=joint, forward=forward, hinge=hinge,
                        jaw_deg=self.motion.jaw_deg(t))

    def camera_tool_pose(self, index: int) -> ToolPose:
        """The tool of frame `index` in that frame's camera space."""
        pose = self.tool_pose(self.time(index))
        world_to_camera = self.world_to_camera(index)
        rotation, translation = world_to_camera[:3, :3], world_to_camera[:3, 3]
        return ToolPose(joint=rotation @ pose.joint + translation, forward=rotation @ pose.forward,
                        hinge=rotation @ pose.hinge, jaw_deg=pose.jaw_deg)

    def world_rays(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """(camera centre [3] mm, ray directions [H, W, 3]) of frame `index` in the world; a
        direction's camera-space z component is 1."""
        camera_to_world = self.camera_path.camera_to_world(self.time(index))
        rotation = camera_to_world[:3, :3]
        directions = (self.xn[..., None] * rotation[:, 0] + self.yn[..., None] * rotation[:, 1]
                      + rotation[:, 2])
        return camera_to_world[:3, 3], directions

    def render(self, index: int) -> PhantomFrame:
        """Ray-cast frame `index`: tissue, tool, nearest hit, shading and exposure."""
        t = self.time(index)
        exposure = self.exposure.factor(t)
        light, light_position = self.light_at(t)
        world_to_camera = self.world_to_camera(index)
        centre, directions = self.world_rays(index)
        tissue_depth = intersect_surface(self.surface, t, centre, directions)  # [H, W]
        x = centre[0] + tissue_depth * directions[..., 0]  # world x, y of the hits [H, W]
        y = centre[1] + tissue_depth * directions[..., 1]
        points = np.stack([tissue_depth * self.xn, tissue_depth * self.yn, tissue_depth],
                          axis=-1)  # [H, W, 3] camera space
        normals = self.surface.normals(x, y, t) @ world_to_camera[:3, :3].T  # camera space
        albedo = self.texture.sample(*self.surface.material(x, y, t)).astype(np.float64)
        cut = CUT_ALBEDO_WEIGHT * self.surface.opening(x, y, t)[..., None]
        albedo = albedo + (CUT_RGB - albedo) * cut
        tissue_image = shade(points, normals, albedo, WET_TISSUE, light, exposure, light_position)
        shading = diffuse_shading(points, normals, WET_TISSUE, light, exposure, light_position)

        hit = intersect_tool(self.geometry, self.camera_tool_pose(index), self.xn, self.yn)
        tool_mask = hit.depth < tissue_depth
        image = tissue_image.copy()
        depth = tissue_depth.copy()
        if tool_mask.any():
            tool_depth = hit.depth[tool_mask]  # [M]
            tool_points = tool_depth[:, None] * np.stack(
                [self.xn[tool_mask], self.yn[tool_mask], np.ones_like(tool_depth)], axis=-1)
            tool_albedo = np.where((hit.part[tool_mask] == JAW)[:, None], JAW_RGB, SHAFT_RGB)
            image[tool_mask] = shade(tool_points, hit.normal[tool_mask], tool_albedo, METAL,
                                     light, exposure, light_position)
            depth[tool_mask] = tool_depth
        return PhantomFrame(
            image=np.clip(image, 0.0, 1.0).astype(np.float32),
            tissue_image=np.clip(tissue_image, 0.0, 1.0).astype(np.float32),
            depth=depth.astype(np.float32), tissue_depth=tissue_depth.astype(np.float32),
            albedo=albedo.astype(np.float32), normals=normals.astype(np.float32),
            tool_mask=tool_mask, exposure=exposure, world_to_camera=world_to_camera,
            shading=shading.astype(np.float32), light_intensity=light.intensity)

    def light_at(self, t: float) -> tuple[Light, np.ndarray | None]:
        """The light at time t and its camera-space position [3] mm (None = camera centre)."""
        factor = self.lighting.intensity_factor(t, self.light_phase)
        light = self.light if factor == 1.0 else dataclasses.replace(
            self.light, intensity=self.light.intensity * factor)
        return light, self.lighting.light_position(t, self.light_angle)
