"""The EndoNeRF on-disk scene layout, shared by the loader, the importer and the phantom.

A scene folder holds::

    images/       RGB frames, 8-bit PNG (any of IMAGE_SUFFIXES is read)
    depth/        optional; per-frame depth in the scene's metric unit: 16-bit or 8-bit PNG
                  (stored integer x depth_scale = depth), or float .npy / .npz; 0 = no depth
    masks/        optional; 8-bit tool masks, 255 = tool (excluded), 0 = not tool
    fov_mask.png  optional; 8-bit field-of-view mask for every frame, 255 = inside the field of
                  view, 0 = outside (the black border of a laparoscope); absent = all inside
    poses_bounds.npy  [N, 17] LLFF: a 3x5 [R | t | (H, W, focal)] block per frame, then near, far
    scene.json    optional; SceneMeta (depth unit and PNG depth scale, full intrinsics,
                  provenance)
    sparse_points.ply  optional; structure-from-motion points (world frame, scene units, RGB),
                  written by `surgsplat import --poses sfm` (see `sparse_points`)

Files of the three folders are paired in natural order of their names (frame_2 before
frame_10, see `natural_key`); their counts must agree. Scenes imported
before fov_mask.png existed hold the border in masks/; they load as before (border = tool).

Cameras are OpenCV pinholes (x right, y down, z forward); "depth" is the z-coordinate in the
frame's camera (not the distance along the ray). Pixel (u, v) = (column, row) has its centre
at (u + 0.5, v + 0.5), so a principal point at the image centre is (W / 2, H / 2) (OpenCV's
calibration puts pixel centres at integers: cx here = cx in OpenCV + 0.5).

Intrinsics: scene.json's `intrinsics` {fx, fy, cx, cy} (pixels, this convention) when present;
otherwise fx = fy = the hwf focal of poses_bounds.npy and the principal point is the image
centre. The hwf focal is written as fx either way, for EndoNeRF-layout readers.

Poses (LLFF convention and its conversion): each 3x4 [R | t] is camera-to-world, with the
columns of R the camera's [down, right, backwards] axes in world coordinates and t its centre.
With the axis change Q = [[0, 1, 0], [1, 0, 0], [0, 0, -1]] (Q = Q^T = Q^-1, det Q = 1, which
turns LLFF camera axes (down, right, backwards) into OpenCV's (right, down, forward)), the
OpenCV camera-to-world is

    R_cv = Q R Q,  t_cv = Q t,   world_to_camera = [R_cv^T | -R_cv^T t_cv],

i.e. the camera axes are re-ordered (right = R[:, 1], down = R[:, 0], forward = -R[:, 2]) and
the world axes are relabelled by the same Q (x_w = y_file, y_w = x_file, z_w = -z_file). Any
fixed relabelling of the world is allowed; this one maps the identity block of the EndoNeRF
files (a static camera) to the identity pose, so the world frame is then the camera frame.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
from dataclasses import asdict, dataclass, field
from fnmatch import fnmatchcase
from pathlib import Path

import cv2
import numpy as np

from surgsplat.errors import DataError

IMAGES_DIR = "images"
DEPTH_DIR = "depth"
MASKS_DIR = "masks"
FOV_FILE = "fov_mask.png"
POSES_FILE = "poses_bounds.npy"
META_FILE = "scene.json"
SPARSE_POINTS_FILE = "sparse_points.ply"

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")
DEPTH_SUFFIXES = (".png", ".npy", ".npz", ".tif", ".tiff")
TOOL_VALUE = 255
"""Value of a tool pixel in a mask file on disk."""
INSIDE_VALUE = 255
"""Value of a pixel inside the field of view in fov_mask.png."""
MAX_FRAME_PIXELS = 4096 * 4096
"""Largest frame, in pixels, that surgsplat makes by resizing (`import --scale`, `--resize`, an
ONNX model's input size): 4096 x 4096, above 4K UHD (3840 x 2160). Each decoded frame with its
depth and masks takes some 19 bytes a pixel in memory (over 300 MB at this size), and
training renders every frame at its full size."""
MAX_DEPTH_MM = 10_000.0
"""Largest depth a depth frame may hold, in millimetres: 10 m, some thirty times the depth of an
insufflated abdomen (about 300 mm), so a larger value is a unit or scale error (a wrong
depth_scale, depth stored in micrometres), not something an endoscope saw. `max_depth` gives
it in a scene's unit."""
MILLIMETRES_PER_UNIT = {"um": 1e-3, "mm": 1.0, "cm": 10.0, "m": 1000.0}
"""Millimetres in one depth unit, for the metric units a scene.json may name."""
LLFF_TO_OPENCV = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""Q of the module doc: LLFF (down, right, backwards) axes to OpenCV (right, down, forward)."""


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; pixel centres at (u + 0.5, v + 0.5) (see the module doc)."""

    fx: float
    """Focal length along image columns, pixels."""
    fy: float
    """Focal length along image rows, pixels."""
    cx: float
    """Principal point, pixels from the left image edge (W / 2 = centred)."""
    cy: float
    """Principal point, pixels from the top image edge (H / 2 = centred)."""

    @staticmethod
    def centred(focal: float, width: int, height: int) -> "Intrinsics":
        """Square pixels of focal length `focal` with the principal point at the image centre."""
        return Intrinsics(fx=float(focal), fy=float(focal), cx=width / 2.0, cy=height / 2.0)

    def scaled(self, sx: float, sy: float) -> "Intrinsics":
        """The intrinsics of the image resized by sx along columns and sy along rows."""
        return Intrinsics(fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy)

    def matrix(self) -> np.ndarray:
        """K [3, 3] float64."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def check(self, width: int | None = None, height: int | None = None) -> None:
        """ValueError saying what is wrong unless fx, fy > 0 and finite and, given the image
        size, the principal point lies inside the image."""
        values = (self.fx, self.fy, self.cx, self.cy)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) for v in values):
            raise ValueError(f"intrinsics must be finite numbers, got fx={self.fx!r}, "
                             f"fy={self.fy!r}, cx={self.cx!r}, cy={self.cy!r}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"focal lengths fx and fy must be positive (pixels), got "
                             f"fx={self.fx:g}, fy={self.fy:g}")
        if width is not None and height is not None and not (
                0 <= self.cx <= width and 0 <= self.cy <= height):
            raise ValueError(f"principal point (cx, cy) = ({self.cx:g}, {self.cy:g}) lies "
                             f"outside the {width}x{height} (WxH) image")


@dataclass
class SceneMeta:
    """Contents of scene.json: what a scene folder's files mean beyond their pixels."""

    depth_unit: str = "unknown"
    """Metric unit of depth values after scaling, e.g. "mm"; "unknown" for EndoNeRF's 8-bit PNGs."""
    depth_scale: float = 1.0
    """Scene units per stored integer step of a PNG/TIFF depth file (ignored for .npy/.npz)."""
    intrinsics: Intrinsics | None = None
    """Full intrinsics of every frame; None = the hwf focal with a centred principal point."""
    source: str = ""
    """Where the frames came from (video path, phantom preset, ...), for provenance only."""
    extra: dict = field(default_factory=dict)
    """Producer-specific facts (phantom motion, stereo baseline, ...), kept verbatim."""

    @staticmethod
    def read(path: Path) -> "SceneMeta":
        try:
            raw = json.loads(path.read_text())
        except (OSError, ValueError) as err:  # ValueError: not JSON, or not UTF-8 text
            raise DataError(path, f"cannot read scene metadata as JSON ({err})") from err
        if not isinstance(raw, dict):
            raise DataError(path, "expected a JSON object with depth_unit / depth_scale")
        known = {k: raw[k] for k in ("depth_unit", "depth_scale", "source", "extra") if k in raw}
        meta = SceneMeta(**known)
        if not (isinstance(meta.depth_scale, (int, float)) and math.isfinite(meta.depth_scale)
                and meta.depth_scale > 0):
            raise DataError(path, f"depth_scale must be a positive finite number, got "
                                  f"{meta.depth_scale!r}")
        if raw.get("intrinsics") is not None:
            meta.intrinsics = _read_intrinsics(path, raw["intrinsics"])
        return meta

    def write(self, path: Path) -> None:
        """Write as JSON; `intrinsics` is left out when None (the hwf camera)."""
        contents = asdict(self)
        if self.intrinsics is None:
            del contents["intrinsics"]
        path.write_text(json.dumps(contents, indent=2) + "\n")


def _read_intrinsics(path: Path, raw: object) -> Intrinsics:
    keys = ("fx", "fy", "cx", "cy")
    if not isinstance(raw, dict) or set(raw) != set(keys):
        raise DataError(path, f"intrinsics must be an object with exactly the keys fx, fy, cx, "
                              f"cy (pixels), got {raw!r}")
    intrinsics = Intrinsics(**raw)
    try:
        intrinsics.check()
    except ValueError as err:
        raise DataError(path, f"intrinsics: {err}") from None
    return intrinsics


def max_depth(unit: str) -> float:
    """MAX_DEPTH_MM in the depth unit `unit` (one of MILLIMETRES_PER_UNIT); any other unit
    (unknown, relative) counts as millimetres, the scale of the depth surgsplat assumes without
    metric depth (50 scene units)."""
    return MAX_DEPTH_MM / MILLIMETRES_PER_UNIT.get(unit, 1.0)


def frame_stem(index: int) -> str:
    """File stem of frame `index` in scenes written by surgsplat."""
    return f"{index:06d}"


_DIGITS = re.compile(r"(\d+)")


def natural_key(path: Path) -> tuple:
    """Sort key of a file name with its digit runs compared as numbers: frame_2 < frame_10."""
    parts = _DIGITS.split(path.name)
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part.lower()) for part in parts)


