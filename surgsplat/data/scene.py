"""Load and validate an EndoNeRF-layout scene folder (see `surgsplat.data.layout`).

Every problem with the files is reported as a DataError naming the file and what was expected,
before any training starts. Each frame carries its own camera (intrinsics from scene.json or
the hwf column, pose from poses_bounds.npy converted from LLFF to OpenCV world-to-camera) and
its tool and field-of-view masks.
"""

from __future__ import annotations

import hashlib
import math
import os
import sys
import tempfile
import threading
import warnings
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import closing, contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import tifffile
import torch
from PIL import Image, ImageFile
from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)
from torch import Tensor

from surgsplat.data.frame_store import CACHE_BYTES, FramePixels, FrameStore
from surgsplat.data.image_files import check_image_file
from surgsplat.data.layout import (DEPTH_DIR, DEPTH_SUFFIXES, FOV_FILE, IMAGE_SUFFIXES,
                                   IMAGES_DIR, INSIDE_VALUE, MASKS_DIR, MAX_DEPTH_MM, META_FILE,
                                   POSES_FILE, Intrinsics, SceneMeta, list_files, max_depth,
                                   not_a_file_problem, world_to_camera_from_llff)
from surgsplat.errors import DataError, SurgsplatError

TEST_EVERY = 8
"""Test frames are those with index % TEST_EVERY == TEST_OFFSET (the EndoNeRF-family split)."""
TEST_OFFSET = 1
ROTATION_TOLERANCE = 1e-3
"""Largest |R^T R - I| entry of a pose's rotation block accepted as a rotation."""
FOCAL_TOLERANCE = 1e-3
"""Largest relative difference between the hwf focal and scene.json's fx."""
MIN_SIZE = 16
"""Smallest frame width and height accepted, pixels (one 16x16 rasterisation tile)."""
DECODE_AHEAD = 4
"""Frames per thread that load_scene decodes ahead of the one it fingerprints."""


@dataclass(frozen=True)
class Camera:
    """A pinhole camera in OpenCV convention (x right, y down, z forward); pixel (u, v) has its
    centre at (u + 0.5, v + 0.5)."""

    K: Tensor  # [3, 3] float32 intrinsics in pixels: [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    world_to_camera: Tensor  # [4, 4] float32 rigid transform; identity for a static scene
    width: int
    height: int

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def focal(self) -> float:
        """fx (the focal length of square-pixel cameras)."""
        return self.fx

    @property
    def camera_to_world(self) -> Tensor:
        """[4, 4] float32 inverse of world_to_camera ([R^T | -R^T t], computed in float64)."""
        world_to_camera = self.world_to_camera.double()
        rotation_t = world_to_camera[:3, :3].T
        inverse = torch.eye(4, dtype=torch.float64)
        inverse[:3, :3] = rotation_t
        inverse[:3, 3] = -rotation_t @ world_to_camera[:3, 3]
        return inverse.float()


