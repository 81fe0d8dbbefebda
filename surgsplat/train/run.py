"""Reading a run folder back: its resolved config, its scene, and its trained model."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from surgsplat.atomic import remove_stale_temporaries
from surgsplat.data.scene import Scene, load_scene
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.overrides import method_from_values
from surgsplat.methods.ranges import check_config
from surgsplat.model.dynamic import SplatModel
from surgsplat.train.checkpoint import (READ_ENTRIES, load_checkpoint, model_from_state,
                                        previous_path)
from surgsplat.train.trainer import (CHECKPOINT, CONFIG_FILE, SCENE_FILE, SCENE_ID_FILE,
                                     scene_identity)

LOCK_FILE = ".lock"
"""RUN/.lock: held (flock, exclusive) by the one process writing the run; holds its PID."""
READ_ONLY_ERRNOS = (errno.EROFS, errno.EACCES, errno.EPERM)
"""What opening RUN/.lock for writing fails with in a folder this process cannot write."""


@contextmanager
def run_lock(run_dir: Path, create: bool = False) -> Iterator[None]:
    """Own the run folder `run_dir` while the block runs: an exclusive flock on RUN/.lock,
    released when the process ends however it ends. Another process that holds it stops this
    one with a SurgsplatError naming the folder and that process's PID. The folder is created
    when `create`, else it must exist. Temporary files that a killed writer left in the folder
    or below it are removed; those of a writer still running (`surgsplat report` into the run,
    say) are left alone (`remove_stale_temporaries`).

    An existing folder that this process cannot write (a read-only mount, no permission) and
    is not asked to `create` is only read by it, which needs no lock: checkpoints and run
    files are replaced atomically, so a reader never meets a half-written one. The block then runs without the lock, and a
    write into the folder fails where it is made, naming its file."""
    run_dir = Path(run_dir)
    if create:
        run_dir.mkdir(parents=True, exist_ok=True)
    elif not run_dir.is_dir():
        raise DataError(run_dir, "is not a folder: expected a run folder written by "
                                 "`surgsplat train`")
    fd = open_lock_file(run_dir / LOCK_FILE, must_write=create)
    if fd is None:
        yield
        return
    try:
        hold_lock(fd, run_dir)
        for folder in (run_dir, *(path for path in run_dir.rglob("*") if path.is_dir())):
            remove_stale_temporaries(folder)
        yield
    finally:
        os.close(fd)


def open_lock_file(path: Path, must_write: bool) -> int | None:
    """A descriptor of the lock file `path` open for writing (created when missing); None when
    its folder cannot be written (READ_ONLY_ERRNOS) and not `must_write`."""
    try:
        return os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as err:
        if must_write or err.errno not in READ_ONLY_ERRNOS:
            raise
    return None


def hold_lock(fd: int, run_dir: Path) -> None:
    """Take the exclusive flock on the open lock file `fd` of `run_dir` and write this
    process's PID into it; SurgsplatError naming the holder's PID when another process holds
    it."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = ""
        for _ in range(20):  # the holder writes its PID just after taking the lock
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip()
            if holder:
                break
            time.sleep(0.05)
        raise SurgsplatError(f"{run_dir}: in use by another surgsplat process (PID "
                             f"{holder or 'unknown'}); wait for it to end or choose another "
                             "folder") from None
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)


