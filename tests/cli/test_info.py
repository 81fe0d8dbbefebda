"""`surgsplat info`: a summary for a good scene, one clear line for a bad one."""

import json
from pathlib import Path

import numpy as np

from surgsplat.data.layout import SceneMeta, SceneWriter


def test_info_prints_summary(tmp_path: Path, cli):
    writer = SceneWriter(tmp_path / "s", focal=20.0, meta=SceneMeta(depth_unit="mm"))
    for i in range(10):
        writer.add_frame(np.full((16, 20, 3), 10 * i, dtype=np.uint8), np.full((16, 20), 50.0))
    scene_dir = str(writer.finish())
    result = cli("info", scene_dir)
    assert result.returncode == 0, result.stderr
    assert "scene summary" in result.stdout and "mm" in result.stdout
    summary = json.loads(cli("info", scene_dir, "--json").stdout)
    assert (summary["num_frames"], summary["num_train"], summary["num_test"]) == (10, 8, 2)
    assert summary["depth_min"] == summary["depth_max"] == 50.0


def test_info_on_bad_scene_is_one_line_without_traceback(tmp_path: Path, cli):
    result = cli("info", str(tmp_path / "missing"))
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error:") and "missing" in lines[0]