class Frame:
    """One video frame with what is known about it.

    Its pixels (image, depth, tool, tissue) are either held, when given to the constructor, or,
    for the frames of a loaded scene, decoded from the scene's files when first used and kept in
    the scene's bounded FrameStore cache (see `surgsplat.data.frame_store`), so that a clip of
    any length fits in memory. Either way the properties below give the same tensors.
    """

    __slots__ = ("index", "time", "is_test", "camera", "_held", "_store")

    def __init__(self, index: int, time: float, image: Tensor, depth: Tensor | None,
                 is_test: bool, camera: Camera, tool: Tensor, fov: Tensor):
        self.index = index
        self.time = time  # index / number of frames, in [0, 1)
        self.is_test = is_test
        self.camera = camera  # this frame's camera
        self._held: FramePixels | None = FramePixels(image=image, depth=depth, tool=tool, fov=fov)
        self._store: FrameStore | None = None

    @classmethod
    def stored(cls, index: int, time: float, is_test: bool, camera: Camera,
               store: FrameStore) -> "Frame":
        """A frame whose pixels are `store`'s entry `index`, decoded when first used."""
        frame = cls.__new__(cls)
        frame.index, frame.time, frame.is_test, frame.camera = index, time, is_test, camera
        frame._held, frame._store = None, store
        return frame

    @property
    def pixels(self) -> FramePixels:
        """Every pixel array of this frame (decoded now unless held or cached)."""
        return self._held if self._held is not None else self._store.get(self.index)

    @property
    def image(self) -> Tensor:  # [H, W, 3] float32 RGB in [0, 1]
        return self.pixels.image

    @property
    def depth(self) -> Tensor | None:  # [H, W] float32 in the scene's depth unit; 0 = no depth
        return self.pixels.depth

    @property
    def tool(self) -> Tensor:  # [H, W] bool, True = tool
        return self.pixels.tool

    @property
    def fov(self) -> Tensor:  # [H, W] bool, True = inside the field of view
        return self.pixels.fov

    @property
    def tissue(self) -> Tensor:  # [H, W] bool, True = tissue = fov & ~tool
        return self.pixels.tissue

    def with_tool(self, tool: Tensor) -> "Frame":
        """This frame with its tool mask ([H, W] bool) replaced; the new frame holds its
        pixels."""
        return Frame(self.index, self.time, self.image, self.depth, self.is_test, self.camera,
                     tool, self.fov)

    def seen_by(self, camera: Camera) -> "Frame":
        """This frame (the same pixels, held or stored) seen by `camera` instead of its own, e.g.
        with a pose that training refined."""
        frame = Frame.__new__(Frame)
        frame.index, frame.time, frame.is_test, frame.camera = (self.index, self.time,
                                                                self.is_test, camera)
        frame._held, frame._store = self._held, self._store
        return frame

    def downscaled(self, factor: int) -> "Frame":
        """This frame at 1/`factor` of its size in each direction (the frame itself for 1): each
        pixel is a `factor` x `factor` block of this one's (a remainder row or column dropped).
        Colour is the block's mean; depth the mean of the block's pixels with depth (0 where
        none has); a block is tool when any of its pixels is, inside the field of view when all
        are, so that no tool pixel is ever counted as tissue. The camera sees the same view: its
        focal lengths and principal point are divided by `factor` (pixel centres stay at
        +0.5). The new frame holds its pixels."""
        if factor == 1:
            return self
        if factor < 1:
            raise ValueError(f"a downscale factor is an integer >= 1, got {factor}")
        height, width = self.camera.height // factor, self.camera.width // factor
        if min(height, width) < MIN_SIZE:
            raise SurgsplatError(f"frame {self.index} at 1/{factor} size would be {width}x"
                                 f"{height}, under the {MIN_SIZE}x{MIN_SIZE} minimum")

        def blocks(plane: Tensor) -> Tensor:  # [H, W, ...] -> [h, w, ..., factor * factor]
            cropped = plane[:height * factor, :width * factor]
            split = cropped.reshape(height, factor, width, factor, *plane.shape[2:])
            return split.movedim(1, -1).movedim(2, -1).flatten(-2)

        image = blocks(self.image).mean(dim=-1)
        depth = None
        if self.depth is not None:
            depth_blocks = blocks(self.depth)
            valid = (depth_blocks > 0).sum(dim=-1)
            depth = depth_blocks.clamp_min(0).sum(dim=-1) / valid.clamp_min(1)
        scale = torch.tensor([1.0 / factor, 1.0 / factor, 1.0], dtype=self.camera.K.dtype)
        camera = Camera(K=self.camera.K * scale[:, None], world_to_camera=self.camera.world_to_camera,
                        width=width, height=height)
        return Frame(self.index, self.time, image.contiguous(), depth, self.is_test, camera,
                     blocks(self.tool).any(dim=-1), blocks(self.fov).all(dim=-1))

    def prefetch(self) -> None:
        """Say that this frame is needed soon: its files start decoding in the background
        (nothing to do for a frame whose pixels are held or cached)."""
        if self._store is not None:
            self._store.prefetch(self.index)


