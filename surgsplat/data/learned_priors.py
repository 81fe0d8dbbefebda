"""Tool masks and relative depth from ONNX models that a user brings, each kind under the input
and output contract of `surgsplat.data.onnx_models` plus what its output map means:

Tool segmenter (`surgsplat import --tool-segmenter MODEL.onnx`): per pixel, the tool's logit
(`output="logits"`; the probability is its sigmoid; a two-class softmax model fits by giving
logit(tool) - logit(background)) or the tool's probability in [0, 1] (`output="probability"`).
The map is resized back to the frame as it comes (a logit map as logits), and a pixel is tool
where the probability is >= `threshold` and it lies inside the field of view.

Depth network (`surgsplat import --depth MODEL.onnx`): per pixel, relative inverse depth
(`output="inverse_depth"`: larger = nearer, known up to one scale, as Depth Anything's relative
models and MiDaS give) or depth known up to one scale (`output="depth"`). Scale handling, the
same route as the shading prior's: depth = 1 / output (or the output), unknown (0) where the
output is not positive and finite; each frame is then scaled so that its median depth over the
field of view's non-tool pixels is `median_depth` (scene units), which fixes the unknown scale
of every frame on its own (a network's scale may drift between frames). Train on it with the
scale-invariant depth loss (`--set components.depth.form=scale_invariant`), which is blind to
one scale per frame. Affine-invariant models (Depth Anything's relative models, MiDaS) give
inverse depth up to a scale *and a shift*; the shift is taken as 0 here, so the depth ratios
within a frame are as good as the model's shift is small.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from scipy.special import logit

from surgsplat.data.layout import MAX_DEPTH_MM
from surgsplat.data.onnx_models import ModelInput, OnnxModel
from surgsplat.errors import DataError, SurgsplatError

TOOL_OUTPUTS = ("logits", "probability")
"""What a tool segmenter's output map holds."""
DEPTH_OUTPUTS = ("inverse_depth", "depth")
"""What a depth network's output map holds."""


@dataclass
class ModelConfig:
    """How an ONNX model of one kind is fed and read: what the two kinds share. Each kind adds
    the field `output`, what its output map holds (one of `outputs`)."""

    kind: ClassVar[str]
    """The kind of model, for messages."""
    outputs: ClassVar[tuple[str, ...]]
    """What the kind's output map may hold."""
    input: ModelInput = field(default_factory=ModelInput)
    """How frames are fitted to the model's input."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        self.input.validate()
        if self.output not in self.outputs:
            raise SurgsplatError(f"a {self.kind}'s output is one of {', '.join(self.outputs)}, "
                                 f"got {self.output!r}")

    def describe(self) -> dict:
        """JSON-ready settings for scene.json."""
        return asdict(self)


@dataclass
class ToolSegmenterConfig(ModelConfig):
    """How an ONNX tool segmenter is fed and read."""

    kind: ClassVar[str] = "tool segmenter"
    outputs: ClassVar[tuple[str, ...]] = TOOL_OUTPUTS
    output: Literal["logits", "probability"] = "logits"
    """What the output map holds: the tool's logit, or its probability in [0, 1]."""
    threshold: float = 0.5
    """Tool probability at and above which a pixel is tool."""

    def validate(self) -> None:
        super().validate()
        if not 0 < self.threshold < 1:
            raise SurgsplatError(f"the tool probability threshold must be in (0, 1), got "
                                 f"{self.threshold}")


@dataclass
class DepthNetworkConfig(ModelConfig):
    """How an ONNX depth network is fed and read."""

    kind: ClassVar[str] = "depth network"
    outputs: ClassVar[tuple[str, ...]] = DEPTH_OUTPUTS
    output: Literal["inverse_depth", "depth"] = "inverse_depth"
    """What the output map holds: relative inverse depth (larger = nearer), or relative depth."""
    median_depth: float = 50.0
    """Median depth of every frame, in the scene's units (the unknown absolute scale)."""

    def validate(self) -> None:
        super().validate()
        if not 0 < self.median_depth <= MAX_DEPTH_MM:
            raise SurgsplatError(f"the depth network's median depth must be positive and at "
                                 f"most {MAX_DEPTH_MM:g}, got {self.median_depth}")


def model_tool_masks(model: OnnxModel, frames: Iterable[np.ndarray], fov: np.ndarray | None,
                     config: ToolSegmenterConfig,
                     advance: Callable[[int], None] | None = None) -> Iterator[np.ndarray]:
    """bool [H, W] tool mask of each uint8 RGB frame [H, W, 3], in order: probability >=
    threshold inside the field of view `fov` (bool [H, W], None = whole frame). Logits are
    compared with logit(threshold), which is the same test without a sigmoid per pixel.
    DataError naming the model for an output outside its range (`check_tool_output`)."""
    cut = logit(config.threshold) if config.output == "logits" else config.threshold
    for index, output in enumerate(model.run(frames, advance)):
        check_tool_output(output, model.path, index, config.output)
        mask = output >= cut
        yield mask if fov is None else mask & fov


PROBABILITY_TOLERANCE = 1e-3
"""How far a probability output may stray outside [0, 1] (float rounding of a sigmoid)."""


def check_tool_output(output: np.ndarray, model: Path, index: int, kind: str) -> None:
    """DataError naming the tool segmenter `model` unless its output map [H, W] for frame
    `index` holds no NaN and, for kind "probability", only values in [0, 1]."""
    if np.isnan(output).any():
        raise DataError(model, f"gave NaN for {np.isnan(output).mean():.0%} of the pixels of "
                               f"frame {index}: expected the tool's {kind} at every pixel")
    if kind == "probability" and not (-PROBABILITY_TOLERANCE <= output.min()
                                      and output.max() <= 1 + PROBABILITY_TOLERANCE):
        raise DataError(model, f"gave values from {output.min():g} to {output.max():g} for "
                               f"frame {index}, outside the [0, 1] of a probability: does it "
                               "give logits? (--tool-segmenter-output logits)")


def network_depth(output: np.ndarray, exclude: np.ndarray | None,
                  config: DepthNetworkConfig) -> np.ndarray:
    """Relative z-depth float32 [H, W] from a depth network's output map [H, W], median
    `median_depth` over the pixels with a depth that `exclude` (bool [H, W]: outside the view,
    tools) leaves; 0 where unknown or excluded. All zeros when no such pixel is left."""
    known = np.isfinite(output) & (output > 0)
    depth = np.zeros(output.shape, np.float32)
    depth[known] = 1.0 / output[known] if config.output == "inverse_depth" else output[known]
    keep = known if exclude is None else known & ~exclude
    if not keep.any():
        return np.zeros_like(depth)
    depth *= np.float32(config.median_depth / np.median(depth[keep]))
    depth[~keep] = 0.0
    return depth