def name_numbers(path: Path) -> tuple[int, ...]:
    """The numbers in a file's stem, in order: frame_561_endo_mask.png -> (561,)."""
    return tuple(int(run) for run in _DIGITS.findall(path.stem))


def list_files(folder: Path, suffixes: tuple[str, ...], pattern: str | None = None
               ) -> list[Path]:
    """Files of `folder` whose names match the glob `pattern`, or without one end in one of
    `suffixes` (case-insensitive), in natural order (`natural_key`). Sub-folders are passed
    over; any other entry of such a name (a broken or looping symbolic link, a pipe, a device)
    is a DataError naming it, since passing over a frame would shift every later one in time."""
    files = []
    for path in folder.iterdir():
        if not (fnmatchcase(path.name, pattern) if pattern is not None
                else path.suffix.lower() in suffixes):
            continue
        if path.is_file():
            files.append(path)
        elif not path.is_dir():
            raise DataError(path, f"{not_a_file_problem(path)}: expected a frame file of "
                                  f"{folder}")
    return sorted(files, key=natural_key)


def not_a_file_problem(path: Path) -> str:
    """What `path`, which is neither a regular file nor a folder, is instead, for a message:
    missing, a broken or looping symbolic link, a pipe, a device or a socket."""
    try:
        mode = path.stat().st_mode
    except OSError as err:
        if path.is_symlink():
            return (f"is a symbolic link to {os.readlink(path)} that leads to no file "
                    f"({err.strerror})")
        return "does not exist"
    if stat.S_ISFIFO(mode):
        return "is a pipe (a FIFO, or a process substitution such as <(cat video.mp4))"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "is a device, not a regular file"
    if stat.S_ISSOCK(mode):
        return "is a socket, not a regular file"
    return "is not a regular file"