@dataclass(frozen=True)
class Scene:
    """A loaded scene: frames with their cameras, and what its depth means."""

    root: Path
    frames: list[Frame]
    meta: SceneMeta
    near: float
    far: float
    has_depth: bool
    has_masks: bool  # tool masks (masks/) present
    has_fov: bool  # a field-of-view mask (fov_mask.png) present
    fingerprint: str = ""  # hex digest of the decoded content (see load_scene); "" = not known

    @property
    def camera(self) -> Camera:
        """Frame 0's camera; for a static scene every frame's."""
        return self.frames[0].camera

    @property
    def width(self) -> int:
        return self.camera.width

    @property
    def height(self) -> int:
        return self.camera.height

    @property
    def has_moving_camera(self) -> bool:
        """Whether any frame's pose differs from frame 0's."""
        first = self.camera.world_to_camera
        return any(not torch.equal(f.camera.world_to_camera, first) for f in self.frames[1:])

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


_STDERR_LOCK = threading.Lock()
"""One redirection of file descriptor 2 at a time (frames decode on several threads)."""
_WHOLE_PROCESS_CAPTURE = threading.Event()
"""Set while `native_stderr_of_every_thread` collects what every thread's decoders print."""


@contextmanager
def native_stderr_to(sink: list[str]) -> Iterator[None]:
    """Collect what native libraries (libpng, libjpeg, libtiff inside OpenCV) print to the
    process's stderr during the block into `sink`, instead of letting it reach the user
    without a file name. Inside `native_stderr_of_every_thread` it collects nothing: that
    block's sink receives the text."""
    if _WHOLE_PROCESS_CAPTURE.is_set():
        yield
        return
    with _STDERR_LOCK:
        yield from _redirected_stderr(sink)


@contextmanager
def native_stderr_of_every_thread(sink: list[str]) -> Iterator[None]:
    """Collect what native libraries print during the block, on any thread, into `sink`: one
    redirection for many files decoded in parallel (per-file redirections would take turns)."""
    with _STDERR_LOCK:
        _WHOLE_PROCESS_CAPTURE.set()
        try:
            yield from _redirected_stderr(sink)
        finally:
            _WHOLE_PROCESS_CAPTURE.clear()


def _redirected_stderr(sink: list[str]) -> Iterator[None]:
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            text = capture.read().decode(errors="replace").strip()
            if text:
                sink.append(text)


def verify_image_file(path: Path, what: str) -> None:
    """Decode the whole of an image file strictly (Pillow with truncated images refused; a TIFF
    by tifffile, or by Pillow when its compression needs a codec tifffile lacks, such as the
    LZW that OpenCV writes): DataError naming the file when it is missing, truncated or
    corrupt, so no partly decoded (grey-filled) frame is ever used."""
    if not path.is_file():
        raise DataError(path, f"missing: expected {what}")
    if path.stat().st_size == 0:
        raise DataError(path, f"is empty (0 bytes): expected {what}")
    problem = "truncated or corrupt"
    try:
        if path.suffix.lower() not in (".tif", ".tiff"):
            _decode_with_pillow(path)
            return
        missing_codec = _tiff_codec_missing(path)
        if missing_codec is None:
            tifffile.imread(path)
            return
        problem = (f"its {missing_codec} compression needs the imagecodecs package for "
                   "tifffile, and Pillow failed on it too")
        _decode_with_pillow(path)
    except (OSError, SyntaxError, ValueError, EOFError, Image.DecompressionBombError) as err:
        raise DataError(path, f"cannot be read as {what}: {problem} ({err})") from None


def _tiff_codec_missing(path: Path) -> str | None:
    """The name of the first compression of a TIFF file that tifffile cannot decode here (it
    needs the imagecodecs package for LZW, JPEG and others), None when it can decode them all;
    a ValueError for a file that is no TIFF."""
    with tifffile.TiffFile(path) as tiff:
        for page in tiff.pages:
            if page.compression not in tifffile.TIFF.DECOMPRESSORS:
                return page.compression.name
    return None


def _decode_with_pillow(path: Path) -> None:
    """Decode the whole of an image file with Pillow, truncated images refused; what its
    native decoders print is dropped (a fault raises)."""
    ImageFile.LOAD_TRUNCATED_IMAGES = False
    with warnings.catch_warnings(), native_stderr_to([]):
        warnings.simplefilter("ignore")  # decoder notes; any real fault raises
        with Image.open(path) as image:
            image.load()


