"""Time curves of the phantom's motions: what the tool and the tissue do over a sequence.

Time t is frame index / number of frames, in [0, 1), so a motion looks the same at any frame
count. Every curve passes through keyframes with smoothstep easing between them, so positions
and angles are continuous with continuous velocity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MOTIONS = ("pulling", "cutting", "grasping")
"""Valid motion names."""


def smoothstep(x: np.ndarray | float) -> np.ndarray:
    """3x^2 - 2x^3 of x clipped to [0, 1]: 0 below 0, 1 above 1, zero slope at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


@dataclass(frozen=True)
class Keyframes:
    """A scalar curve through (times[k], values[k]), held constant outside the first/last key."""

    times: tuple[float, ...]
    """Strictly increasing key times in [0, 1]."""
    values: tuple[float, ...]
    """Curve value at each key time."""

    def __call__(self, t: float) -> float:
        k = int(np.searchsorted(self.times, t, side="right"))
        if k == 0:
            return self.values[0]
        if k == len(self.times):
            return self.values[-1]
        t0, t1 = self.times[k - 1], self.times[k]
        v0, v1 = self.values[k - 1], self.values[k]
        return float(v0 + (v1 - v0) * smoothstep((t - t0) / (t1 - t0)))


@dataclass(frozen=True)
class MotionProgram:
    """The tool's and the tissue's schedule for one motion."""

    name: str
    """One of MOTIONS."""
    insertion: Keyframes
    """How far the tool is pulled back along its shaft: 1 = out of view, 0 = at the tissue."""
    jaw_deg: Keyframes
    """Opening angle between the two jaws, degrees."""
    lift_mm: Keyframes
    """Pulling: height of the tissue bump raised by the grasping jaws, mm (0 when cutting)."""
    cut_front: Keyframes
    """Cutting: how far the groove has been cut, as a fraction of the cut line; values above 1
    let the groove keep opening after the tool reaches the line's end (0 when pulling)."""


def _snips(start: float, stop: float, count: int, open_deg: float) -> Keyframes:
    """Scissor jaws that close `count` times between `start` and `stop`, open otherwise."""
    times = np.linspace(start, stop, 2 * count + 1)
    values = [open_deg if k % 2 == 0 else 0.0 for k in range(len(times))]
    return Keyframes(tuple(float(t) for t in times), tuple(values))


def motion_program(name: str) -> MotionProgram:
    """The schedule of motion `name` (one of MOTIONS)."""
    if name == "pulling":
        # Approach with open jaws, grasp, lift the tissue, lower it, release, withdraw.
        return MotionProgram(
            name=name,
            insertion=Keyframes((0.0, 0.25, 0.9, 1.0), (1.0, 0.0, 0.0, 0.5)),
            jaw_deg=Keyframes((0.0, 0.22, 0.32, 0.82, 0.9), (35.0, 35.0, 0.0, 0.0, 35.0)),
            lift_mm=Keyframes((0.0, 0.32, 0.58, 0.85), (0.0, 0.0, 10.0, 0.0)),
            cut_front=Keyframes((0.0,), (0.0,)),
        )
    if name == "cutting":
        # Approach, then snip along the cut line while the groove opens behind the tool.
        return MotionProgram(
            name=name,
            insertion=Keyframes((0.0, 0.22, 0.85, 1.0), (1.0, 0.0, 0.0, 0.5)),
            jaw_deg=_snips(0.25, 0.8, 6, 25.0),
            lift_mm=Keyframes((0.0,), (0.0,)),
            cut_front=Keyframes((0.0, 0.25, 0.95), (0.0, 0.0, 1.35)),
        )
    if name == "grasping":
        # In view from the first frame to the last at one grasp point: the jaws open wide and
        # close three times, lifting the tissue while closed; the tissue under the shaft is
        # never seen.
        times = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
        return MotionProgram(
            name=name,
            insertion=Keyframes((0.0,), (0.0,)),
            jaw_deg=Keyframes(times, (10.0, 60.0, 0.0, 0.0, 60.0, 0.0, 0.0, 60.0, 0.0, 0.0,
                                      45.0)),
            lift_mm=Keyframes(times, (0.0, 0.0, 0.0, 6.0, 0.0, 0.0, 6.0, 0.0, 0.0, 6.0, 0.0)),
            cut_front=Keyframes((0.0,), (0.0,)),
        )
    raise ValueError(f"unknown motion {name!r}; valid motions: {', '.join(MOTIONS)}")
