"""Drawn clips where the automatic segmenter's cues are weak, with their true tool masks.

- `dark-on-dark`: a black plastic instrument over deep red, liver-like tissue;
- `white-on-pale`: a white insulated instrument over pale fascia and fat;
- `metal-grasper`: a large textured metal grasper (grooved jaws, bright streaks) that fills
  about a third of the view.

Each is a camera drifting over shaded, vascular tissue while the instrument moves on its own,
entering from the border; frames are 640x360 uint8 RGB.
"""

from __future__ import annotations

import cv2
import numpy as np

HEIGHT, WIDTH = 360, 640
MARGIN = 40
KINDS = ("dark-on-dark", "white-on-pale", "metal-grasper")

TISSUE = {"dark-on-dark": ((105, 30, 28), (70, 18, 20)),
          "white-on-pale": ((228, 205, 185), (205, 160, 150)),
          "metal-grasper": ((200, 95, 80), (130, 45, 45))}
"""(base colour, vessel colour) of each clip's tissue."""


def tissue(kind: str, seed: int) -> np.ndarray:
    """float32 RGB [H + 2 MARGIN, W + 2 MARGIN, 3]: shaded tissue with vessels and fine
    texture, larger than a frame so that the camera can drift over it."""
    rng = np.random.default_rng(seed)
    height, width = HEIGHT + 2 * MARGIN, WIDTH + 2 * MARGIN
    ys, xs = np.mgrid[0:height, 0:width]
    light = (0.7 + 0.25 * np.cos((xs - width / 2) / width * 2.4)
             * np.cos((ys - height / 2) / height * 1.6))
    base, vessel = TISSUE[kind]
    canvas = np.stack([c * light for c in base], axis=-1).astype(np.float32)
    for _ in range(14):
        start = (0, int(rng.integers(0, height)))
        end = (width - 1, start[1] + int(rng.integers(-120, 120)))
        cv2.line(canvas, start, end, tuple(float(c) for c in vessel), int(rng.integers(1, 4)))
    blotches = cv2.GaussianBlur(rng.normal(0, 12, (height, width)).astype(np.float32), (0, 0), 9)
    canvas += blotches[..., None]
    return canvas + cv2.GaussianBlur(rng.normal(0, 4, canvas.shape).astype(np.float32), (0, 0),
                                     1)


def _shaft(frame: np.ndarray, entry: tuple[int, int], tip: tuple[int, int], width: int,
           colour: tuple[int, int, int], rim: float, streak: tuple[int, int, int]) -> np.ndarray:
    """Draw a shaft from `entry` to `tip`: body `colour`, a rim darker by the factor `rim`,
    a bright `streak` along it; bool [H, W] its pixels."""
    mask = np.zeros(frame.shape[:2], np.uint8)
    cv2.line(mask, entry, tip, 1, width)
    frame[mask > 0] = colour
    inner = np.zeros_like(mask)
    cv2.line(inner, entry, tip, 1, max(2, width - 6))
    frame[(mask > 0) & (inner == 0)] = tuple(rim * c for c in colour)
    line = np.zeros_like(mask)
    offset = width // 5
    cv2.line(line, (entry[0], entry[1] - offset), (tip[0], tip[1] - offset), 1, 2)
    frame[(line > 0) & (mask > 0)] = streak
    return mask > 0


def _grasper(frame: np.ndarray, tip: tuple[int, int], opening: float,
             rng: np.random.Generator) -> np.ndarray:
    """A large metal grasper: a wide grooved shaft from the right border and two jaws opening
    by `opening` (radians) at `tip`; bool [H, W] its pixels."""
    entry = (WIDTH + 80, tip[1] - 120)
    mask = _shaft(frame, entry, tip, 150, (150, 150, 155), 0.55, (250, 250, 250))
    direction = np.subtract(tip, entry) / np.linalg.norm(np.subtract(tip, entry))
    for sign in (-1, 1):
        angle = np.arctan2(direction[1], direction[0]) + sign * opening
        end = (int(tip[0] + 150 * np.cos(angle)), int(tip[1] + 150 * np.sin(angle)))
        mask |= _shaft(frame, tip, end, 60, (165, 165, 170), 0.6, (245, 245, 245))
    grooves = np.zeros(frame.shape[:2], np.float32)
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    grooves[:] = 0.8 + 0.2 * np.sign(np.sin((xs * direction[0] + ys * direction[1]) / 3.0))
    noise = rng.normal(1.0, 0.05, frame.shape[:2]).astype(np.float32)
    frame[mask] *= (grooves * noise)[mask][:, None]
    return mask


def hard_clip(kind: str, frames: int = 24, seed: int = 0
              ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """(frames uint8 RGB [H, W, 3], true tool masks bool [H, W]) of the clip `kind`."""
    if kind not in KINDS:
        raise ValueError(f"unknown hard clip {kind!r}; expected one of {', '.join(KINDS)}")
    rng = np.random.default_rng(seed)
    canvas = tissue(kind, seed)
    images, truths = [], []
    for step in range(frames):
        phase = step / max(frames - 1, 1)
        shift = (int(round(MARGIN * (1 - phase))), int(round(MARGIN * phase)))
        frame = canvas[shift[0]:shift[0] + HEIGHT, shift[1]:shift[1] + WIDTH].copy()
        tip = (int(WIDTH * (0.62 - 0.25 * phase)), int(HEIGHT * (0.45 + 0.2 * np.sin(4 * phase))))
        if kind == "dark-on-dark":
            truth = _shaft(frame, (WIDTH + 40, tip[1] - 90), tip, 34, (32, 30, 33), 0.5,
                           (150, 150, 150))
        elif kind == "white-on-pale":
            truth = _shaft(frame, (WIDTH + 40, tip[1] - 90), tip, 30, (238, 238, 236), 0.85,
                           (255, 255, 255))
        else:
            truth = _grasper(frame, (int(WIDTH * (0.5 - 0.1 * phase)), tip[1] + 30),
                             0.15 + 0.35 * abs(np.sin(3 * phase)), rng)
        images.append(np.clip(frame, 0, 255).astype(np.uint8))
        truths.append(truth)
    return images, truths