def write_image(path: Path, pixels: np.ndarray) -> None:
    """Write `pixels` (as cv2.imwrite takes them: BGR order, uint8 or uint16) to `path`, encoded
    by its suffix. Unlike cv2.imwrite, which reports success on a full disk, a failed write
    raises an OSError naming `path`."""
    ok, encoded = cv2.imencode(path.suffix, pixels)
    if not ok:
        raise ValueError(f"{path}: cannot encode a {pixels.dtype} {pixels.shape} image")
    try:
        path.write_bytes(encoded.tobytes())
    except OSError as err:
        raise OSError(err.errno, err.strerror or str(err), str(path)) from err


def world_to_camera_from_llff(blocks: np.ndarray) -> np.ndarray:
    """OpenCV world-to-camera [N, 4, 4] of LLFF camera-to-world blocks [N, 3, 4] (module doc)."""
    q = LLFF_TO_OPENCV
    rotation = q @ blocks[:, :, :3] @ q  # [N, 3, 3] camera-to-world, OpenCV axes
    centre = blocks[:, :, 3] @ q.T  # [N, 3] camera centre in the world
    world_to_camera = np.zeros((len(blocks), 4, 4))
    world_to_camera[:, :3, :3] = rotation.transpose(0, 2, 1)
    world_to_camera[:, :3, 3] = -np.einsum("nji,nj->ni", rotation, centre)
    world_to_camera[:, 3, 3] = 1.0
    return world_to_camera + 0.0  # no negative zeros


