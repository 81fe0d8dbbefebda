"""PerFrame: a value of a frame's pixels computed once per frame and size."""

import torch

from surgsplat.data.frame_memo import PerFrame
from surgsplat.data.scene import Camera, Frame


def frame(index: int, size: int = 32) -> Frame:
    K = torch.tensor([[40.0, 0, size / 2], [0, 40.0, size / 2], [0, 0, 1]])
    image = torch.full((size, size, 3), float(index) / 10)
    mask = torch.zeros(size, size, dtype=torch.bool)
    return Frame(index, index / 10, image, None, False, Camera(K, torch.eye(4), size, size),
                 mask, ~mask)


def test_a_value_is_computed_once_per_frame_and_size():
    calls = []

    def mean_colour(seen: Frame) -> float:
        calls.append((seen.index, seen.camera.width))
        return float(seen.image.mean())

    memo = PerFrame(mean_colour)
    first, second = frame(1), frame(2)
    assert memo(first) == memo(first) == float(first.image.mean())
    assert memo(second) == float(second.image.mean())
    assert memo(first.downscaled(2)) == float(first.image.mean())
    assert calls == [(1, 32), (2, 32), (1, 16)]
