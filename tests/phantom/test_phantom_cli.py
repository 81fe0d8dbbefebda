"""`surgsplat phantom`: writes a loadable scene and prints its summary; bad options are one line."""

from pathlib import Path

from surgsplat.data.scene import load_scene


def test_phantom_command_writes_scene(tmp_path: Path, cli):
    out = tmp_path / "scene"
    result = cli("phantom", "--out", str(out), "--motion", "cutting", "--frames", "3",
                 "--seed", "2")
    assert result.returncode == 0, result.stderr
    assert "scene summary" in result.stdout and "phantom written to" in result.stdout
    scene = load_scene(out)
    assert len(scene.frames) == 3 and scene.meta.extra["motion"] == "cutting"
    assert scene.meta.extra["seed"] == 2


def test_phantom_command_rejects_unknown_preset(tmp_path: Path, cli):
    result = cli("phantom", "--out", str(tmp_path / "x"), "--preset", "huge")
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    assert "valid presets: small, full" in result.stderr
    assert not (tmp_path / "x").exists()


def test_phantom_command_moving_camera(tmp_path: Path, cli):
    out = tmp_path / "moving"
    result = cli("phantom", "--out", str(out), "--camera", "moving", "--frames", "3")
    assert result.returncode == 0, result.stderr
    assert "moving, centre travels" in result.stdout
    scene = load_scene(out)
    assert scene.has_moving_camera and scene.meta.extra["camera"] == "moving"
