"""Outputs on a full disk (videos, checkpoints), the viewer's address and height, metrics over
fewer frames than the test set, and `batch`: one line per error, never a traceback, a hang or a
replaced good file."""

from __future__ import annotations

import json
import os
import shutil
import socket
import stat
from pathlib import Path

import pytest

from surgsplat.train.checkpoint import load_checkpoint
from surgsplat.train.run import run_lock
from surgsplat.train.trainer import CHECKPOINT

FULL_DISK_FFMPEG = """#!/bin/sh
# ffmpeg on a full disk: part of the video written, its error printed, a failure status
for output; do :; done
head -c 1000 > "$output"
echo "[out#0/mp4 @ 0x1] Error writing trailer: No space left on device" >&2
exit 228
"""

FULL_DISK_MID_CHECKPOINT = """
import builtins, io
real_open = builtins.open
class FillingFile(io.FileIO):
    def write(self, data):
        if self.tell() + len(data) > {limit}:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(data)
def full_disk_open(file, mode="r", *args, **kwargs):
    name = os.fsdecode(file) if isinstance(file, (str, bytes, os.PathLike)) else ""
    if mode == "wb" and ".tmp" in name and name.endswith(".pt"):
        return io.BufferedWriter(FillingFile(name, "w"))
    return real_open(file, mode, *args, **kwargs)
builtins.open = full_disk_open
"""
"""The disk fills once a checkpoint's temporary file holds `limit` bytes: torch.save's writes
fail (with a limit inside the tensors' data, as a real full disk makes them fail, torch.save
itself raises a RuntimeError about its zip container)."""


@pytest.fixture(scope="module")
def scene(small_phantom, tmp_path_factory) -> Path:
    """The small phantom without the ground-truth mesh of test frame 9."""
    folder = shutil.copytree(small_phantom, tmp_path_factory.mktemp("scene") / "phantom")
    (folder / "gt" / "meshes" / "000009.ply").unlink()
    return folder


@pytest.fixture(scope="module")
def pristine_run(scene, tmp_path_factory, cli) -> Path:
    """A run of 4 iterations of `scene` with checkpoints at 2 and 4."""
    run = tmp_path_factory.mktemp("trained") / "run"
    done = cli("train", "--data", str(scene), "--out", str(run), "--iters", "4",
               "--set", "train.checkpoint_every=2", "--set", "init.max_points=1500")
    assert done.returncode == 0, done.stderr
    return run


@pytest.fixture
def run(pristine_run, tmp_path) -> Path:
    """A copy of the trained run that the test may change."""
    return shutil.copytree(pristine_run, tmp_path / "run")


# ---- class 3: render on a full disk ----

def test_render_on_a_full_disk_is_one_line_and_keeps_the_old_videos(cli, run, tmp_path,
                                                                   one_error_line, monkeypatch):
    assert cli("render", str(run), "--fps", "5").returncode == 0
    videos = run / "videos"
    before = {path.name: path.read_bytes() for path in videos.iterdir()}
    ffmpeg = tmp_path / "ffmpeg"
    ffmpeg.write_text(FULL_DISK_FFMPEG)
    ffmpeg.chmod(ffmpeg.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(ffmpeg))  # read by every get_ffmpeg_exe()
    full = cli("render", str(run), "--fps", "5")
    line = one_error_line(full)
    assert line.startswith(f"error: {videos}/") and line.endswith(".mp4: No space left on device")
    assert {path.name: path.read_bytes() for path in videos.iterdir()} == before


# ---- class 8: the viewer ----

def listening_socket() -> socket.socket:
    """A socket listening on a free port of 127.0.0.1 (as another server would)."""
    taken = socket.socket()
    taken.bind(("127.0.0.1", 0))
    taken.listen()
    return taken


def test_view_refuses_a_port_in_use(cli, pristine_run, one_error_line):
    with listening_socket() as taken:
        port = taken.getsockname()[1]
        line = one_error_line(cli("view", str(pristine_run), "--port", str(port), timeout=120))
    assert f"--port {port}" in line and "Address already in use" in line


def test_view_on_a_host_it_cannot_bind_stops_at_once(cli, pristine_run, one_error_line):
    for host in ("192.0.2.1", "no-such-host.invalid"):  # not this machine's; does not resolve
        line = one_error_line(cli("view", str(pristine_run), "--host", host, timeout=120))
        assert f"--host {host}" in line and "cannot serve there" in line


