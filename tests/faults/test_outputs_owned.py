"""The commands that read a finished run (eval, render, export, report, view): a run read with
its own scene only, no user's file replaced, every option's range and conflicts refused in one
line, reports that say which frames their figures are over, and addresses a browser opens."""

from __future__ import annotations

import errno
import re
import select
import shutil
import socket
import time
from pathlib import Path

import pytest

from surgsplat.atomic import write_text_atomic
from surgsplat.pipeline.run_folders import OWNED_MARK
from surgsplat.train.trainer import SCENE_ID_FILE

from .conftest import TRAIN_FAST
from .test_folders import READ_ONLY


@pytest.fixture(scope="module")
def pristine(small_phantom, tmp_path_factory, cli) -> Path:
    """A run of 6 iterations of the small phantom."""
    run = tmp_path_factory.mktemp("trained") / "run"
    done = cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "6",
               *TRAIN_FAST)
    assert done.returncode == 0, done.stderr
    return run


@pytest.fixture
def run(pristine, tmp_path) -> Path:
    """A copy of the trained run that the test may change."""
    return shutil.copytree(pristine, tmp_path / "run")


def files_of(folder: Path) -> dict[Path, bytes]:
    """Every file under `folder` with its content."""
    return {path: path.read_bytes() for path in folder.rglob("*") if path.is_file()}


def test_a_run_without_its_scene_record_is_not_read_with_another_scene(
        run, small_phantom, tmp_path, cli, one_error_line):
    other = shutil.copytree(small_phantom, tmp_path / "other")
    (run / SCENE_ID_FILE).unlink()
    for args in (("eval", str(run)), ("render", str(run)), ("export", str(run), "--ply")):
        line = one_error_line(cli(*args, "--data", str(other)))
        assert line.startswith(f"error: {run / SCENE_ID_FILE}: missing: the run's record of its "
                               f"scene is gone, so --data {other} cannot be checked"), line
    assert not (run / "metrics.json").exists() and not (run / "videos").exists()


def test_render_and_export_refuse_a_folder_of_the_users_files(run, tmp_path, cli,
                                                              one_error_line):
    own = {"myvids": "rgb.mp4", "mysim": "scene.xml", "myply": "000000.ply"}
    for folder, name in own.items():
        (tmp_path / folder).mkdir()
        (tmp_path / folder / name).write_bytes(b"the user's own file\n")
    before = files_of(tmp_path)
    for folder, option, args in (
            ("myvids", "--out", ("render", str(run), "--channels", "rgb", "--out")),
            ("mysim", "--sim", ("export", str(run), "--sim")),
            ("myply", "--out", ("export", str(run), "--ply", "--out"))):
        line = one_error_line(cli(*args, str(tmp_path / folder)))
        assert line.startswith(f"error: {tmp_path / folder}: is not empty and is not a folder "
                               f"surgsplat writes into; choose a new or empty {option} ("), line
    assert files_of(tmp_path) == before


def test_render_and_export_write_again_into_a_folder_they_claimed(run, tmp_path, cli):
    outputs = tmp_path / "outputs"
    for args in (("render", str(run), "--channels", "rgb", "--fps", "5", "--out"),
                 ("render", str(run), "--channels", "rgb", "--fps", "5", "--out"),
                 ("export", str(run), "--ply", "--frames", "0", "--out")):
        done = cli(*args, str(outputs))
        assert done.returncode == 0, done.stderr
    assert sorted(path.name for path in outputs.iterdir()) == [OWNED_MARK, "000000.ply",
                                                                "rgb.mp4"]


def test_export_refuses_frames_it_would_ignore_or_repeat(run, cli, one_error_line):
    both = one_error_line(cli("export", str(run), "--ply", "--time", "0.5", "--frames", "3"))
    assert both == "error: --frames and --time both choose the moments to export; pass one"
    repeated = one_error_line(cli("export", str(run), "--ply", "--frames", "1,1,1"))
    assert repeated.startswith("error: --frames: frame 1 is named more than once")
    written = cli("export", str(run), "--ply", "--frames", "1,3")
    assert written.returncode == 0, written.stderr
    assert "2 PLY file(s)" in written.stdout
    assert sorted(path.name for path in (run / "export" / "ply").iterdir()) == ["000001.ply",
                                                                                "000003.ply"]


