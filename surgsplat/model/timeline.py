"""Values known at a few times of the clip, read at any time."""

from __future__ import annotations

import torch
from torch import Tensor


def interpolate_in_time(values: Tensor, times: Tensor, t: float) -> Tensor:
    """Values [T, ...] known at increasing times [T] -> the value at t, linear between the two
    nearest times and held constant beyond the first and last (e.g. the illumination states
    of frames between trained ones, or their pose corrections)."""
    if values.shape[0] == 1 or t <= float(times[0]):
        return values[0]
    if t >= float(times[-1]):
        return values[-1]
    right = int(torch.searchsorted(times, torch.tensor([t], dtype=times.dtype))[0])
    left = right - 1
    weight = (t - float(times[left])) / float(times[right] - times[left])
    return (1.0 - weight) * values[left] + weight * values[right]