def decode_image(path: Path, what: str) -> np.ndarray:
    """An image file's pixels as cv2.imread(IMREAD_UNCHANGED) gives them (BGR order, uint8 or
    uint16, 2 or 3 dimensions). A PNG or JPEG is first checked whole by its header and end
    marker (`check_image_file`), other formats by a strict full decode (verify_image_file), so
    no partly decoded (grey-filled) frame is ever used; what the native decoders print is
    passed on as a warning that names the file."""
    if check_image_file(path, what) is None:
        verify_image_file(path, what)
    printed: list[str] = []
    with native_stderr_to(printed):
        raw = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if printed:
        warnings.warn(f"{path}: {' '.join(printed)}", stacklevel=2)
    if raw is None:
        raise DataError(path, f"cannot be read as {what} (corrupt or unknown format)")
    return raw


def read_npy(path: Path) -> np.ndarray:
    """A .npy array (no pickles); DataError naming the file when it is missing, empty,
    truncated or not a .npy file."""
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as err:
        raise DataError(path, f"cannot be read as a .npy array ({err or type(err).__name__})") \
            from None


def read_image(path: Path) -> np.ndarray:
    """An image file as uint8 RGB [H, W, 3]; 16-bit images are reduced to 8 bits."""
    raw = decode_image(path, "an image")
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


def read_depth(path: Path, depth_scale: float, limit: float = MAX_DEPTH_MM) -> np.ndarray:
    """A depth file as float32 [H, W] in scene units (stored integers x depth_scale for images);
    DataError naming the file unless every value is finite and in [0, limit] (`max_depth` of
    the scene's unit; 0 = no depth)."""
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            depth = read_npy(path)
        elif suffix == ".npz":
            with np.load(path, allow_pickle=False) as archive:
                if len(archive.files) != 1:
                    raise DataError(path, f"expected one array in the .npz, found {archive.files}")
                depth = archive[archive.files[0]]
        else:
            depth = decode_image(path, "a depth image")
            if depth.dtype in (np.uint8, np.uint16):
                depth = depth.astype(np.float32) * depth_scale
    except (OSError, ValueError, EOFError) as err:
        raise DataError(path, f"cannot be read as a depth array ({err or type(err).__name__})") \
            from err
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
    if (depth > limit).any():
        stored = ("" if suffix in (".npy", ".npz") else
                  " (image depth is the stored integer x depth_scale of scene.json)")
        raise DataError(path, f"depth reaches {depth.max():g}, beyond {limit:g}, "
                              f"{MAX_DEPTH_MM / 1000:g} m in the scene's depth unit, more than "
                              f"an endoscope sees: a unit or scale error?{stored}")
    return depth


CLASS_ID_HINT = ("; class-ID masks are imported with their tool classes: surgsplat import "
                 "--masks DIR --tool-labels IDS")
"""What to do with class-ID masks where binary ones were expected."""


def read_tool_mask(path: Path, tool_labels: tuple[int, ...] | None = None,
                   lossy: bool = False) -> np.ndarray:
    """A tool mask file as bool [H, W], True = tool: the one reader of tool masks, for the
    label images `import` is given and for a scene's masks/ alike.

    tool_labels None: a binary mask (`read_binary_mask`, with `lossy`; a scene's masks/ store
    TOOL_VALUE = tool). Otherwise a class-ID mask, one integer class per pixel in one channel
    or in three equal ones, whose pixels in `tool_labels` are tool."""
    if tool_labels is None:
        return read_binary_mask(path, "a tool mask", CLASS_ID_HINT, lossy)
    raw = decode_image(path, "a class-ID mask")
    if raw.ndim == 3:
        raw = raw[..., :3]
        if not (raw == raw[..., :1]).all():
            raise DataError(path, "has differing colour channels, but class-ID masks hold one ID "
                                  "per pixel (one channel or three equal ones); is this a "
                                  "colour-coded mask? choose the ID masks with --mask-pattern")
        raw = raw[..., 0]
    return np.isin(raw, np.asarray(tool_labels))