def test_export_refuses_a_mesh_resolution_past_its_bound(run, cli, one_error_line):
    line = one_error_line(cli("export", str(run), "--mesh", "--mesh-resolution", "100000"))
    assert line.startswith("error: --mesh-resolution must be in 8..512"), line


def test_report_refuses_a_negative_frame_count(run, tmp_path, cli, one_error_line):
    out = tmp_path / "report.html"
    line = one_error_line(cli("report", str(run), "--frames", "-3", "--out", str(out)))
    assert line == "error: --frames must be 0 or more (test frames shown per run), got -3"
    assert not out.exists()


def test_the_report_says_which_frames_each_run_is_scored_on(pristine, tmp_path, cli):
    fit, held_out = (shutil.copytree(pristine, tmp_path / "runs" / name)
                     for name in ("fit", "held_out"))
    for run, frames in ((fit, "train"), (held_out, "test")):
        assert cli("eval", str(run), "--frames", frames, "--no-geometry").returncode == 0
    out = tmp_path / "report.html"
    done = cli("report", str(fit), str(held_out), "--frames", "0", "--out", str(out))
    assert done.returncode == 0, done.stderr
    page = out.read_text()
    table = page[page.index("<h2>comparison</h2>"):page.index("<h2>training curves</h2>")]
    assert "<th>method</th><th>frames scored</th>" in table
    assert re.search(r"<td>fit</td>.*?<td>train \(14\)</td>", table)
    assert re.search(r"<td>held_out</td>.*?<td>test \(2\)</td>", table)


def test_report_out_that_cannot_be_written_names_out(run, tmp_path, cli, faults):
    folder = tmp_path / "a folder"
    folder.mkdir()
    line = faults.one_error_line(cli("report", str(run), "--frames", "0", "--out", str(folder)))
    assert line == (f"error: --out {folder}: is a folder; expected the HTML file to write, e.g. "
                    f"{folder / 'report.html'}")
    own = tmp_path / "notes.html"
    own.write_text("<p>the user's notes</p>\n")
    line = faults.one_error_line(cli("report", str(run), "--frames", "0", "--out", str(own)))
    assert line.startswith(f"error: --out {own}: exists and is not a report surgsplat wrote")
    assert own.read_text() == "<p>the user's notes</p>\n"
    read_only = tmp_path / "read-only"
    read_only.mkdir()
    patched = faults.run_patched(READ_ONLY.format(root=str(read_only)), "report", str(run),
                                 "--frames", "0", "--out", str(read_only / "report.html"))
    line = faults.one_error_line(patched)
    assert line == f"error: --out {read_only / 'report.html'}: Read-only file system"


def test_an_atomic_write_error_names_the_target_not_its_temporary(tmp_path):
    target = tmp_path / "metrics.json"
    target.mkdir()
    with pytest.raises(OSError) as caught:
        write_text_atomic(target, "{}")
    error = caught.value
    assert (error.errno, error.filename, error.filename2) == (errno.EISDIR, str(target), None)
    assert [path.name for path in tmp_path.iterdir()] == ["metrics.json"]


def free_ipv6_loopback_port() -> int:
    """A port of ::1 that no server listens on now."""
    with socket.socket(socket.AF_INET6) as probe:
        probe.bind(("::1", 0))
        return probe.getsockname()[1]


def line_starting(process, start: str, seconds: float = 120.0) -> str:
    """The first line of `process`'s standard output that begins with `start` (viser prints
    its own banner around it)."""
    deadline = time.monotonic() + seconds
    while (left := deadline - time.monotonic()) > 0:
        ready, _, _ = select.select([process.stdout], [], [], left)
        line = process.stdout.readline() if ready else ""
        if line.startswith(start):
            return line.strip()
        if ready and not line:
            break  # the process ended
    raise AssertionError(f"no line starting {start!r} within {seconds} s")


def test_view_on_an_ipv6_host_prints_a_url(pristine, faults):
    port = free_ipv6_loopback_port()
    viewer = faults.start("view", str(pristine), "--host", "::1", "--port", str(port))
    assert line_starting(viewer, "viewer at") == (f"viewer at http://[::1]:{port} (Ctrl-C stops "
                                                  "it)")
