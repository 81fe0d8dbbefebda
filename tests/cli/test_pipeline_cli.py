"""train -> eval -> render through the CLI on the small phantom, and the one-line errors a user
meets on the way (existing run without --resume, resume without a checkpoint, unknown method)."""

import json

import pytest


@pytest.mark.slow  # the whole pipeline through the CLI, 22 s: the fast tier stays under 90 s
def test_train_eval_render(small_phantom, tmp_path, cli, one_error_line):
    run = tmp_path / "run"
    trained = cli("train", "--method", "deform3dgs", "--data", str(small_phantom), "--out", str(run),
                  "--iters", "6")
    assert trained.returncode == 0, trained.stderr
    assert "already holds a run" in one_error_line(
        cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "6"))
    resumed = cli("train", "--out", str(run), "--resume", "--iters", "9")
    assert resumed.returncode == 0, resumed.stderr
    assert "resuming" in resumed.stdout and "trained 9 iterations" in resumed.stdout

    evaluated = cli("eval", str(run))
    assert evaluated.returncode == 0, evaluated.stderr
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["iteration"] == 9 and metrics["test_frames"] == 2
    assert "psnr_tissue" in metrics and "chamfer_mm" in metrics
    assert metrics["evaluated_on"] == "test"

    on_train = cli("eval", str(run), "--frames", "train")
    assert on_train.returncode == 0, on_train.stderr
    assert "train-frame metrics" in on_train.stdout
    fit = json.loads((run / "metrics.json").read_text())
    assert fit["evaluated_on"] == "train" and fit["test_frames"] == 14  # 16 frames, 2 held out
    assert fit["psnr_tissue"] != metrics["psnr_tissue"]
    assert "expected test or train" in one_error_line(cli("eval", str(run), "--frames", "all"))

    rendered = cli("render", str(run), "--fps", "5")
    assert rendered.returncode == 0, rendered.stderr
    for name in ("rgb.mp4", "depth.mp4", "normal.mp4", "side_by_side.mp4"):
        assert (run / "videos" / name).stat().st_size > 1000


def test_user_mistakes_are_one_line(small_phantom, tmp_path, cli, one_error_line):
    assert "nothing to resume" in one_error_line(cli("train", "--out", str(tmp_path / "x"),
                                                     "--resume"))
    assert "unknown method" in one_error_line(
        cli("train", "--method", "nope", "--data", str(small_phantom), "--out", str(tmp_path / "y")))
    assert "config.json" in one_error_line(cli("eval", str(tmp_path)))


def test_methods_lists_every_preset(cli):
    listed = cli("methods")
    assert listed.returncode == 0, listed.stderr
    for name in ("deform3dgs", "endogaussian", "endoplanar"):
        assert name in listed.stdout
    shown = cli("methods", "endoplanar")
    assert shown.returncode == 0 and json.loads(shown.stdout)["losses"]["normal"]["weight"] > 0


def test_set_and_config_reproduce_a_run(small_phantom, tmp_path, cli):
    first = tmp_path / "first"
    trained = cli("train", "--method", "endoplanar", "--data", str(small_phantom), "--out",
                  str(first), "--set", "train.iterations=5", "--set", "losses.normal.weight=0.5",
                  "--set", "losses.normal.start=0")
    assert trained.returncode == 0, trained.stderr
    saved = json.loads((first / "config.json").read_text())
    assert saved["losses"]["normal"]["weight"] == 0.5 and saved["train"]["iterations"] == 5
    again = tmp_path / "again"
    reproduced = cli("train", "--config", str(first / "config.json"), "--data", str(small_phantom),
                     "--out", str(again))
    assert reproduced.returncode == 0, reproduced.stderr
    assert json.loads((again / "config.json").read_text()) == saved
    log = [json.loads(line) for line in (first / "train_log.jsonl").read_text().splitlines()]
    log_again = [json.loads(line) for line in (again / "train_log.jsonl").read_text().splitlines()]
    assert [e["terms"] for e in log] == [e["terms"] for e in log_again]


def test_bad_settings_are_one_line(small_phantom, tmp_path, cli, one_error_line):
    out = str(tmp_path / "z")
    assert "--set.train.iterations: expected an integer" in one_error_line(
        cli("train", "--data", str(small_phantom), "--out", out, "--set", "train.iterations=x"))
    assert "losses.nope: no component of this method computes" in one_error_line(
        cli("train", "--data", str(small_phantom), "--out", out, "--set", "losses.nope.weight=1"))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert "bad.json: cannot be read as a config file" in one_error_line(
        cli("train", "--data", str(small_phantom), "--out", out, "--config", str(bad)))
