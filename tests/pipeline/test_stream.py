"""`surgsplat stream`: a folder written frame by frame while the stream trains, the run it
leaves (an ordinary run: evaluation, the lag log), and bad sources."""

from __future__ import annotations

import importlib
import json
import os
import shutil
import threading
import time
from pathlib import Path

import cv2
import pytest

from surgsplat.data.layout import DEPTH_DIR, IMAGES_DIR, MASKS_DIR, META_FILE, POSES_FILE
from surgsplat.export.viewer import FOLLOW_SECONDS, RunViewer, view_image
from surgsplat.methods.registry import DEFAULT_PRESET, PRESETS, method_config
from surgsplat.model.component import SceneInfo
from surgsplat.pipeline.evaluate import evaluate
from surgsplat.pipeline.stream import STREAM_LOG, STREAM_SUMMARY, StreamOptions, stream_run
from surgsplat.pipeline.stream_scene import LIVE_FILE, LiveFollower, load_live_run
from surgsplat.train.checkpoint import build_components
from surgsplat.train.run import LOCK_FILE, load_trained_run
from surgsplat.train.stream import check_streamable, streamable_methods

RATE = 10.0
"""Frames per second the test's writer writes the small phantom at."""


def write_frames(scene: Path, into: Path, rate: float, corrupt: int | None = None,
                 after: Path | None = None) -> threading.Thread:
    """A thread copying `scene`'s frames into the scene folder `into`, as a camera's recorder
    would: scene.json and poses first, then each frame's depth, mask and image (renamed into
    place, the image last) at `rate` frames per second, starting half a second after the file
    `after` appears (if given); frame `corrupt` (if given) is written cut in half."""
    into.mkdir(parents=True, exist_ok=True)

    def run() -> None:
        while after is not None and not after.exists():
            time.sleep(0.01)
        time.sleep(0.5)
        for name in (META_FILE, POSES_FILE):
            shutil.copy(scene / name, into / name)
        for sub in (DEPTH_DIR, MASKS_DIR, IMAGES_DIR):
            (into / sub).mkdir(exist_ok=True)
        start = time.monotonic()
        for index, image in enumerate(sorted((scene / IMAGES_DIR).iterdir())):
            time.sleep(max(start + index / rate - time.monotonic(), 0.0))
            for sub in (DEPTH_DIR, MASKS_DIR, IMAGES_DIR):
                source = scene / sub / image.name
                part = into / sub / f"{image.name}.part"
                data = source.read_bytes()
                part.write_bytes(data[: len(data) // 2] if index == corrupt and
                                 sub == IMAGES_DIR else data)
                os.replace(part, into / sub / image.name)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


@pytest.fixture(scope="module")
def streamed(small_phantom, tmp_path_factory, cli):
    """The small phantom streamed from a folder written at RATE frames per second."""
    importlib.import_module("torch._dynamo")  # as the stream does before it starts (2 s)
    root = tmp_path_factory.mktemp("stream")
    run = root / "run"
    writer = write_frames(small_phantom, root / "incoming", RATE, after=run / LOCK_FILE)
    result = cli("stream", str(root / "incoming"), "--out", str(run), "--idle-timeout", "2",
                 "--polish", "1")
    writer.join()
    assert result.returncode == 0, result.stderr
    return run, result


def read_log(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / STREAM_LOG).read_text().splitlines()]


