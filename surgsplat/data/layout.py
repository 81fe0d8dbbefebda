"""The EndoNeRF on-disk scene layout, shared by the loader, the importer and the phantom.

A scene folder holds::

    images/       RGB frames, 8-bit PNG (any of IMAGE_SUFFIXES is read)
    depth/        optional; per-frame depth in the scene's metric unit: 16-bit or 8-bit PNG
                  (stored integer x depth_scale = depth), or float .npy / .npz; 0 = no depth
    masks/        optional; 8-bit tool masks, 255 = tool, 0 = tissue
    poses_bounds.npy  [N, 17] LLFF: a 3x5 [R | t | (H, W, focal)] block per frame, then near, far
    scene.json    optional; SceneMeta (depth unit and PNG depth scale, provenance)

Files of the three folders are paired by sorted name; their counts must agree. The camera is
the OpenCV pinhole (x right, y down, z forward) with identity pose, and "depth" is the
z-coordinate in that frame (not the distance along the ray).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

IMAGES_DIR = "images"
DEPTH_DIR = "depth"
MASKS_DIR = "masks"
POSES_FILE = "poses_bounds.npy"
META_FILE = "scene.json"

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
DEPTH_SUFFIXES = (".png", ".npy", ".npz", ".tif", ".tiff")
TOOL_VALUE = 255
"""Value of a tool pixel in a mask file on disk."""


@dataclass
class SceneMeta:
    """Contents of scene.json: what a scene folder's files mean beyond their pixels."""

    depth_unit: str = "unknown"
    """Metric unit of depth values after scaling, e.g. "mm"; "unknown" for EndoNeRF's 8-bit PNGs."""
    depth_scale: float = 1.0
    """Scene units per stored integer step of a PNG/TIFF depth file (ignored for .npy/.npz)."""
    source: str = ""
    """Where the frames came from (video path, phantom preset, ...), for provenance only."""
    extra: dict = field(default_factory=dict)
    """Producer-specific facts (phantom motion, stereo baseline, ...), kept verbatim."""

    @staticmethod
    def read(path: Path) -> "SceneMeta":
        from surgsplat.errors import DataError

        try:
            raw = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise DataError(path, f"cannot read scene metadata as JSON ({err})") from err
        if not isinstance(raw, dict):
            raise DataError(path, "expected a JSON object with depth_unit / depth_scale")
        known = {k: raw[k] for k in ("depth_unit", "depth_scale", "source", "extra") if k in raw}
        meta = SceneMeta(**known)
        if not (isinstance(meta.depth_scale, (int, float)) and meta.depth_scale > 0):
            raise DataError(path, f"depth_scale must be a positive number, got {meta.depth_scale!r}")
        return meta

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(asdict(self), indent=2) + "\n")


def frame_stem(index: int) -> str:
    """File stem of frame `index` in scenes written by surgsplat."""
    return f"{index:06d}"


def list_files(folder: Path, suffixes: tuple[str, ...]) -> list[Path]:
    """Files of `folder` with one of `suffixes` (case-insensitive), sorted by name."""
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in suffixes)


def identity_poses_bounds(num_frames: int, height: int, width: int, focal: float,
                          near: float, far: float) -> np.ndarray:
    """LLFF poses_bounds [num_frames, 17] for a static camera with identity pose."""
    block = np.zeros((3, 5), dtype=np.float64)
    block[:, :3] = np.eye(3)
    block[:, 4] = (height, width, focal)
    row = np.concatenate([block.reshape(-1), [near, far]])
    return np.tile(row, (num_frames, 1))


class SceneWriter:
    """Writes a scene folder frame by frame; `finish()` writes poses_bounds.npy and scene.json.

    depth_scale: scene units per 16-bit PNG step (0.01 = 1/100 mm for millimetre scenes; the
    deepest storable depth is then 655.35 mm).
    """

    def __init__(self, root: str | Path, focal: float, meta: SceneMeta,
                 depth_scale: float = 0.01):
        self.root = Path(root)
        self.focal = float(focal)
        self.meta = meta
        self.meta.depth_scale = depth_scale
        self.count = 0
        self.size: tuple[int, int] | None = None  # (H, W)
        self.depth_range = [np.inf, 0.0]
        for sub in (IMAGES_DIR, DEPTH_DIR, MASKS_DIR):
            (self.root / sub).mkdir(parents=True, exist_ok=True)

    def add_frame(self, image: np.ndarray, depth: np.ndarray | None = None,
                  tool_mask: np.ndarray | None = None) -> None:
        """image: uint8 [H,W,3] RGB or float [H,W,3] in [0,1]; depth: float [H,W] in scene
        units, 0 = unknown; tool_mask: bool [H,W], True = tool."""
        if image.dtype != np.uint8:
            image = np.clip(np.rint(np.asarray(image) * 255.0), 0, 255).astype(np.uint8)
        height, width = image.shape[:2]
        if self.size is None:
            self.size = (height, width)
        elif self.size != (height, width):
            raise ValueError(f"frame {self.count} is {height}x{width}, earlier frames {self.size}")
        stem = frame_stem(self.count)
        cv2.imwrite(str(self.root / IMAGES_DIR / f"{stem}.png"), image[..., ::-1])
        if depth is not None:
            self._write_depth(stem, np.asarray(depth, dtype=np.float64))
        if tool_mask is not None:
            mask = np.where(np.asarray(tool_mask, dtype=bool), TOOL_VALUE, 0).astype(np.uint8)
            cv2.imwrite(str(self.root / MASKS_DIR / f"{stem}.png"), mask)
        self.count += 1

    def _write_depth(self, stem: str, depth: np.ndarray) -> None:
        stored = np.rint(depth / self.meta.depth_scale)
        if stored.max(initial=0) > 65535:
            raise ValueError(f"depth {depth.max():.1f} exceeds 16-bit PNG range at scale "
                             f"{self.meta.depth_scale}")
        cv2.imwrite(str(self.root / DEPTH_DIR / f"{stem}.png"), stored.astype(np.uint16))
        valid = depth[depth > 0]
        if valid.size:
            self.depth_range = [min(self.depth_range[0], float(valid.min())),
                                max(self.depth_range[1], float(valid.max()))]

    def finish(self, near: float | None = None, far: float | None = None) -> Path:
        """Write poses_bounds.npy (near/far default to the written depth range) and scene.json,
        and remove depth/ or masks/ when no frame had them."""
        if self.count == 0 or self.size is None:
            raise ValueError("no frame was written")
        for sub in (DEPTH_DIR, MASKS_DIR):
            folder = self.root / sub
            if not any(folder.iterdir()):
                folder.rmdir()
        if near is None:
            near = self.depth_range[0] if np.isfinite(self.depth_range[0]) else 0.01
        if far is None:
            far = self.depth_range[1] if self.depth_range[1] > 0 else 100.0
        height, width = self.size
        np.save(self.root / POSES_FILE,
                identity_poses_bounds(self.count, height, width, self.focal, near, far))
        self.meta.write(self.root / META_FILE)
        return self.root
