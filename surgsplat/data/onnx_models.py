"""Models that a user brings as ONNX files, run on the CPU by ONNX Runtime (the optional extra
`onnx`: pip install 'surgsplat[onnx]'). surgsplat ships no weights and never downloads any.

The contract every model must meet (`surgsplat.data.learned_priors` reads the outputs of the
two kinds, tool segmenters and depth networks):

- Input: exactly one, float32, layout NCHW [N, 3, h, w]. Each uint8 RGB frame of the scene is
  resized to w x h with OpenCV (area when shrinking, bilinear when enlarging; stretched when the
  aspect ratio differs), kept in RGB order, and mapped to (pixel / 255 - mean) / std per channel.
  The defaults are ImageNet's mean (0.485, 0.456, 0.406) and std (0.229, 0.224, 0.225), which
  Depth Anything, MiDaS and segmenters on ImageNet backbones use; a model taking 0..1 wants
  mean 0 and std 1, one taking 0..255 mean 0 and std 1/255.
- h x w: the model's own when its input declares them; else the (width, height) asked for
  (`ModelInput.size`), else the short side asked for with the frame's aspect ratio, else the
  frame's own size. A size chosen here has both sides rounded to a multiple of
  `ModelInput.multiple`; a size asked for must agree with every side the model fixes.
- N: the model's when its batch dimension is fixed (a last, short batch is filled up with
  copies of its last frame), else up to `ModelInput.batch` frames per run.
- Output: exactly one, float, [N, 1, h', w'] or [N, h', w']: one map per frame at the input's
  aspect ratio (to one pixel; h' x w' may be a fraction of h x w, as a stride-4 head gives). It
  is resized back to the frame bilinearly (OpenCV) as raw values, before the kind reads it.

ONNX Runtime runs on `torch.get_num_threads()` threads (`surgsplat --threads N`), and its idle
threads sleep instead of spinning, as the native kernels' do.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from surgsplat.data.layout import MAX_FRAME_PIXELS
from surgsplat.errors import DataError, SurgsplatError

IMAGENET_MEAN = (0.485, 0.456, 0.406)
"""Per-channel (R, G, B) mean of ImageNet, in 0..1."""
IMAGENET_STD = (0.229, 0.224, 0.225)
"""Per-channel (R, G, B) standard deviation of ImageNet, in 0..1."""
FLOAT_OUTPUTS = ("tensor(float)", "tensor(float16)", "tensor(double)")
"""ONNX element types accepted as the output map (converted to float32)."""
INSTALL_HINT = "pip install 'surgsplat[onnx]'"
"""How to get onnxruntime, for the error when it is missing."""

Dims = Sequence[int | str | None]
"""A tensor shape as ONNX Runtime declares it: an int per fixed dimension, a name or None per
free one."""


@dataclass
class ModelInput:
    """How frames are fitted to a model's input (the contract in the module docstring)."""

    size: tuple[int, int] | None = None
    """Input (width, height) of a model whose input size is free; None = by `short_side`."""
    short_side: int | None = None
    """Input short side (pixels), keeping the frame's aspect ratio; None with `size` None = the
    frame's own size."""
    multiple: int = 1
    """Both sides of a size chosen here are rounded to a multiple of this (14 for ViT models
    with 14-pixel patches such as Depth Anything, 32 for a five-level UNet)."""
    mean: tuple[float, float, float] = IMAGENET_MEAN
    """Per-channel (R, G, B) mean subtracted from pixel / 255."""
    std: tuple[float, float, float] = IMAGENET_STD
    """Per-channel (R, G, B) standard deviation dividing pixel / 255 - mean."""
    batch: int = 4
    """Frames per run when the model's batch dimension is free."""

    def validate(self) -> None:
        """Raise SurgsplatError for impossible values."""
        if self.size is not None and self.short_side is not None:
            raise SurgsplatError("give a model either an input size WIDTHxHEIGHT or a short side, "
                                 "not both")
        sides = [*(self.size or ()), *([self.short_side] if self.short_side is not None else [])]
        if any(side < 1 for side in sides) or self.multiple < 1 or self.batch < 1:
            raise SurgsplatError(f"a model's input size, short side, multiple and batch must be "
                                 f"positive, got size {self.size}, short side {self.short_side}, "
                                 f"multiple {self.multiple}, batch {self.batch}")
        if (len(self.mean) != 3 or len(self.std) != 3 or not np.isfinite(self.mean).all()
                or not (0 < np.asarray(self.std)).all() or not np.isfinite(self.std).all()):
            raise SurgsplatError(f"a model's mean and std take 3 finite values (R, G, B), std "
                                 f"positive; got mean {self.mean} and std {self.std}")

    def input_size(self, frame_size: tuple[int, int]) -> tuple[int, int]:
        """(h, w) of the input for frames of `frame_size` (H, W) when the model fixes neither."""
        height, width = frame_size
        if self.size is not None:
            width, height = self.size
        elif self.short_side is not None:
            factor = self.short_side / min(height, width)
            height, width = height * factor, width * factor
        step = self.multiple
        size = max(step, round(height / step) * step), max(step, round(width / step) * step)
        if size[0] * size[1] > MAX_FRAME_PIXELS:
            raise SurgsplatError(f"a model input of {size[1]}x{size[0]} (from the input size, "
                                 f"short side and multiple asked for) exceeds "
                                 f"{MAX_FRAME_PIXELS:,} pixels")
        return size


