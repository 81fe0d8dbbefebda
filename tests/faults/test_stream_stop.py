"""Ctrl-C during `surgsplat stream`: the stream ends there and the run of the frames that came
is finished, an ordinary run."""

from __future__ import annotations

import json
import signal
import threading

import pytest

from surgsplat.data.layout import IMAGES_DIR
from surgsplat.pipeline.stream import STREAM_LOG, STREAM_SUMMARY
from surgsplat.pipeline.stream_scene import LIVE_FILE
from surgsplat.train.run import load_trained_run

pytestmark = pytest.mark.slow  # a stream in a process of its own, stopped by a signal


def test_ctrl_c_ends_the_stream_and_keeps_the_run(small_phantom, tmp_path, faults):
    incoming = tmp_path / "incoming"
    (incoming / IMAGES_DIR).mkdir(parents=True)
    frames = sorted((small_phantom / IMAGES_DIR).iterdir())
    stop_writing = threading.Event()

    def write() -> None:  # a frame every 0.2 s, far more than the stream will take
        for index in range(200):
            source = frames[index % len(frames)]
            part = incoming / IMAGES_DIR / f"{index:06d}.png.part"
            part.write_bytes(source.read_bytes())
            part.rename(incoming / IMAGES_DIR / f"{index:06d}.png")
            if stop_writing.wait(0.2):
                return

    writer = threading.Thread(target=write, daemon=True)
    writer.start()
    run = tmp_path / "run"
    process = faults.start("stream", str(incoming), "--out", str(run), "--idle-timeout", "30")
    try:
        faults.wait_for(lambda: (run / STREAM_LOG).is_file()
                        and len((run / STREAM_LOG).read_text().splitlines()) >= 6,
                        what="six frames streamed")
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=120)
    finally:
        stop_writing.set()
        writer.join()
    assert process.returncode == 0 and "Traceback" not in stderr, stderr
    summary = json.loads((run / STREAM_SUMMARY).read_text())
    assert summary["stopped_by_user"] and summary["untrained_frames"] == 0
    assert 6 <= summary["frames"] < 200
    assert not (run / LIVE_FILE).exists()
    trained = load_trained_run(run)
    assert len(trained.scene.frames) == summary["frames"]
    assert "streamed" in stdout