def test_stream_keeps_up_and_logs_every_frame(streamed, small_phantom):
    run, result = streamed
    log = read_log(run)
    frames = len(list((small_phantom / IMAGES_DIR).iterdir()))
    assert [entry["index"] for entry in log] == list(range(frames))
    arrivals = [entry["arrival"] for entry in log]
    # the frames came at RATE: arrivals span (frames - 1) / RATE seconds, in order
    assert arrivals == sorted(arrivals)
    assert arrivals[-1] - arrivals[0] == pytest.approx((frames - 1) / RATE, rel=0.5)
    for entry in log:
        assert (entry["lag"] is None) == entry["is_test"]
        assert entry["psnr_arrival"] > 0 and entry["psnr_final"] > 0
        if not entry["is_test"]:
            assert entry["trained_at"] >= entry["arrival"]
    lags = sorted(entry["lag"] for entry in log if entry["lag"] is not None)
    assert lags[len(lags) // 2] < 1.0, lags  # each frame is trained on within a second
    # training lifts the first frames above where they stood on arrival
    first = [entry for entry in log[:4] if not entry["is_test"]]
    assert all(entry["psnr_final"] > entry["psnr_arrival"] + 3 for entry in first), first
    summary = json.loads((run / STREAM_SUMMARY).read_text())
    assert summary["frames"] == frames and summary["bad_frames"] == []
    assert summary["untrained_frames"] == 0 and summary["polish_steps"] > 0
    assert "median lag" in result.stdout


def test_streamed_run_is_an_ordinary_run(streamed, small_phantom):
    run, _ = streamed
    trained = load_trained_run(run)
    frames = trained.scene.frames
    assert len(frames) == len(list((small_phantom / IMAGES_DIR).iterdir()))
    assert [frame.time for frame in frames] == [i / len(frames) for i in range(len(frames))]
    metrics = evaluate(trained)
    assert metrics["psnr_tissue"] > 20.0, metrics["psnr_tissue"]


def test_corrupt_frame_is_skipped_or_stops(small_phantom, tmp_path, cli):
    for action in ("skip", "stop"):
        incoming = tmp_path / action / "incoming"
        writer = write_frames(small_phantom, incoming, 40.0, corrupt=5)
        run = tmp_path / action / "run"
        result = cli("stream", str(incoming), "--out", str(run), "--idle-timeout", "1",
                     "--on-bad-frame", action)
        writer.join()
        bad = str(incoming / IMAGES_DIR / "000005.png")
        summary = json.loads((run / STREAM_SUMMARY).read_text())
        assert bad in summary["bad_frames"][0]
        if action == "skip":
            assert result.returncode == 0, result.stderr
            assert bad in result.stdout
            assert summary["frames"] == 15
        else:
            assert result.returncode == 2 and "Traceback" not in result.stderr
            assert bad in result.stderr and "--on-bad-frame stop" in result.stderr
            assert summary["frames"] == 5
        assert load_trained_run(run).iteration > 0  # the run so far is kept


def test_bad_sources_get_one_line(tmp_path, cli, one_error_line):
    empty = tmp_path / "empty"
    empty.mkdir()
    line = one_error_line(cli("stream", str(empty), "--out", str(tmp_path / "a"),
                              "--idle-timeout", "0.3"))
    assert str(empty) in line and "no frame in 0.3 s" in line
    line = one_error_line(cli("stream", "97", "--out", str(tmp_path / "b")))
    assert "camera 97" in line and "does not open" in line
    line = one_error_line(cli("stream", str(tmp_path / "missing.mp4"), "--out",
                              str(tmp_path / "c")))
    assert "missing.mp4" in line and "does not exist" in line


def test_methods_that_cannot_follow_a_growing_clip_are_refused(small_phantom, tmp_path, cli,
                                                               one_error_line):
    result = cli("stream", str(small_phantom), "--out", str(tmp_path / "run"),
                 "--method", "endogaussian", "--idle-timeout", "0.5")
    assert result.returncode == 2, result
    line = one_error_line(result)
    assert "cannot stream" in line and "'deformation'" in line
    assert f"methods that stream: {', '.join(streamable_methods())}" in line


def test_the_default_method_streams():
    """The default method (`surgsplat stream` without --method) can stream: its components
    follow a growing clip and its loss terms have no window."""
    config = PRESETS[DEFAULT_PRESET].build().resolved(SceneInfo(16, 160, 128, tuple(range(16))))
    check_streamable(config, build_components(config))
    assert DEFAULT_PRESET in streamable_methods()


def test_view_follows_a_stream_in_progress(small_phantom, tmp_path):
    """While a stream trains, RUN/live.json lets the run be read at its latest checkpoint, and
    a viewer given a LiveFollower moves on to each newer one, then to the finished run."""
    pytest.importorskip("viser")
    run = tmp_path / "run"
    run.mkdir()
    writer = write_frames(small_phantom, tmp_path / "incoming", 6.0)
    options = StreamOptions(source=str(tmp_path / "incoming"), out=run, idle_timeout=5.0,
                            checkpoint_seconds=1.0)
    config = method_config("deform3dgs")
    streaming = threading.Thread(target=stream_run, args=(config, options))
    streaming.start()
    deadline = time.monotonic() + 60
    while not (run / LIVE_FILE).is_file() and time.monotonic() < deadline:
        time.sleep(0.05)
    live = load_live_run(run)
    total = len(list((small_phantom / IMAGES_DIR).iterdir()))
    assert 1 <= len(live.scene.frames) < total
    image = view_image(live, live.scene.frames[-1].camera, len(live.scene.frames) - 1, "rgb")
    assert image.shape == (128, 160, 3) and image.std() > 0
    viewer = RunViewer(live, port=0, follow=LiveFollower(run, live))
    try:
        counts = {len(live.scene.frames)}
        while streaming.is_alive() or (run / LIVE_FILE).exists() or \
                len(viewer.run.scene.frames) != total:
            assert time.monotonic() < deadline, counts
            counts.add(len(viewer.run.scene.frames))
            time.sleep(FOLLOW_SECONDS / 10)
        assert len(counts) > 2  # it showed the stream's checkpoints as they came
        assert viewer.time_slider.max == total - 1 and viewer.time_slider.value == total - 1
        assert viewer.run.iteration == load_trained_run(run).iteration
    finally:
        viewer.stop()
        streaming.join()
        writer.join()


def test_video_with_automatic_tool_masks(small_phantom, tmp_path, cli):
    """A video file played at --rate, its tool masks found by the automatic segmenter as the
    frames arrive: every frame is in the run's scene with a mask, arriving 1 / rate apart."""
    video = tmp_path / "clip.mp4"
    images = sorted((small_phantom / IMAGES_DIR).iterdir())
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), 25.0, (160, 128))
    for image in images:
        writer.write(cv2.imread(str(image)))
    writer.release()
    run = tmp_path / "run"
    result = cli("stream", str(video), "--out", str(run), "--rate", "20", "--tool-masks", "auto")
    assert result.returncode == 0, result.stderr
    log = read_log(run)
    assert len(log) == len(images)
    arrivals = [entry["arrival"] for entry in log]
    assert arrivals[-1] - arrivals[0] == pytest.approx((len(images) - 1) / 20, rel=0.2)
    assert len(list((run / "scene" / MASKS_DIR).iterdir())) == len(images)
    assert json.loads((run / STREAM_SUMMARY).read_text())["tool_masks"] == "auto"
