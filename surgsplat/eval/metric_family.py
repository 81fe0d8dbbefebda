"""The contract of a metric family: one kind of metrics that `evaluate_run` composes.

A family is built once per evaluation from the run and the options. It sees the test frames
one at a time (`score`: the values of one frame, averaged over the frames that have them; no
value means the frame is not covered by the family), then gives what it pools over all of
them (`pooled`), the metrics it could not compute with the reason (`unavailable`), and what
each of its metrics computes (`conventions`). A family never writes a file.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal
from functools import cached_property
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from surgsplat.data.layout import frame_stem
from surgsplat.data.ply import read_ply_mesh
from surgsplat.data.scene import Frame
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.model.state import GaussianState
from surgsplat.render.render import RenderOutput
from surgsplat.train.run import TrainedRun


@dataclass
class EvalOptions:
    """What `evaluate_run` measures."""

    alexnet_weights: Path | None = None
    """torchvision AlexNet checkpoint for LPIPS (default: env var / torch hub cache)."""
    geometry: bool = True
    """Measure geometry against gt/ meshes when the scene has them."""
    frames: Literal["test", "train"] = "test"
    """The frames scored: the held-out test frames, or the training frames (a measure of the
    fit, not of generalisation: for a scene with no held-out frame, e.g. one stereo pair)."""

    def frames_of(self, run: TrainedRun) -> list[Frame]:
        """The frames of `run`'s scene that these options score."""
        return run.scene.test_frames if self.frames == "test" else run.scene.train_frames


def gt_mesh_path(scene_root: Path, index: int) -> Path:
    """The phantom's ground-truth tissue mesh of frame `index` (world frame, scene unit)."""
    return scene_root / "gt" / "meshes" / f"{frame_stem(index)}.ply"


@dataclass
class FrameView:
    """One test frame as every metric family sees it: the frame, the run's ordinary render of
    it (every component, the tool included) and the scene's ground truth there."""

    run: TrainedRun
    frame: Frame
    render: RenderOutput
    background: Tensor  # [3] RGB in [0, 1]

    @property
    def when(self) -> FrameTime:
        return FrameTime(self.frame.index, self.frame.time)

    @property
    def rgb(self) -> Tensor:
        """[H, W, 3] the rendered colour clamped to [0, 1]."""
        return self.render.rgb.clamp(0, 1)

    @cached_property
    def seen(self) -> Frame:
        """The frame seen by the camera the run renders it with (`SplatModel.camera_at`: its
        own, or the pose a component refined), for every family that places the render or the
        Gaussians in the world."""
        with torch.no_grad():
            return self.frame.seen_by(self.run.model.camera_at(self.frame.camera, self.when))

    @cached_property
    def tissue_render(self) -> RenderOutput:
        """The render of the tissue alone (the tool's Gaussians left out) for a model that
        separates the tool, else the ordinary render; computed once for every family that
        needs it."""
        if not self.run.model.separates_tool:
            return self.render
        frame = self.frame
        with torch.no_grad():
            return render_frame(self.run.model, frame.camera,
                                FrameTime(frame.index, frame.time, tissue_only=True),
                                self.background)

    @cached_property
    def state(self) -> GaussianState:
        """The Gaussians at the frame's time (every component applied, detached); computed once
        for every family that needs them."""
        with torch.no_grad():
            return self.run.model.state_at(self.when)

    @cached_property
    def gt_mesh(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(vertices [V, 3], faces [F, 3]) of the frame's gt tissue mesh, None without one;
        read once for every family that needs it."""
        path = gt_mesh_path(self.run.scene.root, self.frame.index)
        return read_ply_mesh(path) if path.is_file() else None


class MetricFamily:
    """One family of metrics; see the module docstring. Hooks default to contributing nothing."""

    name = ""
    """The family's key in metrics.json's frames_covered."""

    def __init__(self, run: TrainedRun, options: EvalOptions):
        """Built once per evaluation of `run` with `options`."""

    def score(self, view: FrameView) -> dict[str, float]:
        """This family's values at one test frame (means over the covered frames)."""
        return {}

    def pooled(self) -> dict:
        """Metrics over all the test frames seen, once every frame is scored."""
        return {}

    def pooled_frames(self) -> int:
        """Test frames the pooled metrics cover, for families that pool instead of scoring."""
        return 0

    def unavailable(self) -> dict:
        """Metrics this family could not compute at all: None, with a note saying why."""
        return {}

    def conventions(self) -> dict[str, str]:
        """What each of its metrics computes, metric (or metric group) -> text."""
        return {}
