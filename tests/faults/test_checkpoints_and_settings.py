"""Damaged checkpoint contents, settings that contradict each other, a run folder raced for or
read from a read-only mount, and a weights file that is not one: one line naming the file or
the options at fault and exit 2, or a clean recovery from the checkpoint kept before."""

from __future__ import annotations

import os
import pickle
import shutil

import pytest
import torch

from surgsplat.methods.overrides import build_method_config
from surgsplat.errors import SurgsplatError
from surgsplat.train.checkpoint import load_checkpoint, previous_path
from surgsplat.train.run import run_lock
from surgsplat.train.trainer import CHECKPOINT, CONFIG_FILE

from .test_folders import READ_ONLY


def cut_opacities(state: dict) -> str:
    state["gaussians"]["opacity_logits"] = state["gaussians"]["opacity_logits"][:-1]
    return "disagree in length"


def cut_a_moment(state: dict) -> str:
    optimizer = state["optimizer"]
    index = next(group["params"][0] for group in optimizer["param_groups"]
                 if group["name"] == "means")
    optimizer["state"][index]["exp_avg"] = optimizer["state"][index]["exp_avg"][:-1]
    return "optimizer.means.exp_avg"


def nan_mean(state: dict) -> str:
    state["gaussians"]["means"][3] = float("nan")
    return "gaussians.means holds values that are not finite"


@pytest.mark.parametrize("damage", [cut_opacities, cut_a_moment, nan_mean])
def test_a_checkpoint_with_damaged_contents_is_named_and_resumed_from_before(trained, cli,
                                                                            faults, damage):
    """Per-Gaussian tensors of different lengths or values that are not finite: eval names the
    file and what is wrong with it; resume continues from previous.pt, to the same end."""
    latest = trained / CHECKPOINT
    state = torch.load(latest, weights_only=True)
    said = damage(state)
    torch.save(state, latest)
    line = faults.one_error_line(cli("eval", str(trained), "--no-geometry"))
    assert line.startswith(f"error: {latest}: is damaged") and said in line, line
    assert "--resume" in line and "diverged" not in line
    resumed = cli("train", "--out", str(trained), "--resume")
    assert resumed.returncode == 0, resumed.stderr
    out = resumed.stdout.replace("\n", "")
    assert str(latest) in out and previous_path(latest).name in out and "resuming" in out
    assert "trained 4 iterations" in out
    assert load_checkpoint(latest)["iteration"] == 4


def test_resume_without_latest_continues_from_previous(trained, cli):
    latest = trained / CHECKPOINT
    latest.unlink()
    resumed = cli("train", "--out", str(trained), "--resume", "--iters", "6")
    assert resumed.returncode == 0, resumed.stderr
    out = resumed.stdout.replace("\n", "")
    assert "resuming" in out and previous_path(latest).name in out
    assert load_checkpoint(latest)["iteration"] == 6


@pytest.mark.parametrize("settings, first, second", [
    (("densify.start=0.9", "densify.stop=0.1"), "densify.stop (0.1)", "densify.start (0.9)"),
    (("losses.depth.start=0.5", "losses.depth.stop=0.5"), "losses.depth.stop (0.5)",
     "losses.depth.start (0.5)"),
    (("components.deformation.num_basis=12", "components.deformation.max_basis=10"),
     "components.deformation.max_basis (10)", "components.deformation.num_basis (12)"),
    (("train.coarse_factor=4", "train.coarse_fraction=0"), "train.coarse_factor (4)",
     "train.coarse_fraction (0.0)"),
    (("train.coarse_factor=1",), "train.coarse_factor (1)", "train.coarse_fraction (0.1)"),
])
def test_settings_that_contradict_each_other_are_one_line_naming_both(
        small_phantom, tmp_path, cli, faults, settings, first, second):
    sets = [arg for setting in settings for arg in ("--set", setting)]
    line = faults.one_error_line(cli("train", "--data", str(small_phantom), "--out",
                                     str(tmp_path / "run"), "--iters", "2", *sets))
    assert first in line and second in line, line
    assert not (tmp_path / "run").exists()


def test_a_rule_between_settings_holds_once_every_setting_is_in():
    """One --set may need a later one to satisfy a rule: the rules are checked at the end."""
    config = build_method_config("deform3dgs", None, ["densify.start=0.9", "densify.stop=0.95"])
    assert (config.densify.start, config.densify.stop) == (0.9, 0.95)
    with pytest.raises(SurgsplatError, match=r"densify.stop \(0.95\) must be greater than "
                                             r"densify.start \(0.97\)"):
        build_method_config("deform3dgs", None, ["densify.stop=0.95", "densify.start=0.97"])


def test_a_saved_config_breaking_a_rule_is_named(trained, cli, faults):
    path = trained / CONFIG_FILE
    path.write_text(path.read_text().replace('"stop": 0.6666666666666666', '"stop": 0.0'))
    line = faults.one_error_line(cli("eval", str(trained), "--no-geometry"))
    assert line == (f"error: {path}.densify.stop (0.0) must be greater than "
                    f"{path}.densify.start (0.0)")