def read_run_config(run_dir: Path) -> MethodConfig:
    """The MethodConfig saved in RUN/config.json, built from the saved values alone (each
    component from its saved kind), so that a run loads whatever its name; the values are
    checked as any others are (types, ranges and the rules between fields)."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise DataError(path, "missing: not a surgsplat run folder (train one with "
                              "`surgsplat train`)")
    try:
        saved = json.loads(path.read_text())
    except ValueError as err:  # not JSON, or not UTF-8 text
        raise DataError(path, f"is not valid JSON ({err})") from err
    if not isinstance(saved, dict) or not isinstance(saved.get("name"), str):
        raise DataError(path, "expected a saved method configuration with a 'name'")
    config = method_from_values(saved, MethodConfig(name=saved["name"]), where=str(path),
                                complete=True)
    check_config(config, str(path))
    return config


def read_run_scene(run_dir: Path, data_dir: Path | None = None) -> Scene:
    """The run's scene (the path in RUN/scene.txt, or `data_dir` when given), checked against
    the identity saved in RUN/scene.json: DataError saying what differs when it is another."""
    if data_dir is None:
        path = Path(run_dir) / SCENE_FILE
        if not path.is_file():
            raise DataError(path, "missing: the run does not say which scene it was trained on")
        try:
            data_dir = Path(path.read_text().strip())
        except ValueError as err:  # not UTF-8 text
            raise DataError(path, f"is not the path of a scene folder ({err})") from err
        if not data_dir.is_dir():
            raise DataError(data_dir, f"missing: the run's scene (named in {path}) has moved or "
                                      "been deleted; pass --data with its location")
    scene = load_scene(data_dir)
    check_scene_identity(run_dir, scene)
    return scene


def check_scene_identity(run_dir: Path, scene: Scene) -> None:
    """DataError naming what differs (frame count, size, content) when `scene` is not the one
    RUN/scene.json describes; runs from before scene.json are not checked."""
    path = Path(run_dir) / SCENE_ID_FILE
    if not path.is_file():
        return
    try:
        saved = json.loads(path.read_text())
    except ValueError as err:  # not JSON, or not UTF-8 text
        raise DataError(path, f"is not valid JSON ({err})") from err
    if not isinstance(saved, dict):
        raise DataError(path, "expected a JSON object describing the run's scene")
    found = scene_identity(scene)
    where = f"{scene.root} is not the scene this run was trained on ({saved.get('path')})"
    if saved.get("frames") != found["frames"]:
        raise DataError(path, f"{where}: {found['frames']} frames, the run's has "
                              f"{saved.get('frames')}")
    if (saved.get("width"), saved.get("height")) != (found["width"], found["height"]):
        raise DataError(path, f"{where}: frames of {found['width']}x{found['height']} (WxH), "
                              f"the run's are {saved.get('width')}x{saved.get('height')}")
    if saved.get("fingerprint") != found["fingerprint"]:
        raise DataError(path, f"{where}: same frame count and size but other content "
                              f"(fingerprint {found['fingerprint']}, the run's "
                              f"{saved.get('fingerprint')})")


@dataclass
class TrainedRun:
    """A run's model as saved in its latest checkpoint."""

    run_dir: Path
    config: MethodConfig
    scene: Scene
    model: SplatModel
    iteration: int
    train_seconds: float
    peak_rss_mb: float  # of the training process

    @property
    def background(self) -> Tensor:
        """[3] RGB in [0, 1] behind the Gaussians, as the run was trained with."""
        return torch.tensor(self.config.train.background, dtype=torch.float32)


def load_trained_run(run_dir: Path, data_dir: Path | None = None) -> TrainedRun:
    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    scene = read_run_scene(run_dir, data_dir)
    path = run_dir / CHECKPOINT
    try:
        state = load_checkpoint(path, READ_ENTRIES)
    except DataError as err:
        if not previous_path(path).is_file():
            raise
        raise DataError(path, f"{err.problem}; `surgsplat train --out {run_dir} --resume` "
                              f"continues from {previous_path(path).name}, the checkpoint "
                              "kept before it") from None
    model = model_from_state(config, state, path)
    if state.get("num_frames", len(scene.frames)) != len(scene.frames):
        raise DataError(path, f"was trained on {state['num_frames']} frames, but {scene.root} "
                              f"holds {len(scene.frames)}")
    model.eval()
    return TrainedRun(run_dir=run_dir, config=config, scene=scene, model=model,
                      iteration=int(state["iteration"]),
                      train_seconds=float(state["elapsed_seconds"]),
                      peak_rss_mb=float(state["peak_rss_mb"]))