def read_fov_mask(path: Path) -> np.ndarray:
    """fov_mask.png as bool [H, W], True = inside the field of view (`read_binary_mask`;
    surgsplat stores 255 = inside)."""
    inside = read_binary_mask(path, "a field-of-view mask")
    if not inside.any():
        raise DataError(path, f"marks no pixel as inside the field of view (expected "
                              f"{INSIDE_VALUE} = inside, 0 = outside)")
    return inside


def read_binary_mask(path: Path, what: str, hint: str = "", lossy: bool = False) -> np.ndarray:
    """A binary mask file as bool [H, W], True where it is on: 0 is off and one other value
    on, 8- or 16-bit, in one channel or several, where each pixel's brightest colour channel
    counts (so white, red or any colour on black reads alike; alpha is ignored). DataError
    naming the file, with `hint` appended, when it holds more values or two that are not 0.
    lossy: a mask saved lossily or anti-aliased (JPEG, a resized PNG), whatever its values:
    on above half its brightest value (a scene's own masks/, read as they always were)."""
    raw = decode_image(path, what)
    values = raw[..., :3].max(axis=2) if raw.ndim == 3 else raw  # [H, W]
    if lossy:
        return values.astype(np.float32) > values.max() / 2.0 if values.any() else values > 0
    distinct = (np.flatnonzero(np.bincount(values.ravel(), minlength=256))
                if values.dtype == np.uint8 else np.unique(values))
    if distinct.size > 2 or (distinct.size == 2 and distinct[0] != 0):
        shown = ", ".join(str(v) for v in distinct[:8]) + (", ..." if distinct.size > 8 else "")
        raise DataError(path, f"holds the values {shown}, but {what} is binary: 0 and one "
                              f"other value (saved losslessly, e.g. PNG){hint}")
    return values > 0


def read_poses_bounds(path: Path) -> np.ndarray:
    """poses_bounds.npy as float64 [N, 17]."""
    if not path.is_file():
        raise DataError(path, "missing: expected an LLFF poses_bounds.npy array of shape [N, 17]")
    poses = read_npy(path)
    if poses.ndim != 2 or poses.shape[1] != 17 or poses.shape[0] == 0:
        raise DataError(path, f"expected shape [N, 17] (LLFF 3x5 pose block + near, far), "
                              f"got {poses.shape}")
    if not np.isfinite(poses).all():
        raise DataError(path, "holds NaN or infinite values")
    return poses.astype(np.float64)


def cameras_from_poses(poses: np.ndarray, path: Path, height: int, width: int,
                       intrinsics: Intrinsics | None, meta_path: Path) -> list[Camera]:
    """One camera per row of poses_bounds [N, 17]: the intrinsics (or the hwf focal with a
    centred principal point), and the LLFF pose converted to OpenCV world-to-camera.

    Frames with equal poses share one Camera object.
    """
    blocks = poses[:, :15].reshape(-1, 3, 5)
    hwf = blocks[:, :, 4]
    if not np.allclose(hwf, hwf[0]):
        raise DataError(path, "frames have different (H, W, focal); surgsplat expects one "
                              "set of intrinsics for all frames")
    file_h, file_w, focal = hwf[0]
    if (int(round(file_h)), int(round(file_w))) != (height, width):
        raise DataError(path, f"says images are {int(file_h)}x{int(file_w)} (HxW) but "
                              f"{IMAGES_DIR}/ holds {height}x{width}")
    if focal <= 0:
        raise DataError(path, f"focal length must be positive, got {focal:g}")
    if intrinsics is None:
        intrinsics = Intrinsics.centred(focal, width, height)
    else:
        try:
            intrinsics.check(width, height)
        except ValueError as err:
            raise DataError(meta_path, f"intrinsics: {err}") from None
        if not math.isclose(focal, intrinsics.fx, rel_tol=FOCAL_TOLERANCE):
            raise DataError(path, f"hwf focal {focal:g} px disagrees with fx "
                                  f"{intrinsics.fx:g} px of {meta_path.name}; expected equal")
    _check_rotations(blocks[:, :, :3], path)
    K = torch.tensor(intrinsics.matrix(), dtype=torch.float32)
    world_to_camera = torch.from_numpy(world_to_camera_from_llff(blocks[:, :, :4])).float()
    cameras: list[Camera] = []
    for pose in world_to_camera:
        if cameras and torch.equal(pose, cameras[-1].world_to_camera):
            cameras.append(cameras[-1])
        else:
            cameras.append(Camera(K=K, world_to_camera=pose, width=width, height=height))
    return cameras


