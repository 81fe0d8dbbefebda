"""Frames that arrive over time, as from a camera: a video file played at its frame rate, a
folder that frames are being written into, or a camera device.

A source yields `ArrivedFrame`s in order (until its end, or until the `stop` event it is given
is set), each stamped with its arrival time
(`time.monotonic()`): when a played video's clock reaches it, when its file is found complete in
the folder, or when the camera delivered it. It never drops a frame: a consumer slower than the
source lets frames wait, and the wait shows as their lag.

A folder is either a folder of image files or a scene folder (`surgsplat.data.layout`) being
written: images/, and optionally depth/ and masks/ whose files of the same name are waited for
together with the image; its scene.json and poses_bounds.npy, when present, give the depth
scale, the camera and the poses. A frame that cannot be read is yielded as a `BadFrame` (an error
naming its file) in its place, and the source goes on with the next frame.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from surgsplat.data.image_files import check_image_file
from surgsplat.data.layout import (DEPTH_DIR, IMAGE_SUFFIXES, IMAGES_DIR, MASKS_DIR,
                                   MAX_DEPTH_MM, META_FILE, POSES_FILE, Intrinsics, SceneMeta,
                                   list_files, max_depth, world_to_camera_from_llff)
from surgsplat.data.scene import (MIN_SIZE, native_stderr_to, read_depth, read_image,
                                  read_poses_bounds, read_tool_mask)
from surgsplat.errors import DataError

ASSUMED_HFOV_DEG = 70.0
"""Horizontal field of view assumed for a video or camera whose focal length is not given."""
POLL_SECONDS = 0.02
"""How often a folder is listed for new files."""
SETTLE_SECONDS = 2.0
"""How long a folder's file may stay incomplete (no end marker, or its depth or mask missing)
before it counts as bad: a writer may be in the middle of it."""


class BadFrame(DataError):
    """One frame of the source cannot be read; the source can go on with the next one."""

    def __init__(self, path: str | Path, problem: str, index: int):
        super().__init__(path, problem)
        self.index = index

    def __reduce__(self):
        return type(self), (self.path, self.problem, self.index)


@dataclass
class ArrivedFrame:
    """One frame as it arrived."""

    index: int  # position in the stream, from 0
    arrival: float  # time.monotonic() when it became available
    image: np.ndarray  # uint8 RGB [H, W, 3]
    depth: np.ndarray | None = None  # float32 [H, W] in the source's depth unit; 0 = none
    tool: np.ndarray | None = None  # bool [H, W], True = tool; None = not given
    world_to_camera: np.ndarray | None = None  # [4, 4] OpenCV pose; None = the first's


@dataclass
class SourceCamera:
    """What a source knows of its camera and depth before its first frame."""

    intrinsics: Intrinsics | None  # None: assumed from the frame size (`camera_intrinsics`)
    depth_unit: str = "unknown"
    expected_frames: int | None = None  # how many frames it will send, when it says
    rate: float | None = None  # frames per second it plays at; None = as they come


def camera_intrinsics(known: Intrinsics | None, width: int, height: int,
                      focal: float | None = None) -> Intrinsics:
    """The intrinsics of `width` x `height` frames: `known`, else a centred camera of focal
    `focal`, else of ASSUMED_HFOV_DEG horizontal field of view."""
    if known is not None:
        return known
    if focal is None:
        focal = width / 2 / math.tan(math.radians(ASSUMED_HFOV_DEG) / 2)
    return Intrinsics.centred(focal, width, height)


Arrival = ArrivedFrame | BadFrame
"""What a source yields for each frame."""


class VideoStream:
    """A video file played as a camera: frame i arrives `i / rate` seconds after the first
    (the file's own frame rate unless `rate` is given)."""

    def __init__(self, path: Path, rate: float | None = None):
        self.path = path
        capture = cv2.VideoCapture(str(path))
        if not capture.isOpened():
            capture.release()
            raise DataError(path, "cannot be opened as a video (unknown format or corrupt)")
        own_rate = capture.get(cv2.CAP_PROP_FPS)
        count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        capture.release()
        if rate is None and not (own_rate > 0 and math.isfinite(own_rate)):
            raise DataError(path, "does not say its frame rate; pass --rate")
        self.camera = SourceCamera(None, expected_frames=count if count > 0 else None,
                                   rate=rate or own_rate)

    def frames(self, stop: threading.Event) -> Iterator[Arrival]:
        capture = cv2.VideoCapture(str(self.path))
        start = time.monotonic()
        index = 0
        try:
            while True:
                ok, bgr = capture.read()
                if not ok:
                    if self.camera.expected_frames and index < self.camera.expected_frames:
                        yield BadFrame(self.path, f"cannot decode frame {index} of "
                                                  f"{self.camera.expected_frames}; the video "
                                                  "ends there", index)
                    return
                due = start + index / self.camera.rate
                if stop.wait(max(due - time.monotonic(), 0.0)):
                    return
                yield ArrivedFrame(index, max(due, time.monotonic()),
                                   np.ascontiguousarray(bgr[..., ::-1]))
                index += 1
        finally:
            capture.release()


class CameraStream:
    """A camera device by its OpenCV index; frames arrive when it delivers them."""

    def __init__(self, device: int, first_frame_timeout: float):
        self.device = device
        printed: list[str] = []  # what OpenCV's back-ends print: the error below says it
        with native_stderr_to(printed):
            self.capture = cv2.VideoCapture(device)
        if not self.capture.isOpened():
            self.capture.release()
            raise DataError(Path(f"camera {device}"), "does not open (no such device, or in "
                                                      "use): expected an OpenCV camera index")
        rate = self.capture.get(cv2.CAP_PROP_FPS)
        self.camera = SourceCamera(None, rate=rate if rate > 0 else None)
        self.timeout = first_frame_timeout

    def frames(self, stop: threading.Event) -> Iterator[Arrival]:
        index = 0
        try:
            while not stop.is_set():
                ok, bgr = self.capture.read()
                if not ok:
                    if index == 0:
                        raise DataError(Path(f"camera {self.device}"), "opened but delivered "
                                                                       "no frame")
                    return
                yield ArrivedFrame(index, time.monotonic(),
                                   np.ascontiguousarray(bgr[..., ::-1]))
                index += 1
        finally:
            self.capture.release()


class FolderStream:
    """A folder that frames are written into (see the module docstring); it ends after the
    frames it expects (`frames`, else one per row of a scene folder's poses_bounds.npy), or when
    no new frame has come for `idle_timeout` seconds; it is an error when none came at all."""

    def __init__(self, root: Path, idle_timeout: float, frames: int | None = None):
        self.root = root
        self.idle_timeout = idle_timeout
        self.frames_given = frames
        self.camera = SourceCamera(None)
        self._read_layout()

    def _read_layout(self) -> None:
        """What the folder is, as it stands: a scene folder once it has images/ (its
        scene.json and poses_bounds.npy read then), else a folder of images; read again until
        the first frame comes, since a writer may create the scene's files after the stream
        starts."""
        root = self.root
        self.is_scene = (root / IMAGES_DIR).is_dir()
        self.images = root / IMAGES_DIR if self.is_scene else root
        meta = SceneMeta.read(root / META_FILE) if (root / META_FILE).is_file() else SceneMeta()
        self.depth_scale = meta.depth_scale
        self.depth_limit = max_depth(meta.depth_unit) if self.is_scene else MAX_DEPTH_MM
        self.poses: np.ndarray | None = None  # [N, 4, 4] world-to-camera, from poses_bounds
        intrinsics = meta.intrinsics
        poses_path = root / POSES_FILE
        if self.is_scene and poses_path.is_file():
            rows = read_poses_bounds(poses_path)
            self.poses = world_to_camera_from_llff(rows[:, :15].reshape(-1, 3, 5)[:, :, :4])
            if intrinsics is None:
                height, width, focal = rows[0, 4], rows[0, 9], rows[0, 14]
                intrinsics = Intrinsics.centred(focal, int(width), int(height))
        self.camera.intrinsics = intrinsics
        self.camera.depth_unit = meta.depth_unit if self.is_scene else "unknown"
        self.camera.expected_frames = self.frames_given or (None if self.poses is None
                                                            else len(self.poses))

    def _listed(self) -> list[Path]:
        if not self.images.is_dir():
            raise DataError(self.images, "is not a folder (was it removed during the stream?)")
        return list_files(self.images, IMAGE_SUFFIXES)

    def frames(self, stop: threading.Event) -> Iterator[Arrival]:
        index, last_arrival = 0, time.monotonic()
        waiting_since: float | None = None
        while not stop.is_set():
            if index == 0:
                self._read_layout()
            elif index == self.camera.expected_frames:
                return
            listed = self._listed()
            if index >= len(listed):
                if time.monotonic() - last_arrival > self.idle_timeout:
                    if index == 0:
                        raise DataError(self.images, f"received no frame in {self.idle_timeout:g}"
                                                     f" s: expected image files "
                                                     f"({', '.join(IMAGE_SUFFIXES)})")
                    return
                stop.wait(POLL_SECONDS)
                continue
            path = listed[index]
            now = time.monotonic()
            waiting_since = waiting_since or now
            try:
                frame = self._read(index, path, now)
            except BadFrame as err:
                if now - waiting_since < SETTLE_SECONDS and index + 1 >= len(listed):
                    stop.wait(POLL_SECONDS)  # perhaps still being written
                    continue
                frame = err
            index, last_arrival, waiting_since = index + 1, now, None
            yield frame

    def _companion(self, folder: str, image: Path) -> Path | None:
        """The depth or mask file of `image` in the scene folder's `folder`, None without that
        folder; BadFrame while it is missing."""
        if not self.is_scene or not (self.root / folder).is_dir():
            return None
        found = sorted((self.root / folder).glob(image.stem + ".*"))
        if not found:
            raise BadFrame(self.root / folder / image.name, "missing: expected the frame's "
                           f"{folder[:-1]} file beside {image}", -1)
        return found[0]

    def _read(self, index: int, path: Path, arrival: float) -> ArrivedFrame:
        try:
            check_image_file(path, "an image")
            depth_path = self._companion(DEPTH_DIR, path)
            mask_path = self._companion(MASKS_DIR, path)
            for companion in (depth_path, mask_path):
                if companion is not None:
                    check_image_file(companion, "a depth map or a mask")
            image = read_image(path)
            if min(image.shape[:2]) < MIN_SIZE:
                raise DataError(path, f"is {image.shape[0]}x{image.shape[1]} (HxW); frames "
                                      f"must be at least {MIN_SIZE}x{MIN_SIZE}")
            depth = (None if depth_path is None
                     else read_depth(depth_path, self.depth_scale, self.depth_limit))
            tool = None if mask_path is None else read_tool_mask(mask_path, lossy=True)
        except DataError as err:
            raise BadFrame(err.path, err.problem, index) from None
        pose = None
        if self.poses is not None and index < len(self.poses):
            pose = self.poses[index]
        return ArrivedFrame(index, arrival, image, depth, tool, pose)


StreamSource = VideoStream | FolderStream | CameraStream


def open_source(source: str, rate: float | None, idle_timeout: float,
                frames: int | None = None) -> StreamSource:
    """The source `source` names: a camera index (digits), a folder (ending after `frames`
    when given), or a video file; DataError naming it when it is none of these or does not
    open."""
    if source.isdigit():
        return CameraStream(int(source), idle_timeout)
    path = Path(source)
    if path.is_dir():
        return FolderStream(path, idle_timeout, frames)
    if not path.exists():
        raise DataError(path, "does not exist: expected a video file, a folder that frames are "
                              "written into, or a camera index")
    if path.suffix.lower() in IMAGE_SUFFIXES:
        raise DataError(path, "is a single image: expected a video file, a folder of frames or "
                              "a camera index")
    return VideoStream(path, rate)
