"""A stream's scene folder (RUN/scene) as it is written, and the run as it stands mid-stream.

`StreamScene` writes each arrived frame into RUN/scene (on a thread of its own) and serves the
frames to training through a bounded cache that decodes evicted frames from the written files.
While the stream runs, RUN/live.json says what the latest checkpoint was trained on (its frame
count, the time axis, the cameras), so that `load_live_run` reads the run at that checkpoint
before its scene folder is finished (`surgsplat view` during a stream). The stream removes it
when the run is finished, an ordinary run from then on.
"""

from __future__ import annotations

import json
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from surgsplat.atomic import write_text_atomic
from surgsplat.data.frame_store import FramePixels, FrameStore
from surgsplat.data.layout import (DEPTH_DIR, IMAGES_DIR, MASKS_DIR, SceneMeta, SceneWriter,
                                   frame_stem, max_depth)
from surgsplat.data.scene import (Camera, Frame, FrameFiles, Scene, frame_pixels, is_test_index,
                                  load_scene, read_frame_files)
from surgsplat.data.stream_source import (ArrivedFrame, BadFrame, StreamSource,
                                          camera_intrinsics)
from surgsplat.errors import DataError
from surgsplat.train.checkpoint import READ_ENTRIES, load_checkpoint, model_from_state
from surgsplat.train.run import TrainedRun, load_trained_run, read_run_config
from surgsplat.train.trainer import CHECKPOINT

SCENE_DIR = "scene"
"""RUN/scene: the frames of the stream, as a scene folder."""
LIVE_FILE = "live.json"
"""RUN/live.json: what the latest checkpoint of a stream in progress was trained on."""


@dataclass(frozen=True)
class WrittenFrames:
    """How to read a stream's frames back from its scene folder."""

    root: Path
    height: int
    width: int
    has_depth: bool
    has_masks: bool
    depth_scale: float  # scene units per stored step of the depth PNGs
    depth_unit: str

    def pixels(self, index: int) -> FramePixels:
        stem = frame_stem(index)
        files = FrameFiles(image=self.root / IMAGES_DIR / f"{stem}.png",
                           depth=self.root / DEPTH_DIR / f"{stem}.png" if self.has_depth
                           else None,
                           mask=self.root / MASKS_DIR / f"{stem}.png" if self.has_masks
                           else None,
                           depth_scale=self.depth_scale, depth_limit=max_depth(self.depth_unit),
                           size=(self.height, self.width))
        return frame_pixels(*read_frame_files(files, None),
                            torch.ones((self.height, self.width), dtype=torch.bool))


class StreamScene:
    """RUN/scene written frame by frame (see the module docstring)."""

    def __init__(self, root: Path, first: ArrivedFrame, source: StreamSource, focal: float | None,
                 description: str, tool: np.ndarray | None):
        height, width = first.image.shape[:2]
        intrinsics = camera_intrinsics(source.camera.intrinsics, width, height, focal)
        depth_unit = source.camera.depth_unit if first.depth is not None else "unknown"
        self.meta = SceneMeta(depth_unit=depth_unit, intrinsics=intrinsics, source=description)
        self.writer = SceneWriter(root, intrinsics.fx, self.meta)
        self.files = WrittenFrames(root, height, width, first.depth is not None,
                                   tool is not None, self.meta.depth_scale, depth_unit)
        self.K = torch.tensor(intrinsics.matrix(), dtype=torch.float32)
        self.fov = torch.ones((height, width), dtype=torch.bool)
        self.store = FrameStore(self._decode)
        # the files are written on a thread of their own, while training goes on
        self.writing = ThreadPoolExecutor(1, thread_name_prefix="stream-scene")
        self.written: list[Future] = []
        self.poses: list[np.ndarray] = []  # [4, 4] world-to-camera of every frame so far
        self.first_pose = (np.eye(4) if first.world_to_camera is None
                           else first.world_to_camera)

    def _decode(self, index: int) -> FramePixels:
        self.written[index].result()
        return self.files.pixels(index)

    def add(self, arrived: ArrivedFrame, tool: np.ndarray | None) -> Frame:
        """Write `arrived` (with tool mask `tool`) as the next frame and return it; BadFrame
        when it does not match the first frame (size, depth, mask)."""
        files = self.files
        problem = None
        if arrived.image.shape[:2] != (files.height, files.width):
            problem = (f"is {arrived.image.shape[0]}x{arrived.image.shape[1]} (HxW), the "
                       f"stream's frames {files.height}x{files.width}")
        elif (arrived.depth is not None) != files.has_depth:
            problem = ("has no depth while the first had depth" if files.has_depth
                       else "has depth while the first had none")
        elif (tool is not None) != files.has_masks:
            problem = ("has no tool mask while the first had one" if files.has_masks
                       else "has a tool mask while the first had none")
        if problem is not None:
            raise BadFrame(Path(f"frame {arrived.index}"), problem, arrived.index)
        index = len(self.written)
        pose = self.first_pose if arrived.world_to_camera is None else arrived.world_to_camera
        self.written.append(self.writing.submit(self.writer.add_frame, arrived.image,
                                                arrived.depth, tool, pose))
        self.poses.append(np.asarray(pose, dtype=np.float64))
        depth = None if arrived.depth is None else arrived.depth.astype(np.float32)
        self.store.put(index, frame_pixels(arrived.image, depth, tool, self.fov))
        return Frame.stored(index, 0.0, is_test_index(index), self.camera(pose), self.store)

    def camera(self, pose: np.ndarray) -> Camera:
        return camera_of(self.K, pose, self.files.width, self.files.height)

    def scene(self, frames: list[Frame]) -> Scene:
        """The scene of `frames` (training grows its list)."""
        return Scene(root=self.files.root, frames=frames, meta=self.meta, near=0.01,
                     far=1000.0, has_depth=self.files.has_depth,
                     has_masks=self.files.has_masks, has_fov=False)

    def write_live(self, run_dir: Path, frames: int, horizon: int) -> None:
        """RUN/live.json for a checkpoint trained on the first `frames` frames, frame i at
        time i / `horizon`."""
        state = {"frames": frames, "horizon": horizon, "K": self.K.tolist(),
                 "poses": [pose.tolist() for pose in self.poses[:frames]],
                 "files": {**asdict(self.files), "root": str(self.files.root)}}
        write_text_atomic(run_dir / LIVE_FILE, json.dumps(state) + "\n")

    def finish(self) -> Scene:
        """Write the scene folder's remaining files and load it back, as any run's scene."""
        self.writing.shutdown()
        for written in self.written:
            written.result()  # an error writing a frame's files is raised here
        self.writer.finish()
        return load_scene(self.files.root)


