"""Load and validate an EndoNeRF-layout scene folder (see `surgsplat.data.layout`).

Every problem with the files is reported as a DataError naming the file and what was expected,
before any training starts.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch import Tensor

from surgsplat.data.layout import (DEPTH_DIR, DEPTH_SUFFIXES, IMAGE_SUFFIXES, IMAGES_DIR,
                                   MASKS_DIR, META_FILE, POSES_FILE, TOOL_VALUE, SceneMeta,
                                   list_files)
from surgsplat.errors import DataError

TEST_EVERY = 8
"""Test frames are those with index % TEST_EVERY == TEST_OFFSET (the EndoNeRF-family split)."""
TEST_OFFSET = 1


@dataclass(frozen=True)
class Camera:
    """A pinhole camera in OpenCV convention (x right, y down, z forward)."""

    K: Tensor  # [3, 3] float32 intrinsics in pixels; principal point at the image centre
    world_to_camera: Tensor  # [4, 4] float32; identity for EndoNeRF scenes
    width: int
    height: int

    @property
    def focal(self) -> float:
        return float(self.K[0, 0])


@dataclass(frozen=True)
class Frame:
    """One video frame with what is known about it."""

    index: int
    time: float  # index / number of frames, in [0, 1)
    image: Tensor  # [H, W, 3] float32 RGB in [0, 1]
    depth: Tensor | None  # [H, W] float32 in the scene's depth unit; 0 = no depth
    tissue: Tensor  # [H, W] bool, True = tissue (False = tool or outside the field of view)
    is_test: bool


@dataclass(frozen=True)
class Scene:
    """A loaded scene: frames, one static camera, and what its depth means."""

    root: Path
    frames: list[Frame]
    camera: Camera
    meta: SceneMeta
    near: float
    far: float
    has_depth: bool
    has_masks: bool

    @property
    def train_frames(self) -> list[Frame]:
        return [f for f in self.frames if not f.is_test]

    @property
    def test_frames(self) -> list[Frame]:
        return [f for f in self.frames if f.is_test]

    @property
    def depth_unit(self) -> str:
        return self.meta.depth_unit


def is_test_index(index: int) -> bool:
    """Whether frame `index` belongs to the test split (i % 8 == 1)."""
    return index % TEST_EVERY == TEST_OFFSET


def read_image(path: Path) -> np.ndarray:
    """An image file as uint8 RGB [H, W, 3]; 16-bit images are reduced to 8 bits."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise DataError(path, "cannot be read as an image (missing, corrupt or unknown format)")
    if raw.dtype == np.uint16:
        raw = (raw // 257).astype(np.uint8)
    if raw.dtype != np.uint8:
        raise DataError(path, f"expected an 8-bit or 16-bit image, got {raw.dtype}")
    if raw.ndim == 2:
        return np.repeat(raw[..., None], 3, axis=2)
    if raw.shape[2] == 4:
        raw = raw[..., :3]
    if raw.shape[2] != 3:
        raise DataError(path, f"expected 1, 3 or 4 channels, got {raw.shape[2]}")
    return np.ascontiguousarray(raw[..., ::-1])


def read_depth(path: Path, depth_scale: float) -> np.ndarray:
    """A depth file as float32 [H, W] in scene units (stored integers x depth_scale for images)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            depth = np.load(path, allow_pickle=False)
        elif suffix == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                if len(archive.files) != 1:
                    raise DataError(path, f"expected one array in the .npz, found {archive.files}")
                depth = archive[archive.files[0]]
        else:
            depth = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            if depth is None:
                raise DataError(path, "cannot be read as a depth image (missing or corrupt)")
            if depth.dtype in (np.uint8, np.uint16):
                depth = depth.astype(np.float32) * depth_scale
    except (OSError, ValueError) as err:
        raise DataError(path, f"cannot be read as a depth array ({err})") from err
    depth = np.asarray(depth)
    if depth.ndim == 3 and depth.shape[2] in (3, 4) and suffix not in (".npy", ".npz"):
        depth = depth[..., 0]
    if depth.ndim == 3 and 1 in (depth.shape[0], depth.shape[-1]):
        depth = depth.squeeze()
    if depth.ndim != 2:
        raise DataError(path, f"expected a single-channel depth map [H, W], got shape {depth.shape}")
    if not np.issubdtype(depth.dtype, np.number):
        raise DataError(path, f"expected numeric depth, got {depth.dtype}")
    depth = depth.astype(np.float32)
    if not np.isfinite(depth).all():
        raise DataError(path, "depth holds NaN or infinite values")
    if (depth < 0).any():
        raise DataError(path, f"depth holds negative values (min {depth.min():g})")
    return depth


def read_tool_mask(path: Path) -> np.ndarray:
    """A tool mask file as bool [H, W], True = tool (stored as 255; any value > 127 is tool)."""
    raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if raw is None:
        raise DataError(path, "cannot be read as a mask image (missing or corrupt)")
    if raw.ndim == 3:
        raw = raw[..., 0]
    threshold = TOOL_VALUE // 2 if raw.dtype == np.uint8 else raw.max(initial=0) // 2
    return raw > threshold


def read_poses_bounds(path: Path) -> np.ndarray:
    """poses_bounds.npy as float64 [N, 17]."""
    if not path.is_file():
        raise DataError(path, "missing: expected an LLFF poses_bounds.npy array of shape [N, 17]")
    try:
        poses = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise DataError(path, f"cannot be read as a .npy array ({err})") from err
    if poses.ndim != 2 or poses.shape[1] != 17 or poses.shape[0] == 0:
        raise DataError(path, f"expected shape [N, 17] (LLFF 3x5 pose block + near, far), "
                              f"got {poses.shape}")
    if not np.isfinite(poses).all():
        raise DataError(path, "holds NaN or infinite values")
    return poses.astype(np.float64)


def camera_from_poses(poses: np.ndarray, path: Path, height: int, width: int) -> Camera:
    """The camera from the hwf column; every frame must have the same camera and pose."""
    blocks = poses[:, :15].reshape(-1, 3, 5)
    hwf = blocks[:, :, 4]
    if not np.allclose(hwf, hwf[0]):
        raise DataError(path, "frames have different (H, W, focal); surgsplat expects one camera")
    file_h, file_w, focal = hwf[0]
    if (int(round(file_h)), int(round(file_w))) != (height, width):
        raise DataError(path, f"says images are {int(file_h)}x{int(file_w)} (HxW) but "
                              f"{IMAGES_DIR}/ holds {height}x{width}")
    if focal <= 0:
        raise DataError(path, f"focal length must be positive, got {focal:g}")
    if not np.allclose(blocks[:, :, :4], blocks[0, :, :4]):
        raise DataError(path, "camera poses change over time; surgsplat expects a static camera")
    K = torch.tensor([[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]],
                     dtype=torch.float32)
    # A static camera defines the world frame: world coordinates are camera coordinates.
    return Camera(K=K, world_to_camera=torch.eye(4), width=width, height=height)


def _folder_files(root: Path, name: str, suffixes: tuple[str, ...], required: bool) -> list[Path]:
    folder = root / name
    if not folder.is_dir():
        if required:
            raise DataError(folder, f"missing: expected a folder of frames ({', '.join(suffixes)})")
        return []
    files = list_files(folder, suffixes)
    if required and not files:
        raise DataError(folder, f"holds no frame files ({', '.join(suffixes)})")
    return files


def load_scene(root: str | Path, depth_scale: float | None = None) -> Scene:
    """Load and validate a scene folder.

    depth_scale: scene units per stored integer of PNG/TIFF depth files; overrides scene.json
    (whose default is 1.0, e.g. EndoNeRF's own 8-bit depth maps).
    """
    root = Path(root)
    if not root.is_dir():
        raise DataError(root, "is not a folder: expected an EndoNeRF-layout scene "
                              f"({IMAGES_DIR}/, optional {DEPTH_DIR}/ and {MASKS_DIR}/, {POSES_FILE})")
    meta = SceneMeta.read(root / META_FILE) if (root / META_FILE).is_file() else SceneMeta()
    if depth_scale is not None:
        if depth_scale <= 0:
            raise DataError(root, f"depth scale must be positive, got {depth_scale:g}")
        meta.depth_scale = depth_scale
    image_files = _folder_files(root, IMAGES_DIR, IMAGE_SUFFIXES, required=True)
    depth_files = _folder_files(root, DEPTH_DIR, DEPTH_SUFFIXES, required=False)
    mask_files = _folder_files(root, MASKS_DIR, IMAGE_SUFFIXES, required=False)
    poses_path = root / POSES_FILE
    poses = read_poses_bounds(poses_path)

    count = len(image_files)
    for name, files in ((DEPTH_DIR, depth_files), (MASKS_DIR, mask_files)):
        if files and len(files) != count:
            raise DataError(root / name, f"holds {len(files)} files but {IMAGES_DIR}/ holds {count}")
    if len(poses) != count:
        raise DataError(poses_path, f"has {len(poses)} rows but {IMAGES_DIR}/ holds {count} frames")

    frames = []
    size: tuple[int, int] | None = None
    for index, image_path in enumerate(image_files):
        image = read_image(image_path)
        size = size or image.shape[:2]
        _check_size(image_path, image.shape[:2], size)
        depth = None
        if depth_files:
            depth_np = read_depth(depth_files[index], meta.depth_scale)
            _check_size(depth_files[index], depth_np.shape, size)
            depth = torch.from_numpy(depth_np)
        tissue = torch.ones(size, dtype=torch.bool)
        if mask_files:
            tool = read_tool_mask(mask_files[index])
            _check_size(mask_files[index], tool.shape, size)
            if tool.all():
                raise DataError(mask_files[index], "marks every pixel as tool: no tissue is visible")
            tissue = torch.from_numpy(~tool)
        frames.append(Frame(index=index, time=index / count,
                            image=torch.from_numpy(image).float().div_(255.0), depth=depth,
                            tissue=tissue, is_test=is_test_index(index)))
    height, width = size
    camera = camera_from_poses(poses, poses_path, height, width)
    near, far = (float(v) for v in poses[0, 15:17])
    return Scene(root=root, frames=frames, camera=camera, meta=meta, near=near, far=far,
                 has_depth=bool(depth_files), has_masks=bool(mask_files))


def _check_size(path: Path, shape: tuple[int, ...], expected: tuple[int, int]) -> None:
    if tuple(shape[:2]) != tuple(expected):
        raise DataError(path, f"is {shape[0]}x{shape[1]} (HxW) but the first image is "
                              f"{expected[0]}x{expected[1]}")
