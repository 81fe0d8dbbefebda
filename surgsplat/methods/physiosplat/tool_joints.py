"""The tool field's jaws: a grasper as a shaft and two jaws turning about one hinge.

The tool field's articulated motion (`ToolFieldConfig.motion = "articulated"`) moves the tool
Gaussians of each part with its own transform. In the canonical tool (the tool of the field's
reference frame) the hinge is a point, a unit axis and a unit forward direction normal to it
(from the shaft into the jaws); in the hinge's frame (x forward, z the axis, y = z x x):

- a tool Gaussian whose canonical centre lies behind the hinge (x <= 0) is the shaft;
- the others are the jaws, split by their angle phi = atan2(y, x) about the axis at the middle
  of the two jaws' canonical angles: jaw a (the smaller angle) below, jaw b above.

The parts follow from the canonical centres, so Gaussians added by densification join the part
where they are. At frame t each jaw turns about the hinge by its angle at t minus its canonical
angle; then the whole tool takes the frame's rigid (shaft) pose.

The hinge and the first angles come from `model.articulation`'s estimate over the training
frames' observed tool points (`initial_joints`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from surgsplat.data.phantom.kinematics import hinge_frame
from surgsplat.model.articulation import (JAW_A, JAW_B, SHAFT, ArticulationOptions, Observation,
                                          estimate_articulation)
from surgsplat.render.rotation import quaternion_multiply


@dataclass(frozen=True)
class Hinge:
    """The hinge of the canonical tool (scene units, radians)."""

    point: Tensor
    """[3] a point on the hinge axis."""
    axis: Tensor
    """[3] unit hinge axis."""
    forward: Tensor
    """[3] unit direction from the shaft into the jaws, normal to `axis`."""
    canonical_angles: Tensor
    """[2] jaw a's and jaw b's angle from `forward` about `axis` in the canonical tool
    (right-hand rule), a <= b."""

    def local(self, points: Tensor) -> Tensor:
        """[N, 2] (x forward, y = axis x forward) of points [N, 3] relative to the hinge."""
        offset = points - self.point
        return torch.stack([offset @ self.forward,
                            offset @ torch.linalg.cross(self.axis, self.forward)], dim=1)


def jaw_parts(means: Tensor, hinge: Hinge) -> Tensor:
    """[N] long part (SHAFT, JAW_A, JAW_B) of the canonical centres `means` [N, 3]."""
    local = hinge.local(means.detach())
    angle = torch.atan2(local[:, 1], local[:, 0])  # [N]
    middle = hinge.canonical_angles.mean()
    parts = torch.where(angle < middle, JAW_A, JAW_B)
    return torch.where(local[:, 0] <= 0, SHAFT, parts)


def turn_jaws(means: Tensor, quats: Tensor, parts: Tensor, turns: Tensor,
              hinge: Hinge) -> tuple[Tensor, Tensor]:
    """Canonical means [N, 3] and unit quaternions [N, 4] of the tool Gaussians with each jaw
    turned about the hinge by its turn (turns [2], radians: jaw a, jaw b); the shaft's rows
    unchanged. Differentiable in means, quats and turns, also at a turn of 0."""
    zero = turns.new_zeros(())
    angle = torch.where(parts == JAW_A, turns[0], torch.where(parts == JAW_B, turns[1], zero))
    axis = hinge.axis
    offset = means - hinge.point  # [N, 3]
    cos, sin = torch.cos(angle)[:, None], torch.sin(angle)[:, None]  # [N, 1]
    along = (offset @ axis)[:, None] * axis  # [N, 3] the offset's part along the axis
    turned = along + (offset - along) * cos + torch.linalg.cross(axis.expand_as(offset),
                                                                 offset) * sin
    half = 0.5 * angle[:, None]
    turn_quats = torch.cat([torch.cos(half), torch.sin(half) * axis], dim=1)  # [N, 4] wxyz
    return turned + hinge.point, quaternion_multiply(turn_quats, quats)


@dataclass(frozen=True)
class InitialJoints:
    """The articulated field's start: its hinge, each frame's jaw angles and shaft pose."""

    hinge: Hinge
    angles: dict[int, Tensor]
    """frame index -> [2] jaw angles (radians)."""
    shaft_corrections: dict[int, np.ndarray]
    """frame index -> [4, 4] float64 canonical -> canonical motion that the frame's rigid pose
    takes first (the shaft's motion the rigid registration missed)."""


def initial_joints(canonical: Tensor, observations: list[Observation], reference: int,
                   options: ArticulationOptions = ArticulationOptions()) -> InitialJoints:
    """The joints of the canonical tool `canonical` [K, 3] (the `reference` frame's tool),
    estimated from the frames' `observations` in the canonical frame; ValueError when the
    estimate cannot be made (`estimate_articulation`)."""
    estimate = estimate_articulation(canonical.double().numpy(), observations, options)
    # the reference frame's hinge frame in canonical coordinates is the canonical hinge
    start = hinge_frame(estimate.forward, estimate.axis, estimate.hinge_point)
    at_reference = estimate.shaft_motion_at(reference) @ start  # [4, 4]
    reference_angles = np.radians(estimate.jaw_angles_at(reference))
    order = np.argsort(reference_angles)
    hinge = Hinge(point=torch.from_numpy(at_reference[:3, 3]).float(),
                  axis=torch.from_numpy(at_reference[:3, 2]).float(),
                  forward=torch.from_numpy(at_reference[:3, 0]).float(),
                  canonical_angles=torch.from_numpy(reference_angles[order]).float())
    back = np.linalg.inv(estimate.shaft_motion_at(reference))
    angles, corrections = {}, {}
    for observation in observations:
        index = observation.index
        angles[index] = torch.from_numpy(np.radians(estimate.jaw_angles_at(index))[order]).float()
        corrections[index] = estimate.shaft_motion_at(index) @ back
    return InitialJoints(hinge, angles, corrections)

