"""The viewer: a real viser server, a real headless browser, and surgsplat's frames in it."""

from __future__ import annotations

import socket
import time

import cv2
import numpy as np
import pytest

from surgsplat.data.scene import load_scene
from surgsplat.export.viewer import RunViewer
from surgsplat.methods.registry import method_config
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import Trainer

pytest.importorskip("viser")


def central_correlation(first: np.ndarray, second: np.ndarray) -> float:
    """Correlation of the grey levels of the central thirds of two RGB images, at 64x64."""
    def centre(image):
        height, width = image.shape[:2]
        crop = image[height // 3: 2 * height // 3, width // 3: 2 * width // 3]
        grey = cv2.cvtColor(np.ascontiguousarray(crop), cv2.COLOR_RGB2GRAY)
        return cv2.resize(grey, (64, 64), interpolation=cv2.INTER_AREA).astype(float).ravel()

    return float(np.corrcoef(centre(first), centre(second))[0, 1])


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


@pytest.fixture(scope="module")
def run_dir(small_phantom, tmp_path_factory):
    config = method_config("deform3dgs")
    config.train.iterations = 30
    config.init.max_points = 3000
    folder = tmp_path_factory.mktemp("viewer") / "run"
    Trainer(config, load_scene(small_phantom), folder).fit()
    return folder


@pytest.mark.slow  # a real viser server and a real chromium
def test_browser_shows_the_render_and_the_slider_changes_the_frame(run_dir, browser):
    viewer = RunViewer(load_trained_run(run_dir), port=free_port())
    try:
        shot, errors = browser.visit(f"http://127.0.0.1:{viewer.server.get_port()}", 30.0,
                                     until=lambda: viewer.frames_sent > 0, settle=4.0)
        assert viewer.frames_sent > 0 and viewer.last.index == 0
        first = viewer.last.image
        screenshot = cv2.imdecode(np.frombuffer(shot, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
        (run_dir / "viewer-screenshot.png").write_bytes(shot)
        # The page shows the render, not a blank canvas: the central thirds of the screenshot
        # and of the rendered frame (which fills the canvas) correlate, and are tissue-red.
        # (Correlation, not equality: viser fades a new background in from white.)
        assert central_correlation(screenshot, first) > 0.8
        centre = screenshot[screenshot.shape[0] // 3: 2 * screenshot.shape[0] // 3].mean((0, 1))
        assert centre[0] > centre[2] + 20  # red over blue, as the tissue is

        sent = viewer.frames_sent
        viewer.time_slider.value = 9  # through the server API
        deadline = time.monotonic() + 20
        while viewer.frames_sent == sent and time.monotonic() < deadline:
            time.sleep(0.1)
        assert viewer.last.index == 9 and not np.array_equal(viewer.last.image, first)
        assert not [e for e in errors if "WebGL" not in e], errors
    finally:
        viewer.stop()


def test_view_errors_are_one_line(cli, tmp_path):
    done = cli("view", str(tmp_path / "missing"))
    assert done.returncode == 2 and "config.json" in done.stderr and "Traceback" not in done.stderr
    done = cli("view", str(tmp_path), "--port", "0")
    assert done.returncode == 2 and "--port must be" in done.stderr