def _check_rotations(rotations: np.ndarray, path: Path) -> None:
    """DataError unless every [3, 3] of rotations [N, 3, 3] is a rotation (within tolerance)."""
    deviation = np.abs(rotations.transpose(0, 2, 1) @ rotations - np.eye(3)).max(axis=(1, 2))
    determinant = np.linalg.det(rotations)
    bad = np.flatnonzero((deviation > ROTATION_TOLERANCE) | (determinant <= 0))
    if len(bad):
        row = int(bad[0])
        raise DataError(path, f"row {row}: the 3x3 pose block is not a rotation (|R^T R - I| "
                              f"up to {deviation[row]:.3g}, det {determinant[row]:.3g}); "
                              "expected an LLFF camera-to-world rotation with columns [down, "
                              "right, backwards]")


def _folder_files(root: Path, name: str, suffixes: tuple[str, ...], required: bool) -> list[Path]:
    """The frame files of the scene's folder `name` (`list_files`); [] for an optional folder
    that is absent."""
    folder = root / name
    expected = f"a folder of frames ({', '.join(suffixes)})"
    if not _present(folder, True, expected):
        if required:
            raise DataError(folder, f"missing: expected {expected}")
        return []
    files = list_files(folder, suffixes)
    if required and not files:
        raise DataError(folder, f"holds no frame files ({', '.join(suffixes)})")
    return files


def _present(path: Path, folder: bool, expected: str) -> bool:
    """Whether the scene's entry `path` is there, as a folder when `folder`, else as a file;
    False when nothing is. Anything else in its place (a file where a folder belongs, a folder
    where a file belongs, a broken symbolic link, a pipe) is a DataError naming it and what
    was `expected`, never read as absent."""
    if not os.path.lexists(path):
        return False
    if path.is_dir() if folder else path.is_file():
        return True
    found = ("is a folder" if path.is_dir() else "is a file" if path.is_file()
             else not_a_file_problem(path))
    raise DataError(path, f"{found}: expected {expected}")


@dataclass(frozen=True)
class FrameFiles:
    """The files of one frame and how to read them."""

    image: Path
    depth: Path | None  # None: the scene has no depth/
    mask: Path | None  # None: the scene has no masks/
    depth_scale: float  # scene units per stored integer of PNG/TIFF depth
    depth_limit: float  # largest depth accepted, scene units (`max_depth` of the scene's unit)
    size: tuple[int, int]  # (H, W) of the scene's first image

    def named(self) -> list[tuple[Path, str]]:
        """(file, what it should hold) of each of the frame's files."""
        named = [(self.image, "an image"), (self.depth, "a depth map"),
                 (self.mask, "a mask image")]
        return [(path, what) for path, what in named if path is not None]