def camera_of(K: torch.Tensor, pose: np.ndarray, width: int, height: int) -> Camera:
    return Camera(K=K, world_to_camera=torch.tensor(pose, dtype=torch.float32), width=width,
                  height=height)


def load_live_run(run_dir: Path) -> TrainedRun:
    """The run of a stream in progress at its latest checkpoint (RUN/live.json says what that
    was trained on); DataError when the run has no stream in progress."""
    path = Path(run_dir) / LIVE_FILE
    try:
        state = json.loads(path.read_text())
    except FileNotFoundError:
        raise DataError(path, "missing: no stream is writing this run") from None
    except ValueError as err:
        raise DataError(path, f"is not valid JSON ({err})") from err
    config = read_run_config(run_dir)
    checkpoint = Path(run_dir) / CHECKPOINT
    saved = load_checkpoint(checkpoint, READ_ENTRIES)
    model = model_from_state(config, saved, checkpoint)
    model.eval()
    files = WrittenFrames(**{**state["files"], "root": Path(state["files"]["root"])})
    K = torch.tensor(state["K"], dtype=torch.float32)
    store = FrameStore(files.pixels)
    frames = [Frame.stored(index, index / state["horizon"], is_test_index(index),
                           camera_of(K, np.array(pose), files.width, files.height), store)
              for index, pose in enumerate(state["poses"])]
    scene = Scene(root=files.root, frames=frames, meta=SceneMeta(depth_unit=files.depth_unit),
                  near=0.01, far=1000.0, has_depth=files.has_depth, has_masks=files.has_masks,
                  has_fov=False)
    return TrainedRun(run_dir=Path(run_dir), config=config, scene=scene, model=model,
                      iteration=int(saved["iteration"]),
                      train_seconds=float(saved["elapsed_seconds"]),
                      peak_rss_mb=float(saved["peak_rss_mb"]))


class LiveFollower:
    """What a viewer of a stream in progress calls, every second or so: the run at a newer
    checkpoint, the finished run once the stream has ended, or None when nothing changed."""

    def __init__(self, run_dir: Path, loaded: TrainedRun):
        self.run_dir = Path(run_dir)
        self.seen = loaded.iteration
        self.finished = False

    def __call__(self) -> TrainedRun | None:
        if self.finished:
            return None
        live = self.run_dir / LIVE_FILE
        if not live.is_file():
            self.finished = True
            return load_trained_run(self.run_dir)
        try:
            run = load_live_run(self.run_dir)
        except DataError:  # the stream ended or was replacing a file meanwhile
            return None
        if run.iteration == self.seen:
            return None
        self.seen = run.iteration
        return run