def llff_from_world_to_camera(world_to_camera: np.ndarray) -> np.ndarray:
    """LLFF camera-to-world blocks [N, 3, 4] of OpenCV world-to-camera [N, 4, 4]; the inverse
    of `world_to_camera_from_llff`."""
    q = LLFF_TO_OPENCV
    rotation = world_to_camera[:, :3, :3].transpose(0, 2, 1)  # camera-to-world
    centre = -np.einsum("nij,nj->ni", rotation, world_to_camera[:, :3, 3])  # [N, 3]
    blocks = np.concatenate([q @ rotation @ q, (centre @ q.T)[..., None]], axis=2)
    return blocks + 0.0  # no negative zeros


def poses_bounds(world_to_camera: np.ndarray, height: int, width: int, focal: float,
                 near: float, far: float) -> np.ndarray:
    """LLFF poses_bounds [N, 17] of per-frame OpenCV world-to-camera poses [N, 4, 4]."""
    blocks = llff_from_world_to_camera(np.asarray(world_to_camera, dtype=np.float64))
    hwf = np.broadcast_to(np.array([height, width, focal], dtype=np.float64), (len(blocks), 3))
    rows = np.concatenate([blocks, hwf[..., None]], axis=2).reshape(len(blocks), 15)
    bounds = np.broadcast_to(np.array([near, far], dtype=np.float64), (len(blocks), 2))
    return np.concatenate([rows, bounds], axis=1)


