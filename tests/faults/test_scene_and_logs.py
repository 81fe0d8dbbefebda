"""Issue 30, classes 1, 2, 7 and 12: frames load in the order `import` writes them, `train --out`
replaces no user's files, a damaged training log is read as far as it is whole (by `report` and
by `train --resume` alike), the report names each run and its scene, a killed writer's
temporaries go with the next write into their folder, and a full disk or a bad option value is
one line naming the path or the option."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from surgsplat.atomic import write_text_atomic
from surgsplat.data.layout import write_image
from surgsplat.data.scene import load_scene
from surgsplat.methods.registry import method_config
from surgsplat.train.trainer import LOG_FILE, Trainer, read_log, trim_log

FULL_DISK_NUMPY = """
import numpy
def full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
numpy.save = full_disk
"""


@pytest.fixture
def unpadded_copy(small_phantom, tmp_path) -> Path:
    """The small phantom with its frame files renamed 0.png ... 15.png (no zero padding)."""
    copy = tmp_path / "unpadded"
    shutil.copytree(small_phantom, copy, ignore=shutil.ignore_patterns("gt"))
    for folder in ("images", "depth", "masks"):
        for path in (copy / folder).iterdir():
            path.rename(path.with_name(f"{int(path.stem)}{path.suffix}"))
    return copy


def test_frames_load_in_natural_order(small_phantom, unpadded_copy):
    """Class 1: 0.png ... 15.png load as frames 0 ... 15 (not 0, 1, 10, ..., 15, 2, ... 9)."""
    renamed = load_scene(unpadded_copy)
    assert renamed.fingerprint == load_scene(small_phantom).fingerprint


def test_train_refuses_an_out_folder_holding_other_files(small_phantom, tmp_path, cli,
                                                         one_error_line):
    """Class 2: a scene folder or a folder of the user's own files is refused, untouched."""
    scene = tmp_path / "scene"
    shutil.copytree(small_phantom, scene)
    own = tmp_path / "own"
    own.mkdir()
    (own / "config.json").write_text("{\"mine\": true}\n")
    for out in (scene, own):
        before = {path: path.read_bytes() for path in out.rglob("*") if path.is_file()}
        line = one_error_line(cli("train", "--data", str(small_phantom), "--out", str(out),
                                  "--iters", "2"))
        assert line.startswith(f"error: {out}: is not empty and is not a surgsplat run folder")
        after = {path: path.read_bytes() for path in out.rglob("*") if path.is_file()}
        assert after == before


DAMAGED_LINES = (b"\xff\xfe not UTF-8\n", b"[1, 2, 3]\n", b"{\"loss\": 2.0}\n",
                 b"{\"iteration\": \"7\"}\n", b"{\"iteration\": 3, \"loss\": \"x\"}\n")
"""Lines a damaged log may hold besides a torn last one: bytes that are not UTF-8, a JSON value
that is not an object, an entry without an integer iteration, and one without numbers."""


def damage(log: Path) -> None:
    """Put every kind of damaged line into a training log, and end it with a torn line."""
    lines = log.read_bytes().splitlines(keepends=True)
    log.write_bytes(lines[0] + b"".join(DAMAGED_LINES) + b"".join(lines[1:])
                    + b"{\"iteration\": 999, \"lo")


def test_one_reader_of_a_damaged_log(tmp_path):
    """Class 7: the entries of a damaged log are its whole ones, for the report and for the
    resume's cut alike."""
    log = tmp_path / LOG_FILE
    log.write_text("".join(json.dumps({"iteration": i, "loss": 1.0 / i}) + "\n"
                           for i in (1, 2, 4)))
    damage(log)
    assert [entry["iteration"] for entry in read_log(log)] == [1, 3, 4]
    trim_log(log, 3)
    assert log.read_text().splitlines() == [json.dumps({"iteration": 1, "loss": 1.0}),
                                            json.dumps({"iteration": 3, "loss": "x"})]


def tiny_run(scene: Path, run: Path) -> None:
    """Two iterations of deform3dgs on `scene` into `run`, with a metrics.json (no eval)."""
    config = method_config("deform3dgs")
    config.train.iterations = 2
    config.init.max_points = 500
    Trainer(config, load_scene(scene), run).fit()
    write_text_atomic(run / "metrics.json", json.dumps({"psnr_tissue": 20.0}) + "\n")


