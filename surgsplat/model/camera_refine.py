"""Per-frame camera pose refinement, learnt from the render losses.

Imported poses (structure from motion, a robot's kinematics) are a little off, and the
photometric loss sees it. Each frame i has a correction xi_i = (omega_i, tau_i) [6], a twist in
the camera's frame: omega_i its rotation (radians) and tau_i its translation (in scene extents,
so that the learning rate and the prior are unit-free). Frame i is rendered with

    world_to_camera'_i = exp(hat(omega_i, extent tau_i)) @ world_to_camera_i,

the se(3) exponential (`torch.linalg.matrix_exp` of the 4x4 twist matrix: the rotation by the
rotation vector omega_i, and a translation that is extent tau_i to first order). Every correction
starts at 0, the imported pose. The native projection differentiates the render in the pose, so
training with this component stays on the native kernels.

Test frames are never trained on. A test frame's correction starts from the linear
interpolation in time between the corrections of the nearest training frames before and after
it (held beyond the first and the last); evaluation then fits it to the frame's own tissue
pixels with the model frozen (`fit_held_out`, `test_time_steps` Adam steps on their L1; 0 keeps
the interpolation), as evaluations of pose-free NeRF and 3DGS do: the training frames'
corrections absorb their pose errors, and the interpolation cannot know a test frame's own. Such
a frame's score then depends on its pixels through its 6 pose numbers as well. The metrics say
which (`frame_diagnostics`: "test_frame_poses" in the conventions of metrics.json).

The loss term "pose_prior" (weight in the method's `losses`; 0 = no prior) is
|omega_i|^2 + |tau_i|^2 of the step's frame: a pull towards the imported pose.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor, nn

from surgsplat.data.scene import Camera
from surgsplat.errors import SurgsplatError
from surgsplat.model.capabilities import CameraCorrection, HeldOutPoses
from surgsplat.model.component import (Component, ComponentConfig, Diagnostics, FrameTime,
                                       ParamGroup, RenderContext, SceneInfo, SetupContext)
from surgsplat.model.phases import Phase
from surgsplat.model.timeline import interpolate_in_time

PRIOR = "pose_prior"
"""The loss term pulling the step's frame's correction towards the imported pose."""

INTERPOLATED_POSES = ("test frames are not trained on: a test frame's pose correction is "
                      "interpolated linearly in time between the corrections of the nearest "
                      "training frames before and after it (held beyond the first and last), "
                      "with no test-time optimisation")
FITTED_POSES = ("test frames are not trained on: a test frame's pose correction starts from "
                "the linear interpolation in time between the corrections of the nearest "
                "training frames and is then fitted to the frame's tissue pixels (L1, {steps} "
                "Adam steps) with the model frozen (test-time pose optimisation)")
"""What metrics.json states of the poses of the frames it scores, without and with test-time
optimisation."""


@dataclass
class CameraRefineConfig(ComponentConfig, kind="camera_refine"):
    """Per-frame pose corrections of a run."""

    lr: float = field(default=1e-4, metadata={"range": "[0, inf)"})
    """Adam learning rate of the corrections at iteration 0: radians for the rotation vectors,
    scene extents for the translations. Adam moves each correction by about this much per step
    while the scene is still a blur, so a high rate lets the poses wander with it; a low one
    still corrects poses from structure from motion (measurements:
    docs/methods/shared-components.md)."""
    lr_final: float = field(default=1e-5, metadata={"range": "(0, inf)"})
    """Learning rate at the end of the run (exponential decay from `lr`)."""
    test_time_steps: int = field(default=100, metadata={"range": "[0, inf)"})
    """Adam steps fitting each test frame's correction at evaluation (0 = interpolate only)."""
    test_time_lr: float = field(default=1e-4, metadata={"range": "(0, inf)"})
    """Adam learning rate of that fit, decaying to a tenth over its steps."""
    num_frames: int = field(default=0, metadata={"range": "[0, inf)"})
    """Frames of the clip (set when resolved for a scene)."""

    def resolve(self, scene: SceneInfo) -> "CameraRefineConfig":
        """This config for the scene: its frame count."""
        return dataclasses.replace(self, num_frames=scene.num_frames)

    def build(self) -> "CameraRefine":
        return CameraRefine(self)


def se3_generators() -> Tensor:
    """[6, 4, 4] the basis of se(3): rotations about the x, y, z axes, translations along them."""
    generators = torch.zeros(6, 4, 4)
    for axis, (row, col) in enumerate(((2, 1), (0, 2), (1, 0))):
        generators[axis, row, col], generators[axis, col, row] = 1.0, -1.0
        generators[3 + axis, axis, 3] = 1.0
    return generators


def correction_transform(correction: Tensor, extent: float) -> Tensor:
    """[4, 4] rigid transform exp(hat(correction)) of a twist correction [6] (rotation in
    radians, translation in scene extents of `extent` scene units); the identity, exactly, at
    the zero correction. Differentiable in the correction."""
    generators = se3_generators().to(correction.dtype)
    generators[3:] *= extent
    return torch.linalg.matrix_exp(torch.tensordot(correction, generators, dims=1))