@pytest.mark.parametrize("length, setting", [
    (("--iters", "20"), "train.iterations=30"),
    (("--budget", "5"), "train.iterations=30"),
    (("--iters", "20"), 'train={"budget_seconds": 5}'),
])
def test_the_run_length_given_twice_is_refused(small_phantom, tmp_path, cli, faults, length,
                                               setting):
    line = faults.one_error_line(cli("train", "--data", str(small_phantom), "--out",
                                     str(tmp_path / "run"), *length, "--set", setting))
    assert line == (f"error: {' '.join(length)} and --set {setting} each set the run's "
                    "length: give one")


@pytest.mark.parametrize("started", [(), (CONFIG_FILE,)])
def test_the_loser_of_a_race_for_a_new_run_folder_names_the_winner(small_phantom, tmp_path,
                                                                   cli, faults, started):
    """What the second of two `train --out X` started together sees: the folder holds the
    first one's lock file (and maybe its first run file), the lock held."""
    run = tmp_path / "run"
    with run_lock(run, create=True):
        for name in started:
            (run / name).write_text("{}")
        line = faults.one_error_line(cli("train", "--data", str(small_phantom), "--out",
                                         str(run), "--iters", "2"))
    assert line.startswith(f"error: {run}: in use by another surgsplat process (PID "
                           f"{os.getpid()})"), line


def test_a_folder_of_the_users_is_refused_without_a_lock_file_left_in_it(small_phantom,
                                                                        tmp_path, cli, faults):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    line = faults.one_error_line(cli("train", "--data", str(small_phantom), "--out",
                                     str(mine), "--iters", "2"))
    assert "is not empty and is not a surgsplat run folder" in line
    assert sorted(path.name for path in mine.iterdir()) == ["notes.txt"]


def test_a_read_only_run_is_rendered_and_exported_elsewhere(trained, tmp_path, cli, faults):
    """EROFS from every write under the run folder, as on a read-only mount (tests run as root,
    for whom chmod does not make a folder read-only)."""
    patch = READ_ONLY.format(root=str(trained))
    videos, exported = tmp_path / "videos", tmp_path / "exported"
    rendered = faults.run_patched(patch, "render", str(trained), "--out", str(videos),
                                  "--channels", "rgb")
    assert rendered.returncode == 0, rendered.stderr
    assert (videos / "rgb.mp4").stat().st_size > 0
    ply = faults.run_patched(patch, "export", str(trained), "--ply", "--frames", "0", "--out",
                             str(exported))
    assert ply.returncode == 0, ply.stderr
    assert list(exported.glob("*.ply"))
    line = faults.one_error_line(faults.run_patched(patch, "eval", str(trained),
                                                    "--no-geometry"))
    assert line.startswith(f"error: {trained}") and "Read-only file system" in line, line


@pytest.mark.parametrize("content", [b"just some text\nof two lines\n",
                                     pickle.dumps({"features.0.weight": [1.0]}, protocol=4)])
def test_alexnet_weights_that_are_not_weights_are_one_line(trained, tmp_path, cli, faults,
                                                            content):
    weights = tmp_path / "weights.pth"
    weights.write_bytes(content)
    line = faults.one_error_line(cli("eval", str(trained), "--no-geometry", "--alexnet-weights",
                                     str(weights)))
    assert line.startswith(f"error: {weights}: cannot be read as torchvision's AlexNet "
                           "ImageNet weights"), line
    assert "weights_only" not in line



def test_a_checkpoint_missing_an_entry_is_named_and_resumed_from_before(small_phantom, tmp_path,
                                                                       cli, one_error_line):
    """A checkpoint without an entry training saves (here the optimiser's state) is damaged:
    resume falls back to previous.pt; with no previous.pt, eval and resume name the entry."""
    import torch

    from surgsplat.train.checkpoint import previous_path
    from surgsplat.train.trainer import CHECKPOINT

    run = tmp_path / "run"
    trained = cli("train", "--data", str(small_phantom), "--out", str(run), "--iters", "4",
                  "--set", "init.max_points=1500")
    assert trained.returncode == 0, trained.stderr
    latest = run / CHECKPOINT
    shutil.copy(latest, previous_path(latest))
    state = torch.load(latest, weights_only=True)
    del state["optimizer"], state["elapsed_seconds"]
    torch.save(state, latest)
    resumed = cli("train", "--out", str(run), "--resume", "--iters", "6")
    assert resumed.returncode == 0, resumed.stderr
    torch.save(state, latest)
    previous_path(latest).unlink()
    line = one_error_line(cli("train", "--out", str(run), "--resume", "--iters", "8"))
    assert line.startswith(f"error: {latest}: is damaged: it has no ") and "'optimizer'" in line
    line = one_error_line(cli("eval", str(run), "--no-geometry"))
    assert line == (f"error: {latest}: is damaged: it has no 'elapsed_seconds' entry, which "
                    "training saves")