class SceneWriter:
    """Writes a scene folder frame by frame; `finish()` writes poses_bounds.npy, fov_mask.png
    (when set) and scene.json.

    focal: the hwf focal of poses_bounds.npy, pixels; it must equal meta.intrinsics.fx when
    meta holds full intrinsics. depth_scale: scene units per 16-bit PNG step (0.01 = 1/100 mm
    for millimetre scenes; the deepest storable depth is then 655.35 mm).
    """

    def __init__(self, root: str | Path, focal: float, meta: SceneMeta,
                 depth_scale: float = 0.01):
        if meta.intrinsics is not None and not math.isclose(meta.intrinsics.fx, focal):
            raise ValueError(f"focal {focal:g} differs from the intrinsics' fx "
                             f"{meta.intrinsics.fx:g}")
        self.root = Path(root)
        self.focal = float(focal)
        self.meta = meta
        self.meta.depth_scale = depth_scale
        self.count = 0
        self.size: tuple[int, int] | None = None  # (H, W)
        self.depth_range = [np.inf, 0.0]
        self.poses: list[np.ndarray] = []  # per frame [4, 4] world-to-camera
        self.fov: np.ndarray | None = None  # [H, W] bool, True = inside the field of view
        for sub in (IMAGES_DIR, DEPTH_DIR, MASKS_DIR):
            (self.root / sub).mkdir(parents=True, exist_ok=True)

    def add_frame(self, image: np.ndarray, depth: np.ndarray | None = None,
                  tool_mask: np.ndarray | None = None,
                  world_to_camera: np.ndarray | None = None) -> None:
        """image: uint8 [H,W,3] RGB or float [H,W,3] in [0,1]; depth: float [H,W] in scene
        units, 0 = unknown; tool_mask: bool [H,W], True = tool; world_to_camera: [4, 4] OpenCV
        pose of the frame's camera, None = identity."""
        if image.dtype != np.uint8:
            image = np.clip(np.rint(np.asarray(image) * 255.0), 0, 255).astype(np.uint8)
        height, width = image.shape[:2]
        if self.size is None:
            self.size = (height, width)
        elif self.size != (height, width):
            raise ValueError(f"frame {self.count} is {height}x{width}, earlier frames {self.size}")
        stem = frame_stem(self.count)
        write_image(self.root / IMAGES_DIR / f"{stem}.png", image[..., ::-1])
        if depth is not None:
            self._write_depth(stem, np.asarray(depth, dtype=np.float64))
        if tool_mask is not None:
            mask = np.where(np.asarray(tool_mask, dtype=bool), TOOL_VALUE, 0).astype(np.uint8)
            write_image(self.root / MASKS_DIR / f"{stem}.png", mask)
        self.poses.append(np.eye(4) if world_to_camera is None
                          else np.asarray(world_to_camera, dtype=np.float64))
        self.count += 1

    def set_camera(self, world_to_camera: np.ndarray, intrinsics: Intrinsics | None = None
                   ) -> None:
        """Replace the poses of the frames written so far, [count, 4, 4] OpenCV world-to-camera
        (e.g. estimated once every frame is in), and, given, the intrinsics (and focal)."""
        if world_to_camera.shape != (self.count, 4, 4):
            raise ValueError(f"expected [{self.count}, 4, 4] poses, got {world_to_camera.shape}")
        self.poses = list(np.asarray(world_to_camera, dtype=np.float64))
        if intrinsics is not None:
            self.meta.intrinsics = intrinsics
            self.focal = float(intrinsics.fx)

    def set_fov(self, inside: np.ndarray) -> None:
        """The field of view of every frame, bool [H, W] (True = inside); written by finish()."""
        self.fov = np.asarray(inside, dtype=bool)

    def _write_depth(self, stem: str, depth: np.ndarray) -> None:
        stored = np.rint(depth / self.meta.depth_scale)
        if stored.max(initial=0) > 65535:
            raise ValueError(f"depth {depth.max():.1f} exceeds 16-bit PNG range at scale "
                             f"{self.meta.depth_scale}")
        write_image(self.root / DEPTH_DIR / f"{stem}.png", stored.astype(np.uint16))
        valid = depth[depth > 0]
        if valid.size:
            self.depth_range = [min(self.depth_range[0], float(valid.min())),
                                max(self.depth_range[1], float(valid.max()))]

    def finish(self, near: float | None = None, far: float | None = None) -> Path:
        """Write poses_bounds.npy (near/far default to the written depth range), fov_mask.png
        and scene.json, and remove depth/ or masks/ when no frame had them."""
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
        if self.fov is not None:
            if self.fov.shape != self.size:
                raise ValueError(f"field of view mask is {self.fov.shape}, frames {self.size}")
            write_image(self.root / FOV_FILE, np.where(self.fov, INSIDE_VALUE, 0).astype(np.uint8))
        np.save(self.root / POSES_FILE,
                poses_bounds(np.stack(self.poses), height, width, self.focal, near, far))
        self.meta.write(self.root / META_FILE)
        return self.root