@pytest.mark.parametrize("height", ["0", "-5"])
def test_view_refuses_a_height_below_one(cli, pristine_run, one_error_line, height):
    line = one_error_line(cli("view", str(pristine_run), "--height", height, timeout=120))
    assert "--height must be in 1.." in line


# ---- class 9: metrics over fewer frames ----

def test_eval_says_which_metrics_cover_fewer_frames(cli, run):
    done = cli("eval", str(run))
    assert done.returncode == 0, done.stderr
    metrics = json.loads((run / "metrics.json").read_text())
    covered = metrics["frames_covered"]
    assert metrics["test_frames"] == 2 and covered["image"] == 2 and covered["normals"] == 2
    assert covered["geometry"] == covered["mesh_geometry"] == covered["gaussians_p2s"] == 1
    printed = " ".join(done.stdout.split())
    assert "over fewer than the 2 test frames: " in printed and "geometry 1" in printed


# ---- class 11: a full disk during a checkpoint write ----

def test_a_full_disk_mid_checkpoint_is_one_line_and_keeps_the_checkpoint(run, faults):
    latest = run / CHECKPOINT
    before = latest.read_bytes()
    patch = FULL_DISK_MID_CHECKPOINT.format(limit=len(before) // 5)
    full = faults.run_patched(patch, "train", "--out", str(run), "--resume", "--iters", "6")
    assert faults.one_error_line(full) == f"error: {latest}: No space left on device"
    assert latest.read_bytes() == before and load_checkpoint(latest)["iteration"] == 4
    assert not [path for path in latest.parent.iterdir() if ".tmp" in path.name]


# ---- class 10: batch ----

def test_batch_out_on_a_file_or_under_one_is_one_line(cli, small_phantom, tmp_path,
                                                      one_error_line):
    existing = tmp_path / "file"
    existing.write_text("not a folder")
    line = one_error_line(cli("batch", str(small_phantom), "--out", str(existing),
                              "--iters", "2"))
    assert line == f"error: {existing}: File exists"
    line = one_error_line(cli("batch", str(small_phantom), "--out",
                              str(existing / "batch"), "--iters", "2"))
    assert line == f"error: {existing / 'batch'}: Not a directory"


def test_a_second_batch_into_one_folder_is_refused(cli, small_phantom, tmp_path,
                                                   one_error_line):
    out = tmp_path / "batch"
    # as the first batch holds it; flock refuses any other open of the lock file, this
    # process's own as another's
    with run_lock(out, create=True):
        line = one_error_line(cli("batch", str(small_phantom), "--out", str(out),
                                  "--iters", "2"))
    assert f"{out}: in use by another surgsplat process (PID {os.getpid()})" in line
    assert sorted(path.name for path in out.iterdir()) == [".lock"]


def test_batch_set_is_checked_as_train_checks_it(cli, small_phantom, tmp_path,
                                                 one_error_line):
    line = one_error_line(cli("batch", str(small_phantom), "--out", str(tmp_path / "b"),
                              "--iters", "2", "--set", "densify.every=0"))
    assert "densify.every" in line
    assert not (tmp_path / "b").exists()


@pytest.mark.slow
def test_batch_with_a_failing_clip_prints_one_line_and_exits_1(cli, small_phantom, tmp_path):
    good = shutil.copytree(small_phantom, tmp_path / "clips" / "good")
    bad = shutil.copytree(small_phantom, tmp_path / "clips" / "bad")
    broken = bad / "images" / "000003.png"
    broken.write_bytes(broken.read_bytes()[:200])
    out = tmp_path / "batch"
    done = cli("batch", str(good), str(bad), "--out", str(out), "--iters", "2",
               "--num-cpus", "2", "--no-geometry", "--memory-gb", "0.5",
               "--set", "train.checkpoint_every=1", timeout=600,
               process=True)  # a Ray instance of its own, ended with the process
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stdout + done.stderr, done.stdout + done.stderr
    failed = [line for line in done.stdout.splitlines() if line.startswith(f"{bad}: failed")]
    assert len(failed) == 1 and f"failed in import: {broken}: " in failed[0]
    assert done.stdout.splitlines()[-1].startswith("1 of 2 clips done, 1 failed")
    status = json.loads((out / "bad" / "status.json").read_text())
    assert status["state"] == "failed" and status["attempts"] == 2
    config = json.loads((out / "good" / "run" / "config.json").read_text())
    assert config["train"]["checkpoint_every"] == 1  # --set reached the clip's run
