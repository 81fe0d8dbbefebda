"""What keeps a run folder whole: the log cut back to the checkpoint on resume, checkpoints by
wall time, the checkpoint kept before the latest, a full disk, the run's scene checked."""

from __future__ import annotations

import errno
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from surgsplat.atomic import temporary_path
from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.methods.registry import method_config
from surgsplat.train import checkpoint as checkpoint_module
from surgsplat.train.checkpoint import load_checkpoint, previous_path
from surgsplat.train.run import check_scene_identity, run_lock
from surgsplat.train.trainer import CHECKPOINT, LOG_FILE, Trainer, trim_log


def small_config(iterations: int):
    config = method_config("deform3dgs")
    config.train.iterations = iterations
    config.init.max_points = 2000
    return config


def logged_iterations(run) -> list[int]:
    return [json.loads(line)["iteration"] for line in (run / LOG_FILE).read_text().splitlines()]


def test_trim_log_keeps_one_increasing_history(tmp_path):
    log = tmp_path / LOG_FILE
    lines = [json.dumps({"iteration": i}) for i in (10, 20, 30, 40, 20, 30)] + ['{"iterat']
    log.write_text("\n".join(lines) + "\n")
    trim_log(log, 30)
    assert [json.loads(line)["iteration"] for line in log.read_text().splitlines()] == [10, 20, 30]
    trim_log(log, 0)
    assert log.read_text() == ""


def test_resume_after_a_stop_leaves_no_duplicate_in_the_log(small_phantom, tmp_path):
    scene = load_scene(small_phantom)
    run = tmp_path / "run"
    config = small_config(40)
    config.train.checkpoint_every = 20
    first = Trainer(config, scene, run)

    def die(stats):  # a kill after iteration 35: the checkpoint is at 20, the log at 30
        if stats.iteration == 35:
            raise SystemExit

    with pytest.raises(SystemExit):
        first.fit(die)
    assert logged_iterations(run)[-1] == 30 and load_checkpoint(run / CHECKPOINT)["iteration"] == 20
    resumed = Trainer(small_config(40), scene, run)
    resumed.load(run / CHECKPOINT)
    resumed.fit()
    assert logged_iterations(run) == [10, 20, 30, 40]


def test_checkpoints_by_wall_time(small_phantom, tmp_path, monkeypatch):
    config = small_config(6)
    config.train.checkpoint_every = 1000
    config.train.checkpoint_seconds = 0.0
    saved = []
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    monkeypatch.setattr(trainer, "save", lambda: saved.append(trainer.iteration))
    trainer.fit()
    assert saved[:6] == [1, 2, 3, 4, 5, 6]


def test_a_full_disk_keeps_the_last_checkpoint(small_phantom, tmp_path, monkeypatch):
    run = tmp_path / "run"
    trainer = Trainer(small_config(4), load_scene(small_phantom), run)
    trainer.fit()
    before = (run / CHECKPOINT).read_bytes()
    real_save = torch.save

    def full_disk(state, handle):
        real_save(state, handle)  # most of the bytes, then the disk is full
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(checkpoint_module.torch, "save", full_disk)
    trainer.config.train.iterations = 8
    with pytest.raises(OSError) as caught:
        trainer.fit()
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(run / CHECKPOINT)
    monkeypatch.setattr(checkpoint_module.torch, "save", real_save)
    assert (run / CHECKPOINT).read_bytes() == before
    assert load_checkpoint(run / CHECKPOINT)["iteration"] == 4
    assert not [p for p in (run / "checkpoints").iterdir() if ".tmp" in p.name]


@pytest.fixture(scope="module")
def two_checkpoints(small_phantom, tmp_path_factory):
    """A run of 4 iterations checkpointed at 2 (previous.pt) and 4 (latest.pt)."""
    run = tmp_path_factory.mktemp("two") / "run"
    config = small_config(4)
    config.train.checkpoint_every = 2
    Trainer(config, load_scene(small_phantom), run).fit()
    return run


@pytest.mark.parametrize("tenths", range(10))
def test_a_truncated_checkpoint_falls_back_to_the_previous(small_phantom, two_checkpoints,
                                                           tmp_path, tenths):
    run = shutil.copytree(two_checkpoints, tmp_path / "run")
    latest = run / CHECKPOINT
    assert load_checkpoint(previous_path(latest))["iteration"] == 2
    data = latest.read_bytes()
    latest.write_bytes(data[: len(data) * tenths // 10])
    with pytest.raises(DataError, match="latest.pt"):
        load_checkpoint(latest)
    resumed = Trainer(small_config(5), load_scene(small_phantom), run)
    damaged = resumed.load(latest)
    assert damaged is not None and damaged.path == latest and resumed.iteration == 2
    resumed.fit()
    assert load_checkpoint(latest)["iteration"] == 5


def test_another_scene_is_refused_with_what_differs(small_phantom, tmp_path):
    run = tmp_path / "run"
    Trainer(small_config(1), load_scene(small_phantom), run).write_run_files()
    check_scene_identity(run, load_scene(small_phantom))
    other = shutil.copytree(small_phantom, tmp_path / "other")
    image = sorted((other / "images").iterdir())[3]
    pixels = cv2.imread(str(image))
    pixels[5, 5] ^= 255
    cv2.imwrite(str(image), pixels)
    with pytest.raises(DataError, match="same frame count and size but other content"):
        check_scene_identity(run, load_scene(other))
    for folder in ("images", "depth", "masks"):
        if (other / folder).is_dir():
            sorted((other / folder).iterdir())[-1].unlink()
    np.save(other / "poses_bounds.npy", np.load(other / "poses_bounds.npy")[:-1])
    with pytest.raises(DataError, match="15 frames, the run's has 16"):
        check_scene_identity(run, load_scene(other))


def temporary_of(process: subprocess.Popen, target: Path) -> Path:
    """A hidden temporary beside `target` named as process `process` names its own."""
    name = temporary_path(target).name.replace(f"-{os.getpid()}-", f"-{process.pid}-")
    return target.with_name(name)


def test_one_writer_per_run_folder(tmp_path):
    killed = subprocess.Popen([sys.executable, "-c", "pass"])
    killed.wait()
    orphan = temporary_of(killed, tmp_path / "run" / "checkpoints" / "latest.pt")
    orphan.parent.mkdir(parents=True)
    orphan.write_bytes(b"left by a kill -9")
    with run_lock(tmp_path / "run", create=True):
        assert (tmp_path / "run" / ".lock").read_text().strip() == str(os.getpid())
        assert not orphan.exists()
        with pytest.raises(SurgsplatError, match=f"run: in use by another surgsplat process "
                                                 f"\\(PID {os.getpid()}\\)"):
            with run_lock(tmp_path / "run"):
                pass
    with run_lock(tmp_path / "run"):  # released at the end of the block
        pass
    with pytest.raises(DataError, match="is not a folder"):
        with run_lock(tmp_path / "missing"):
            pass
    assert not (tmp_path / "missing").exists()
    assert issubclass(DataError, SurgsplatError)


def test_the_lock_leaves_the_temporaries_of_running_writers(tmp_path):
    """A report written into the run while training starts keeps its temporary."""
    writer = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        for target in (tmp_path / "run" / "report.html", tmp_path / "run" / "videos" / "rgb.mp4"):
            target.parent.mkdir(parents=True, exist_ok=True)
            temporary_of(writer, target).write_bytes(b"being written")
        with run_lock(tmp_path / "run"):
            left = sorted(p.name for p in (tmp_path / "run").rglob(".*.tmp*"))
        assert len(left) == 2, left
    finally:
        writer.kill()
        writer.wait()
