"""Two writers of one run folder, a full disk, a read-only folder, --out on an existing file and
a checkpoint cut at every tenth of its length: one line and exit 2 (or a clean recovery), never
a traceback, and the last good checkpoint loads."""

from __future__ import annotations

import os
import signal

import pytest

from surgsplat.train.checkpoint import load_checkpoint, previous_path
from surgsplat.train.trainer import CHECKPOINT


FULL_DISK = """
import torch
real_save = torch.save
def full_disk(state, handle):
    real_save(state, handle)
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
torch.save = full_disk
"""

READ_ONLY = """
import builtins, pathlib
ROOT = os.path.realpath({root!r})
def under(path):
    try:
        return os.path.realpath(os.fsdecode(path)).startswith(ROOT)
    except TypeError:
        return False
def refuse(path):
    raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fsdecode(path))
real_open, real_os_open, real_mkdir = builtins.open, os.open, os.mkdir
def guarded_open(file, mode="r", *args, **kwargs):
    if under(file) and any(c in mode for c in "wax+"):
        refuse(file)
    return real_open(file, mode, *args, **kwargs)
def guarded_os_open(path, flags, *args, **kwargs):
    if under(path) and flags & (os.O_WRONLY | os.O_RDWR | os.O_CREAT):
        refuse(path)
    return real_os_open(path, flags, *args, **kwargs)
def guarded_mkdir(path, *args, **kwargs):
    if under(path):
        refuse(path)
    return real_mkdir(path, *args, **kwargs)
builtins.open, os.open, os.mkdir = guarded_open, guarded_os_open, guarded_mkdir
"""


@pytest.mark.slow  # the first writer trains in a process of its own until it is stopped
def test_two_writers_of_one_run_folder(small_phantom, tmp_path, cli, faults):
    run = tmp_path / "run"
    first = faults.start("train", "--data", str(small_phantom), "--out", str(run), "--iters",
                         "5000", *faults.TRAIN_FAST)
    faults.wait_for(lambda: faults.logged_iterations(run), what="the first writer to train")
    for second in (cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "5"),
                   cli("train", "--out", str(run), "--resume"),
                   cli("eval", str(run)), cli("render", str(run))):
        line = faults.one_error_line(second)
        assert f"{run}: in use by another surgsplat process (PID {first.pid})" in line
    first.send_signal(signal.SIGTERM)
    stdout, stderr = first.communicate(timeout=120)
    assert first.returncode == 2 and "Traceback" not in stderr, stderr
    stopped = load_checkpoint(run / CHECKPOINT)["iteration"]
    assert stopped >= faults.logged_iterations(run)[-1]
    resumed = cli("train", "--out", str(run), "--resume", "--iters", str(stopped + 3))
    assert resumed.returncode == 0, resumed.stderr
    assert load_checkpoint(run / CHECKPOINT)["iteration"] == stopped + 3
    assert faults.strictly_increasing(faults.logged_iterations(run))


def test_a_full_disk_keeps_the_last_checkpoint(trained, faults, cli):
    before = (trained / CHECKPOINT).read_bytes()
    full = faults.run_patched(FULL_DISK, "train", "--out", str(trained), "--resume", "--iters", "7")
    assert faults.one_error_line(full) == (f"error: {trained / CHECKPOINT}: No space left on "
                                           "device")
    assert (trained / CHECKPOINT).read_bytes() == before
    assert load_checkpoint(trained / CHECKPOINT)["iteration"] == 4
    assert not [p for p in (trained / "checkpoints").iterdir() if ".tmp" in p.name]
    resumed = cli("train", "--out", str(trained), "--resume", "--iters", "7")
    assert resumed.returncode == 0, resumed.stderr
    assert load_checkpoint(trained / CHECKPOINT)["iteration"] == 7
    assert faults.strictly_increasing(faults.logged_iterations(trained))


def test_a_read_only_folder_is_one_line(trained, small_phantom, tmp_path, faults):
    """Denied writes (EROFS from every write under the folder: tests run as root, for whom
    chmod does not make a folder read-only)."""
    patch = READ_ONLY.format(root=str(tmp_path))
    for args in (("eval", str(trained)), ("render", str(trained)),
                 ("train", "--out", str(trained), "--resume", "--iters", "6"),
                 ("train", "--data", str(small_phantom), "--out", str(tmp_path / "new"))):
        line = faults.one_error_line(faults.run_patched(patch, *args))
        assert line.startswith(f"error: {tmp_path}") and "Read-only file system" in line, line
    assert load_checkpoint(trained / CHECKPOINT)["iteration"] == 4


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into folders without write "
                                               "permission; the EROFS test covers this")
def test_a_folder_without_write_permission(trained, cli, faults):
    os.chmod(trained, 0o555)
    try:
        line = faults.one_error_line(cli("eval", str(trained)))
        assert str(trained) in line and "Permission denied" in line
    finally:
        os.chmod(trained, 0o755)


def test_out_on_an_existing_file(small_phantom, tmp_path, cli, faults):
    existing = tmp_path / "file"
    existing.write_text("not a folder")
    line = faults.one_error_line(cli("train", "--data", str(small_phantom), "--out",
                                     str(existing), "--iters", "2"))
    assert line == f"error: {existing}: File exists"


def test_a_truncated_checkpoint(trained, cli, faults):
    """Cut at every tenth (in-process checks of every tenth are in tests/train): eval names the
    damaged file, resume continues from the checkpoint before it, to the same end."""
    latest = trained / CHECKPOINT
    data = latest.read_bytes()
    for tenths in (0, 5, 9):
        latest.write_bytes(data[: len(data) * tenths // 10])
        line = faults.one_error_line(cli("eval", str(trained)))
        assert str(latest) in line and "--resume" in line
    resumed = cli("train", "--out", str(trained), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    said = resumed.stdout.replace("\n", "")
    assert previous_path(latest).name in said and "trained 4 iterations" in said
    assert load_checkpoint(latest)["iteration"] == 4
    assert faults.strictly_increasing(faults.logged_iterations(trained))