def test_report_of_damaged_logs_names_runs_and_scenes(small_phantom, unpadded_copy, tmp_path):
    """Class 7: `report` reads a damaged log; runs laid out as `batch` writes them (DIR/clip/run)
    are told apart, each with its scene. Class 12: a killed report's temporary goes."""
    from surgsplat.export.report import write_report

    runs = [tmp_path / "batch" / "a" / "run", tmp_path / "batch" / "b" / "run"]
    tiny_run(small_phantom, runs[0])
    tiny_run(unpadded_copy, runs[1])
    damage(runs[0] / LOG_FILE)
    out = tmp_path / "report"
    out.mkdir()
    stale = out / f".report.{stale_writer_tag()}.tmp.html"
    stale.write_text("half")
    html = write_report(runs, out / "report.html", max_frames=1).read_text()
    table = html.split("<h2>comparison</h2>")[1].split("</table>")[0]
    assert "<th>run</th><th>scene</th><th>method</th>" in table
    assert re.search(r"<td>a/run</td><td>[^<]*/small</td>", table)
    assert re.search(r"<td>b/run</td><td>[^<]*/unpadded</td>", table)
    assert not stale.exists()


def stale_writer_tag() -> str:
    """The host-pid-random part of a temporary name of a writer that no longer runs."""
    from surgsplat.atomic import HOST

    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True)
    return f"{HOST}-{int(ended.stdout)}-0123abcd"


KILLED_WRITER = """
import sys, time
from pathlib import Path
from surgsplat.atomic import write_atomic
def write(handle):
    handle.write(b"half")
    handle.flush()
    print("writing", flush=True)
    time.sleep(600)
write_atomic(Path(sys.argv[1]), write)
"""


def test_a_killed_writers_temporary_goes_with_the_next_write(tmp_path):
    """Class 12: kill -9 during an atomic write leaves a hidden temporary; the next write into
    the folder (by another process) removes it, but not that of a writer still running."""
    folders = [tmp_path / "killed", tmp_path / "running"]
    writers = [subprocess.Popen([sys.executable, "-c", KILLED_WRITER, str(folder / "out.ply")],
                                stdout=subprocess.PIPE, text=True) for folder in folders]
    try:
        for writer in writers:
            assert writer.stdout.readline().strip() == "writing"
        writers[0].send_signal(signal.SIGKILL)
        writers[0].wait(timeout=60)
        assert [path.name for path in folders[0].iterdir() if ".tmp" in path.name]
        for folder in folders:
            write_text_atomic(folder / "other.ply", "whole")
        assert sorted(path.name for path in folders[0].iterdir()) == ["other.ply"]
        assert len(list(folders[1].iterdir())) == 2
    finally:
        for writer in writers:
            writer.kill()
            writer.wait(timeout=60)


def test_a_full_disk_is_named(tmp_path, faults):
    """Class 12: `phantom` on a full disk names its --out (or the file it could not write);
    images written with OpenCV, which reports success on a full disk, fail with their path."""
    out = tmp_path / "phantom"
    line = faults.one_error_line(faults.run_patched(FULL_DISK_NUMPY, "phantom", "--out",
                                                    str(out)))
    assert line.startswith(f"error: {out}") and line.endswith(": No space left on device")
    assert not out.exists() and not list(tmp_path.iterdir())
    full = tmp_path / "frame.png"
    full.symlink_to("/dev/full")
    with pytest.raises(OSError, match="No space left on device") as caught:
        write_image(full, np.zeros((16, 16, 3), np.uint8))
    assert caught.value.filename == str(full)


def test_info_names_a_bad_depth_scale(small_phantom, cli, one_error_line):
    """Class 12: --depth-scale nan is refused as the option's value, not blamed on a file."""
    for value in ("nan", "inf", "0"):
        line = one_error_line(cli("info", str(small_phantom), "--depth-scale", value))
        assert line.startswith("error: --depth-scale must be a positive finite number")
