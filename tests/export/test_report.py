"""The HTML report: self-contained, every image decodes, and a real browser renders it."""

from __future__ import annotations

import base64
import re

import cv2
import numpy as np
import pytest

from surgsplat.data.scene import load_scene
from surgsplat.methods.registry import method_config
from surgsplat.train.trainer import Trainer


@pytest.fixture(scope="module")
def two_runs(small_phantom, tmp_path_factory):
    folder = tmp_path_factory.mktemp("runs")
    runs = []
    for method in ("deform3dgs", "endoplanar"):
        config = method_config(method)
        config.train.iterations = 20
        config.init.max_points = 2000
        Trainer(config, load_scene(small_phantom), folder / method).fit()
        runs.append(folder / method)
    return runs


def test_report_of_two_runs(two_runs, cli, tmp_path):
    out = tmp_path / "report.html"
    done = cli("report", *map(str, two_runs), "--out", str(out), "--frames", "2")
    assert done.returncode == 0, done.stderr
    page = out.read_text()
    assert "<script" not in page and "http" not in page  # nothing to fetch: opens offline
    assert "comparison" in page and "psnr_tissue" in page and "endoplanar" in page
    images = re.findall(r"src='data:image/png;base64,([^']+)'", page)
    assert len(images) == 1 + 2 * 2  # curves + two frames of each run
    for data in images:
        image = cv2.imdecode(np.frombuffer(base64.b64decode(data), np.uint8), cv2.IMREAD_COLOR)
        assert image is not None and image.std() > 1.0  # decodes, and is not blank


@pytest.mark.slow  # a real chromium
def test_a_browser_opens_the_report(two_runs, cli, browser, tmp_path):
    out = tmp_path / "report.html"
    assert cli("report", str(two_runs[0]), "--out", str(out), "--frames", "2").returncode == 0
    shot, errors = browser.visit(out.as_uri(), 3.0)
    assert errors == []
    screenshot = cv2.imdecode(np.frombuffer(shot, np.uint8), cv2.IMREAD_COLOR)
    (two_runs[0] / "report-screenshot.png").write_bytes(shot)
    assert screenshot.std() > 10.0  # the page rendered content, not a blank canvas


def test_report_errors_are_one_line(cli, tmp_path):
    done = cli("report", str(tmp_path / "missing"))
    assert done.returncode == 2 and "config.json" in done.stderr and "Traceback" not in done.stderr
