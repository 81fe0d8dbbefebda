"""Values that follow from a frame's pixels alone (a median depth, an edge weight map), computed
once per frame and size instead of at every training step that draws the frame again."""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

from surgsplat.data.scene import Frame

Value = TypeVar("Value")


class PerFrame(Generic[Value]):
    """`compute(frame)` kept per (frame index, image height, width): a frame seen again, at the
    same size, gets the kept value. Only for values of the frame's own pixels (image, depth,
    masks), which do not change during a run; a downscaled frame (another size) gets its own."""

    def __init__(self, compute: Callable[[Frame], Value]):
        self._compute = compute
        self._kept: dict[tuple[int, int, int], Value] = {}

    def __call__(self, frame: Frame) -> Value:
        key = (frame.index, frame.camera.height, frame.camera.width)
        if key not in self._kept:
            self._kept[key] = self._compute(frame)
        return self._kept[key]
