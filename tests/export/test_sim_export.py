"""`surgsplat export RUN --sim DIR`: the scene loads and runs in MuJoCo and PyBullet, and bad
runs give one clear line. One small physiosplat run (few iterations) serves every test."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from surgsplat.export.ply import read_gaussian_ply
from surgsplat.export.sim_check import jaw_sweep, probe_drop, urdf_sweep

pytest.importorskip("mujoco")
pytest.importorskip("pybullet")

FRAME = 8


@pytest.fixture(scope="module")
def exported(small_phantom: Path, tmp_path_factory, cli) -> tuple[Path, Path]:
    """(run folder, simulation folder of frame FRAME) of a 30-iteration physiosplat run."""
    root = tmp_path_factory.mktemp("sim")
    run, sim = root / "run", root / "sim"
    trained = cli("train", "--method", "physiosplat", "--data", str(small_phantom),
                  "--out", str(run), "--iters", "30")
    assert trained.returncode == 0, trained.stderr
    assert (run / "articulation.json").is_file()  # written at the end of training
    done = cli("export", str(run), "--sim", str(sim), "--frame", str(FRAME))
    assert done.returncode == 0, done.stderr
    return run, sim


@pytest.mark.slow
def test_files_are_in_metres_and_the_ply_is_the_frames_gaussians(exported):
    run, sim = exported
    meta = json.loads((sim / "sim.json").read_text())
    assert meta["scale_m_per_unit"] == 1e-3 and meta["frame"] == FRAME
    assert "scale = 0.001 m per mm" in (sim / "scene.xml").read_text()
    assert "scale = 0.001 m per mm" in (sim / "tool.urdf").read_text()
    gaussians = read_gaussian_ply(sim / "gaussians.ply")
    assert gaussians.means.shape[0] == meta["gaussians"] > 0
    extent = float(gaussians.means.abs().max())
    assert 0.01 < extent < 1.0  # the phantom's tens of millimetres, in metres


@pytest.mark.slow
def test_mujoco_jaws_follow_their_command_and_a_probe_rests_on_the_tissue(exported):
    _, sim = exported
    sweep = jaw_sweep(sim / "scene.xml", steps=1000)
    assert sweep["finite"]
    assert sweep["max_tracking_error_deg"] < 2.0
    assert sweep["max_beyond_limits_deg"] < 0.5
    achieved_deg = np.array(sweep["trace"]["achieved_deg"]).T  # [joint, sample]
    for (low, high), achieved in zip(sweep["range_deg"], achieved_deg):
        assert achieved.max() - achieved.min() > 0.9 * (high - low)  # the whole range is swept
    probe = probe_drop(sim / "scene.xml", sim / "tissue.obj")
    assert probe["finite"] and probe["fell_m"] > 0.004
    assert probe["speed_m_s"] < 0.01
    assert abs(probe["contact_distance_mm"]) <= 1.0


@pytest.mark.slow
def test_pybullet_loads_the_urdf_and_moves_the_jaws(exported):
    _, sim = exported
    result = urdf_sweep(sim / "tool.urdf")
    assert result["joints"] == ["jaw_a", "jaw_b"]
    for end, index in (("lower", 0), ("upper", 1)):
        reached = np.array(result["reached_rad"][end])
        target = np.array([limits[index] for limits in result["limits_rad"]])
        np.testing.assert_allclose(reached, target, atol=0.02)


@pytest.mark.slow
def test_missing_or_corrupt_runs_give_one_clear_line(exported, tmp_path, cli, one_error_line):
    run, _ = exported
    missing = one_error_line(cli("export", str(tmp_path / "nothing"), "--sim", str(tmp_path / "a")))
    assert "nothing" in missing
    out_of_range = one_error_line(cli("export", str(run), "--sim", str(tmp_path / "f"),
                                      "--frame", "9999"))
    assert "--frame" in out_of_range and "9999" in out_of_range
    assert "nothing" in one_error_line(cli("articulate", str(tmp_path / "nothing")))
    broken = tmp_path / "broken"
    shutil.copytree(run, broken)
    (broken / "articulation.json").write_text("{not json")
    assert "articulation.json" in one_error_line(
        cli("export", str(broken), "--sim", str(tmp_path / "b")))
    (broken / "articulation.json").unlink()
    (broken / "checkpoints" / "latest.pt").write_bytes(b"garbage")
    assert "latest.pt" in one_error_line(cli("export", str(broken), "--sim", str(tmp_path / "c")))
