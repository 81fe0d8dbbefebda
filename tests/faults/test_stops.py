"""kill -9 at a random moment and SIGTERM during training: no traceback, the last checkpoint
loads, the resumed run reaches the same final iteration, and its log holds each iteration once,
in increasing order."""

from __future__ import annotations

import random
import signal
import subprocess
import time

import pytest

from surgsplat.train.checkpoint import load_checkpoint
from surgsplat.train.trainer import CHECKPOINT

ITERATIONS = 60

pytestmark = pytest.mark.slow  # each trains on the phantom in a process of its own, then again


def resume_to_the_end(run, small_phantom, cli, faults):
    """Continue a stopped run (or start it again when it stopped before its first checkpoint)
    and check the result."""
    if (run / CHECKPOINT).is_file():
        done = cli("train", "--out", str(run), "--resume")
    else:
        done = cli("train", "--data", str(small_phantom), "--out", str(run), "--iters",
                   str(ITERATIONS), *faults.TRAIN_FAST)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert f"trained {ITERATIONS} iterations" in done.stdout
    assert load_checkpoint(run / CHECKPOINT)["iteration"] == ITERATIONS
    logged = faults.logged_iterations(run)
    assert faults.strictly_increasing(logged) and logged[-1] == ITERATIONS, logged


@pytest.mark.parametrize("trial", range(2))
def test_kill_9_at_a_random_moment(small_phantom, tmp_path, cli, faults, trial):
    run = tmp_path / "run"
    process = faults.start("train", "--data", str(small_phantom), "--out", str(run), "--iters",
                           str(ITERATIONS), "--set", "train.checkpoint_seconds=0.5",
                           "--set", "train.checkpoint_every=1000", *faults.TRAIN_FAST)
    faults.wait_for(lambda: faults.logged_iterations(run) or process.poll() is not None,
                    what="training to start")
    time.sleep(random.Random(trial).uniform(0.0, 1.5))
    process.send_signal(signal.SIGKILL)
    process.communicate(timeout=60)
    if (run / CHECKPOINT).is_file():
        load_checkpoint(run / CHECKPOINT)  # whole, whenever the kill came
    resume_to_the_end(run, small_phantom, cli, faults)


def test_sigterm_checkpoints_and_stops_cleanly(small_phantom, tmp_path, cli, faults):
    run = tmp_path / "run"
    process = faults.start("train", "--data", str(small_phantom), "--out", str(run), "--iters",
                           "5000", *faults.TRAIN_FAST)
    faults.wait_for(lambda: faults.logged_iterations(run), what="training to start")
    process.send_signal(signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=120)
    line = faults.one_error_line(subprocess.CompletedProcess(process.args, process.returncode,
                                                             stdout, stderr))
    stopped = load_checkpoint(run / CHECKPOINT)["iteration"]
    assert f"interrupted at iteration {stopped}; checkpoint saved" in line
    assert faults.logged_iterations(run)[-1] <= stopped
    extended = cli("train", "--out", str(run), "--resume", "--iters", str(stopped + 12))
    assert extended.returncode == 0, extended.stderr
    assert load_checkpoint(run / CHECKPOINT)["iteration"] == stopped + 12
    logged = faults.logged_iterations(run)
    assert faults.strictly_increasing(logged) and logged[-1] == stopped + 12, logged


def lock_is_held(path) -> bool:
    """Whether another process holds the run folder's lock file."""
    import fcntl

    if not path.is_file():
        return False
    with open(path, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return True
        fcntl.flock(handle, fcntl.LOCK_UN)
        return False


def test_sigterm_during_render_is_one_line_and_keeps_the_old_videos(small_phantom, tmp_path, cli,
                                                                    faults):
    run = tmp_path / "run"
    trained = cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "5",
                  *faults.TRAIN_FAST)
    assert trained.returncode == 0, trained.stderr
    assert cli("render", str(run), "--fps", "5").returncode == 0
    before = (run / "videos" / "rgb.mp4").read_bytes()
    process = faults.start("render", str(run), "--fps", "5")
    faults.wait_for(lambda: lock_is_held(run / ".lock") or process.poll() is not None,
                    what="the render to take its run folder")
    process.send_signal(signal.SIGTERM)
    stdout, stderr = process.communicate(timeout=120)
    if process.returncode == 0:
        pytest.skip("the render finished before the signal arrived")
    line = faults.one_error_line(subprocess.CompletedProcess(process.args, process.returncode,
                                                             stdout, stderr))
    assert "interrupted" in line
    assert (run / "videos" / "rgb.mp4").read_bytes() == before  # written atomically or not at all