def _onnxruntime():
    """The onnxruntime module, imported only when a model is given."""
    try:
        import onnxruntime
    except ImportError:
        raise SurgsplatError(f"ONNX models need onnxruntime, which is not installed: "
                             f"{INSTALL_HINT}") from None
    return onnxruntime


def _runtime_errors(ort) -> tuple[type[Exception], ...]:
    """The exceptions ONNX Runtime raises for a model it cannot load or run."""
    state = ort.capi.onnxruntime_pybind11_state
    return (state.Fail, state.InvalidArgument, state.InvalidGraph, state.InvalidProtobuf,
            state.NoSuchFile, state.NoModel, state.NotImplemented, state.RuntimeException)


def _first_line(error: Exception) -> str:
    """ONNX Runtime's message without its status prefix, on one line."""
    return " ".join(str(error).split(" : ")[-1].split())


def _fixed(dim: int | str | None) -> bool:
    return isinstance(dim, int) and dim > 0


def _fits(dim: int | str | None, value: int) -> bool:
    """Whether a declared dimension is free or fixed at `value`."""
    return not _fixed(dim) or dim == value


def _shape_text(dims: Dims) -> str:
    return "[" + ", ".join(str(d) if _fixed(d) else "?" for d in dims) + "]"


class OnnxModel:
    """An ONNX model checked against the contract, ready to run on frames of one size."""

    def __init__(self, path: Path, fit: ModelInput, frame_size: tuple[int, int]):
        """Open `path` for frames of `frame_size` (H, W); DataError (naming the file and what
        was expected) for a file that is not an ONNX model or a model outside the contract."""
        ort = _onnxruntime()
        self.path, self.fit, self.frame_size = Path(path), fit, frame_size
        # (pixel / 255 - mean) / std = pixel * scale + offset, per channel [3, 1, 1]
        self._scale = (1.0 / (255.0 * np.float32(fit.std))).reshape(3, 1, 1)
        self._offset = (-np.float32(fit.mean) / np.float32(fit.std)).reshape(3, 1, 1)
        self._errors = _runtime_errors(ort)
        if not self.path.is_file():
            problem = "is not a file" if self.path.exists() else "does not exist"
            raise DataError(self.path, f"{problem}: expected an ONNX model file")
        options = ort.SessionOptions()
        options.intra_op_num_threads = torch.get_num_threads()
        options.inter_op_num_threads = 1
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
        options.log_severity_level = 3  # errors only
        try:
            self.session = ort.InferenceSession(str(self.path), options,
                                                providers=["CPUExecutionProvider"])
        except self._errors as err:
            raise DataError(self.path, f"is not an ONNX model that ONNX Runtime can load "
                                       f"({_first_line(err)})") from None
        inputs, outputs = self.session.get_inputs(), self.session.get_outputs()
        if len(inputs) != 1 or len(outputs) != 1:
            raise DataError(self.path, f"has {len(inputs)} inputs and {len(outputs)} outputs; "
                                       "expected one input [N, 3, h, w] and one output "
                                       "[N, 1, h, w] or [N, h, w]")
        self.input_name, self.output_name = inputs[0].name, outputs[0].name
        self.input_size = self._check_input(inputs[0].shape, inputs[0].type)  # (h, w)
        batch = inputs[0].shape[0]
        self.fixed_batch = _fixed(batch)
        self.batch = batch if self.fixed_batch else fit.batch
        if outputs[0].type not in FLOAT_OUTPUTS:
            raise DataError(self.path, f"gives {outputs[0].type} output; expected float "
                                       "[N, 1, h, w] or [N, h, w]")
        self._check_output(outputs[0].shape)

    def _check_input(self, dims: Dims, element: str) -> tuple[int, int]:
        """(h, w) of the input, from the declared `dims` and the fit."""
        if element != "tensor(float)" or len(dims) != 4 or not _fits(dims[1], 3):
            raise DataError(self.path, f"takes {element} input {_shape_text(dims)}; expected "
                                       "float32 [N, 3, h, w] (NCHW, RGB)")
        declared = dims[2], dims[3]
        if all(_fixed(d) for d in declared) and self.fit.size is None \
                and self.fit.short_side is None:
            return int(declared[0]), int(declared[1])
        size = self.fit.input_size(self.frame_size)
        if not all(_fits(d, s) for d, s in zip(declared, size)):
            raise DataError(self.path, f"takes input {_shape_text(dims)}, not the {size[1]}x"
                                       f"{size[0]} (WxH) asked for; give no input size, or its own")
        return size

    def _check_output(self, dims: Dims) -> None:
        """DataError unless `dims` can be one map per frame at the input's aspect ratio."""
        if len(dims) not in (3, 4) or (len(dims) == 4 and not _fits(dims[1], 1)):
            raise DataError(self.path, f"gives output {_shape_text(dims)}; expected one map per "
                                       "frame, [N, 1, h, w] or [N, h, w]")
        out_h, out_w = dims[-2:]
        if not (_fixed(out_h) and _fixed(out_w)):
            return
        in_h, in_w = self.input_size
        if abs(out_w - in_w * out_h / in_h) > max(1.0, 0.02 * out_w):
            raise DataError(self.path, f"gives a {out_w}x{out_h} (WxH) output for a {in_w}x{in_h}"
                                       " input: it cannot be resized back to the frame; expected "
                                       "the input's aspect ratio")

    def preprocess(self, frame: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """float32 [3, h, w] model input of a uint8 RGB frame [H, W, 3], written into `out`
        (float32 [3, h, w]) when given."""
        height, width = self.input_size
        if (height, width) != frame.shape[:2]:
            shrink = width < frame.shape[1]
            frame = cv2.resize(frame, (width, height),
                               interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
        planes = np.empty((3, height, width), np.float32) if out is None else out
        np.multiply(frame.transpose(2, 0, 1), self._scale, out=planes)
        planes += self._offset
        return planes

    def _infer(self, inputs: np.ndarray) -> np.ndarray:
        """float32 [n, h', w'] maps of float32 inputs [n, 3, h, w]."""
        try:
            (outputs,) = self.session.run([self.output_name], {self.input_name: inputs})
        except self._errors as err:
            raise DataError(self.path, f"failed on an input {_shape_text(inputs.shape)}: "
                                       f"{_first_line(err)}") from None
        self._check_output(outputs.shape)
        if outputs.shape[0] != len(inputs):
            raise DataError(self.path, f"gave {outputs.shape[0]} maps for {len(inputs)} frames; "
                                       "expected one per frame")
        return outputs.reshape(len(inputs), *outputs.shape[-2:]).astype(np.float32, copy=False)

    def run(self, frames: Iterable[np.ndarray],
            advance: Callable[[int], None] | None = None) -> Iterator[np.ndarray]:
        """The output float32 [H, W] of each uint8 RGB frame [H, W, 3] of `frame_size`, resized
        back to the frame; frames go through in batches of `batch`, and `advance(frames done)` is
        called after each batch."""
        height, width = self.frame_size
        frames, done = iter(frames), 0
        while batch := list(itertools.islice(frames, self.batch)):
            inputs = np.empty((self.batch if self.fixed_batch else len(batch), 3,
                               *self.input_size), np.float32)
            for row, frame in enumerate(batch):
                self.preprocess(frame, inputs[row])
            inputs[len(batch):] = inputs[len(batch) - 1]  # a fixed batch filled up: last frame
            maps = self._infer(inputs)[:len(batch)]
            done += len(batch)
            if advance is not None:
                advance(done)
            for output in maps:
                yield (output if output.shape == (height, width) else
                       cv2.resize(output, (width, height), interpolation=cv2.INTER_LINEAR))