class CameraRefine(Component):
    """A learnt correction [6] of every frame's pose; see the module docstring."""

    phase = Phase.CAMERA

    def __init__(self, config: CameraRefineConfig):
        super().__init__()
        if config.num_frames < 1:
            raise SurgsplatError("camera_refine: the config must be resolved for a scene "
                                 "(num_frames)")
        self.config = config
        self.corrections = nn.Parameter(torch.zeros(config.num_frames, 6))  # [F, 6]
        self.register_buffer("trained", torch.zeros(config.num_frames, dtype=torch.bool))  # [F]
        self.register_buffer("extent", torch.ones(()))  # scene units per translation unit
        self.held_out: dict[int, Tensor] = {}  # [6] fitted corrections of held-out frames

    @property
    def provides(self) -> tuple[type, ...]:
        """A corrected camera; and the fitting of held-out frames' poses unless its steps are
        0."""
        return ((CameraCorrection, HeldOutPoses) if self.config.test_time_steps > 0
                else (CameraCorrection,))

    def setup(self, context: SetupContext) -> None:
        self.trained[list(context.scene.train_indices)] = True
        self.extent.fill_(context.scene_extent)

    def param_groups(self) -> list[ParamGroup]:
        return [ParamGroup("camera_refine", [self.corrections], self.config.lr,
                           self.config.lr_final)]

    def correction(self, when: FrameTime) -> Tensor:
        """[6] the correction of frame `when.index`: its own if it is a training frame, the
        fitted one of a held-out frame `fit_held_out` saw, else interpolated in time between the
        training frames' (0 when none is known)."""
        if bool(self.trained[when.index]):
            return self.corrections[when.index]
        if when.index in self.held_out:
            return self.held_out[when.index]
        known = self.trained.nonzero()[:, 0]
        if known.numel() == 0:
            return torch.zeros_like(self.corrections[0])
        times = known.to(torch.float64) / self.config.num_frames
        return interpolate_in_time(self.corrections[known], times, when.time)

    def camera(self, camera: Camera, when: FrameTime) -> Camera:
        """`camera` with its pose corrected by the frame's correction (in the camera frame)."""
        transform = correction_transform(self.correction(when), float(self.extent))
        pose = transform.to(camera.world_to_camera) @ camera.world_to_camera
        return dataclasses.replace(camera, world_to_camera=pose)

    def fit_held_out(self, index: int, time: float, loss: Callable[[], Tensor]) -> None:
        """Fit held-out frame `index`'s correction (starting from the interpolation) by
        `test_time_steps` Adam steps on `loss()`, a render of the frame with it scored against
        its image; only the correction moves. SurgsplatError for a training frame."""
        if bool(self.trained[index]):
            raise SurgsplatError(f"camera_refine: frame {index} is a training frame; only "
                                 "held-out frames are fitted at test time")
        self.held_out.pop(index, None)
        fitted = self.correction(FrameTime(index, time)).detach().clone().requires_grad_(True)
        self.held_out[index] = fitted
        steps, lr = self.config.test_time_steps, self.config.test_time_lr
        optimizer = torch.optim.Adam([fitted], lr=lr)
        for step in range(steps):
            for group in optimizer.param_groups:
                group["lr"] = lr * 0.1 ** (step / steps)
            with torch.enable_grad():
                (fitted.grad,) = torch.autograd.grad(loss(), [fitted], allow_unused=True)
            if fitted.grad is None:  # nothing of the render depends on the pose: nothing to fit
                break
            optimizer.step()
        self.held_out[index] = fitted.detach()

    def loss_names(self) -> tuple[str, ...]:
        return (PRIOR,)

    def losses(self, context: RenderContext, active: frozenset[str]) -> dict[str, Tensor]:
        return {PRIOR: self.correction(context.when).square().sum()}

    def frame_diagnostics(self, state, gaussians, when: FrameTime) -> Diagnostics:
        """The size of the correction the frame `when` is rendered with, and the poses'
        convention."""
        correction = self.correction(when)
        angle = math.degrees(float(correction[:3].norm()))
        shift = float(correction_transform(correction, float(self.extent))[:3, 3].norm())
        return Diagnostics(
            averaged={"pose_correction_deg": angle, "pose_correction_translation": shift},
            conventions={
                "test_frame_poses": FITTED_POSES.format(steps=self.config.test_time_steps)
                if when.index in self.held_out else INTERPOLATED_POSES,
                "pose_correction_deg": "angle of the rotation of the pose correction each "
                                       "test frame is rendered with, degrees, mean over test "
                                       "frames (see test_frame_poses)",
                "pose_correction_translation": "length of the translation of that correction, "
                                               "scene units (mm for the phantom), mean over "
                                               "test frames"})