def read_frame_files(files: FrameFiles, fov: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """A frame's files decoded and checked: uint8 RGB [H, W, 3], float32 depth [H, W] (None
    without depth) and bool tool mask [H, W] (None without masks); `fov` is the scene's
    field-of-view mask (None without fov_mask.png). DataError naming the file when one is
    unreadable, of another size, or leaves no tissue visible."""
    image = read_image(files.image)
    _check_size(files.image, image.shape[:2], files.size)
    depth = None
    if files.depth is not None:
        depth = read_depth(files.depth, files.depth_scale, files.depth_limit)
        _check_size(files.depth, depth.shape, files.size)
    tool = None
    if files.mask is not None:
        tool = read_tool_mask(files.mask, lossy=True)
        _check_size(files.mask, tool.shape, files.size)
        check_tissue_visible(tool, fov, files.mask)
    return image, depth, tool


def check_tissue_visible(tool: np.ndarray, fov: np.ndarray | None, source: Path,
                         hint: str = "") -> None:
    """DataError naming `source` (the mask file, or the model that made the mask) when the tool
    mask `tool` (bool [H, W]) leaves no tissue pixel inside the field of view `fov` (bool
    [H, W], None = every pixel); `hint` is appended to the message."""
    if tool.all():
        raise DataError(source, f"marks every pixel as tool: no tissue is visible{hint}")
    if fov is not None and not (fov & ~tool).any():
        raise DataError(source, f"marks every pixel inside the field of view ({FOV_FILE}) as "
                                f"tool: no tissue is visible{hint}")


def check_frame_headers(files: list[FrameFiles]) -> None:
    """Every PNG and JPEG file of the frames checked without decoding (`check_image_file`:
    present, not empty, not cut short) and its header's size compared with the first image's;
    DataError naming the first bad file. Other formats are checked when decoded."""
    for frame_files in files:
        for path, what in frame_files.named():
            header = check_image_file(path, what)
            if header is not None:
                _check_size(path, (header.height, header.width), frame_files.size)


def decoded_frames(root: Path, files: list[FrameFiles], fov: np.ndarray | None
                   ) -> Iterator[tuple[np.ndarray, np.ndarray | None, np.ndarray | None]]:
    """read_frame_files of every frame, in frame order, decoded on `torch.get_num_threads()`
    threads with a progress bar; the first bad file's DataError stops the decoding. What the
    native decoders print meanwhile becomes one warning naming the scene folder."""
    printed: list[str] = []
    with native_stderr_of_every_thread(printed), validation_progress(len(files)) as advance:
        yield from _in_parallel(lambda frame_files: read_frame_files(frame_files, fov), files,
                                advance)
    if printed:
        lines = dict.fromkeys(line for text in printed for line in text.splitlines())
        warnings.warn(f"{root}: the image decoders said, while its frames were checked: "
                      f"{' '.join(lines)}", stacklevel=3)


def _in_parallel(work: Callable, items: list, done: Callable[[], None]) -> Iterator:
    """work(item) of every item, in order, computed on `torch.get_num_threads()` threads at
    most DECODE_AHEAD items ahead of the consumer; done() after each. An exception of one item
    is raised when its turn comes, and the items after it are dropped."""
    workers = max(1, torch.get_num_threads())
    pending: deque[Future] = deque()
    with ThreadPoolExecutor(workers, thread_name_prefix="scene-check") as pool:
        try:
            for item in items:
                pending.append(pool.submit(work, item))
                if len(pending) >= DECODE_AHEAD * workers:
                    yield pending.popleft().result()
                    done()
            while pending:
                yield pending.popleft().result()
                done()
        finally:
            for future in pending:
                future.cancel()


@contextmanager
def validation_progress(total: int) -> Iterator[Callable[[], None]]:
    """A transient progress bar of the frames checked, on an interactive console only; yields
    the function that counts one more frame."""
    console = Console(stderr=False)
    with Progress(TextColumn("[bold]checking frames"), BarColumn(), MofNCompleteColumn(),
                  TimeElapsedColumn(), TimeRemainingColumn(), console=console, transient=True,
                  disable=not console.is_terminal) as bar:
        task = bar.add_task("checking frames", total=total)
        yield lambda: bar.advance(task)


def frame_pixels(image: np.ndarray, depth: np.ndarray | None, tool: np.ndarray | None,
                 fov: Tensor) -> FramePixels:
    """The tensors of a frame from what read_frame_files gave (fov: [H, W] bool, shared)."""
    return FramePixels(image=torch.from_numpy(image).float().div_(255.0),
                       depth=None if depth is None else torch.from_numpy(depth),
                       tool=torch.zeros(fov.shape, dtype=torch.bool) if tool is None
                       else torch.from_numpy(tool), fov=fov)


def check_depth_scale(depth_scale: float, name: str) -> None:
    """SurgsplatError saying that `name` (the option or setting given) must be a positive finite
    number, unless `depth_scale` is one."""
    if not (isinstance(depth_scale, (int, float)) and math.isfinite(depth_scale)
            and depth_scale > 0):
        raise SurgsplatError(f"{name} must be a positive finite number (scene units per stored "
                             f"integer of PNG depth), got {depth_scale!r}")


def load_scene(root: str | Path, depth_scale: float | None = None,
               cache_bytes: int = CACHE_BYTES) -> Scene:
    """Load and validate a scene folder.

    Every file's header, size and end marker are checked first (seconds for a long clip), then
    every frame is decoded and checked on `torch.get_num_threads()` threads with a progress
    bar, so that a bad file stops the load with a DataError naming it before any training; the
    frames then decode again from their files when used, through a cache of at most
    `cache_bytes` (whole clips that fit stay cached from this first pass), so memory does not
    grow with the clip's length.

    The scene's fingerprint is a BLAKE2b digest of what was decoded: the poses, the camera
    matrix and every frame's 8-bit image, depth and masks, so a run can tell its own scene from
    another one (moved or re-encoded copies included) without keeping the frames.

    depth_scale: scene units per stored integer of PNG/TIFF depth files; overrides scene.json
    (whose default is 1.0, e.g. EndoNeRF's own 8-bit depth maps).
    """
    root = Path(root)
    if not root.is_dir():
        raise DataError(root, "is not a folder: expected an EndoNeRF-layout scene "
                              f"({IMAGES_DIR}/, optional {DEPTH_DIR}/ and {MASKS_DIR}/, {POSES_FILE})")
    meta = (SceneMeta.read(root / META_FILE)
            if _present(root / META_FILE, False, "the scene's metadata (JSON)") else SceneMeta())
    if depth_scale is not None:
        check_depth_scale(depth_scale, "depth scale")
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

    first_image = read_image(image_files[0])
    size = first_image.shape[:2]
    height, width = size
    if min(height, width) < MIN_SIZE:
        raise DataError(image_files[0], f"is {height}x{width} (HxW); surgsplat needs frames of "
                                        f"at least {MIN_SIZE}x{MIN_SIZE} pixels")
    cameras = cameras_from_poses(poses, poses_path, height, width, meta.intrinsics,
                                 root / META_FILE)
    digest = hashlib.blake2b(poses.tobytes(), digest_size=16)
    digest.update(cameras[0].K.numpy().tobytes())
    fov_path = root / FOV_FILE
    has_fov = _present(fov_path, False, "the field-of-view mask image")
    fov_np = None
    fov = torch.ones(size, dtype=torch.bool)  # shared by every frame
    if has_fov:
        fov_np = read_fov_mask(fov_path)
        _check_size(fov_path, fov_np.shape, size)
        fov = torch.from_numpy(fov_np)
        digest.update(fov_np.tobytes())

    files = [FrameFiles(image=image_path, depth=depth_files[index] if depth_files else None,
                        mask=mask_files[index] if mask_files else None,
                        depth_scale=meta.depth_scale,
                        depth_limit=max_depth(meta.depth_unit), size=size)
             for index, image_path in enumerate(image_files)]
    check_frame_headers(files)
    store = FrameStore(lambda index: frame_pixels(*read_frame_files(files[index], fov_np), fov),
                       cache_bytes)
    frames = []
    with closing(decoded_frames(root, files, fov_np)) as decoded:
        for index, arrays in enumerate(decoded):
            for array in arrays:
                if array is not None:
                    digest.update(array.tobytes())
            store.put(index, frame_pixels(*arrays, fov))
            frames.append(Frame.stored(index=index, time=index / count,
                                       is_test=is_test_index(index), camera=cameras[index],
                                       store=store))
    near, far = (float(v) for v in poses[0, 15:17])
    return Scene(root=root, frames=frames, meta=meta, near=near, far=far,
                 has_depth=bool(depth_files), has_masks=bool(mask_files), has_fov=has_fov,
                 fingerprint=digest.hexdigest())


def _check_size(path: Path, shape: tuple[int, ...], expected: tuple[int, int]) -> None:
    if tuple(shape[:2]) != tuple(expected):
        raise DataError(path, f"is {shape[0]}x{shape[1]} (HxW) but the first image is "
                              f"{expected[0]}x{expected[1]}")
