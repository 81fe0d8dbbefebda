"""Results are tied to what they score: metrics.json names its scene, method and iteration; eval,
render and resume refuse another scene (one line saying what differs); a moved scene is found
with --data; demo never silently reuses a run made with other options; edge values are one
line."""

import json
import shutil

import cv2
import numpy as np
import torch


def test_results_against_the_wrong_scene(small_phantom, tmp_path, cli, one_error_line):
    scene = shutil.copytree(small_phantom, tmp_path / "scene")
    run = tmp_path / "run"
    trained = cli("train", "--data", str(scene), "--out", str(run), "--iters", "3",
                  "--set", "init.max_points=1500")
    assert trained.returncode == 0, trained.stderr
    identity = json.loads((run / "scene.json").read_text())
    assert identity["frames"] == 16 and (identity["width"], identity["height"]) == (160, 128)

    other = shutil.copytree(scene, tmp_path / "other")
    image = sorted((other / "images").iterdir())[0]
    pixels = cv2.imread(str(image))
    pixels[0, 0] ^= 255
    cv2.imwrite(str(image), pixels)
    for args in (("eval", str(run), "--data", str(other)),
                 ("render", str(run), "--data", str(other)),
                 ("train", "--out", str(run), "--resume", "--iters", "4", "--data", str(other))):
        assert "other content" in one_error_line(cli(*args))
    for folder in ("images", "depth", "masks"):
        sorted((other / folder).iterdir())[-1].unlink()
    np.save(other / "poses_bounds.npy", np.load(other / "poses_bounds.npy")[:-1])
    assert "15 frames, the run's has 16" in one_error_line(cli("eval", str(run), "--data",
                                                               str(other)))
    assert not (run / "metrics.json").exists()

    moved = tmp_path / "moved"
    scene.rename(moved)
    assert "pass --data" in one_error_line(cli("eval", str(run)))
    evaluated = cli("eval", str(run), "--data", str(moved), "--no-geometry")
    assert evaluated.returncode == 0, evaluated.stderr
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["method"] == "deform3dgs" and metrics["iteration"] == 3
    assert metrics["scene"] == {**identity, "path": str(moved.resolve())}
    assert "15 frames" in one_error_line(cli("export", str(run), "--ply", "--data", str(other)))


def test_resume_with_another_method_or_fewer_iterations(small_phantom, tmp_path, cli,
                                                       one_error_line):
    run = tmp_path / "run"
    assert cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "3",
               "--set", "init.max_points=1500").returncode == 0
    assert "holds a 'deform3dgs' run" in one_error_line(
        cli("train", "--out", str(run), "--resume", "--method", "endogaussian"))
    assert "cannot be shortened" in one_error_line(cli("train", "--out", str(run), "--resume",
                                                       "--iters", "2"))
    latest = run / "checkpoints" / "latest.pt"
    state = torch.load(latest, weights_only=True)
    torch.save({**state, "method": "endogaussian"}, latest)  # whole, but of another method
    for args in (("eval", str(run)), ("train", "--out", str(run), "--resume", "--iters", "5")):
        assert "holds a 'endogaussian' run, not 'deform3dgs'" in one_error_line(cli(*args))


def test_demo_never_silently_reuses_another_run(small_phantom, tmp_path, cli, one_error_line):
    out = tmp_path / "demo"
    shutil.copytree(small_phantom, out / "phantom")
    assert cli("train", "--data", str(out / "phantom"), "--out", str(out / "run"), "--iters",
               "3").returncode == 0
    line = one_error_line(cli("demo", "--out", str(out), "--method", "endogaussian", "--iters",
                              "5"))
    assert "holds a demo run of deform3dgs for 3 iterations, not endogaussian for 5" in line


def test_edge_values_are_one_line(small_phantom, tmp_path, cli, one_error_line):
    for fps in ("-5", "0", "nan", "inf"):
        assert "--fps must be a number in (0, 1000]" in one_error_line(
            cli("render", str(tmp_path), "--fps", fps))
    tiny = shutil.copytree(small_phantom, tmp_path / "tiny", ignore=shutil.ignore_patterns("gt"))
    for folder in ("images", "depth", "masks"):
        for path in (tiny / folder).iterdir():
            cv2.imwrite(str(path), cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[:1, :1])
    poses = np.load(tiny / "poses_bounds.npy")
    poses[:, 4], poses[:, 9] = 1, 1
    np.save(tiny / "poses_bounds.npy", poses)
    (tiny / "fov_mask.png").unlink(missing_ok=True)
    (tiny / "scene.json").unlink(missing_ok=True)
    line = one_error_line(cli("train", "--data", str(tiny), "--out", str(tmp_path / "run")))
    assert "is 1x1 (HxW); surgsplat needs frames of at least 16x16 pixels" in line
