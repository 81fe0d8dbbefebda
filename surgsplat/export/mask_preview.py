"""A scene's tool masks over its frames, as a video a person checks (`masks_preview.mp4`).

Each frame shows the tool pixels tinted and outlined, the frame's index among the imported
frames (the INDEX a prompt file names), its mask confidence when the masks are derived (the
automatic segmenter's or the prompted masks', from scene.json), the clicks of the prompts on
the frames they were given on, and a strip along the bottom: the confidence of every frame,
the current one marked, so that the frames to check stand out.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from surgsplat.data.layout import META_FILE, SceneMeta
from surgsplat.data.scene import Scene
from surgsplat.export.video import VideoWriter, even_size

PREVIEW_FILE = "masks_preview.mp4"
TOOL_TINT = np.array([40, 230, 90], np.float32)
"""RGB of the tint of tool pixels."""
STRIP_PX = 24
"""Height of the confidence strip under the frame."""


def mask_confidences(meta: SceneMeta) -> list[float] | None:
    """The per-frame confidences of the scene's derived masks, or None (given masks)."""
    masks = meta.extra.get("masks")
    if not isinstance(masks, dict) or "confidence" not in masks:
        return None
    return [float(value) for value in masks["confidence"]]


def prompt_clicks(meta: SceneMeta) -> dict[int, list[tuple[str, float, float]]]:
    """(kind, x, y) of the prompts' clicks per frame index, in the written frames' pixels."""
    extra = meta.extra
    masks = extra.get("masks")
    if not isinstance(masks, dict) or "prompts" not in masks:
        return {}
    (source_w, source_h), (width, height) = extra["source_size_wh"], extra["size_wh"]
    clicks: dict[int, list[tuple[str, float, float]]] = {}
    for prompt in masks["prompts"]:
        for kind in ("tool", "tissue"):
            for x, y in prompt[kind]:
                clicks.setdefault(prompt["frame"], []).append(
                    (kind, x * width / source_w, y * height / source_h))
    return clicks


def preview_frame(image: np.ndarray, tool: np.ndarray, index: int,
                  confidences: list[float] | None,
                  clicks: list[tuple[str, float, float]]) -> np.ndarray:
    """uint8 RGB [H + STRIP_PX, W, 3]: `image` (uint8 RGB [H, W, 3]) with the tool mask
    `tool` (bool [H, W]) tinted and outlined, its label, its clicks, and the strip."""
    picture = image.astype(np.float32)
    picture[tool] = 0.55 * picture[tool] + 0.45 * TOOL_TINT
    picture = picture.astype(np.uint8)
    contours, _ = cv2.findContours(tool.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(picture, contours, -1, tuple(int(c) for c in TOOL_TINT), 1)
    for kind, x, y in clicks:
        colour = (255, 255, 0) if kind == "tool" else (0, 160, 255)
        cv2.drawMarker(picture, (int(round(x)), int(round(y))), colour, cv2.MARKER_CROSS, 14, 2)
    label = f"frame {index}"
    if confidences is not None:
        label += f"  confidence {confidences[index]:.2f}"
    for colour, thickness in (((0, 0, 0), 2), ((255, 255, 255), 1)):
        cv2.putText(picture, label, (8, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, colour, thickness,
                    cv2.LINE_AA)
    return np.concatenate([picture, confidence_strip(picture.shape[1], index, confidences)])


def confidence_strip(width: int, index: int, confidences: list[float] | None) -> np.ndarray:
    """uint8 RGB [STRIP_PX, width, 3]: one bar per frame, its height the frame's confidence
    (red below 0.5, amber below 0.75, green above), the frame `index` marked in white; grey
    when the masks have no confidences."""
    strip = np.full((STRIP_PX, width, 3), 30, np.uint8)
    count = len(confidences) if confidences is not None else 1
    edges = np.linspace(0, width, count + 1).round().astype(int)
    if confidences is not None:
        for frame, value in enumerate(confidences):
            colour = (220, 60, 50) if value < 0.5 else (230, 170, 40) if value < 0.75 else \
                (60, 190, 80)
            top = STRIP_PX - max(1, round(value * (STRIP_PX - 4)))
            strip[top:, edges[frame]:max(edges[frame + 1], edges[frame] + 1)] = colour
        left, right = edges[index], max(edges[index + 1], edges[index] + 1)
        strip[:, left:right] = np.maximum(strip[:, left:right], 90)
        strip[:3, left:right] = 255
    return strip


def write_mask_preview(scene: Scene, fps: float = 10.0,
                       progress: Callable[[int, int], None] | None = None) -> Path:
    """Write the scene's masks_preview.mp4 (see the module docstring) into its folder, frame by
    frame; `progress(done, total)` after each frame. Returns its path."""
    meta = SceneMeta.read(scene.root / META_FILE)
    confidences = mask_confidences(meta)
    if confidences is not None and len(confidences) != len(scene.frames):
        confidences = None  # masks edited since the import: their confidences no longer hold
    clicks = prompt_clicks(meta)
    path = scene.root / PREVIEW_FILE
    with VideoWriter(path, fps) as video:
        for done, frame in enumerate(scene.frames, start=1):
            image = (frame.image.numpy() * 255.0 + 0.5).astype(np.uint8)
            video.add(even_size(preview_frame(image, frame.tool.numpy(), frame.index,
                                              confidences, clicks.get(frame.index, []))))
            if progress is not None:
                progress(done, len(scene.frames))
    return path
