"""Training end to end on the small phantom: loss falls, checkpoints resume exactly, Ctrl-C saves,
and the evaluation of the run is sane. Each test trains only a few dozen iterations."""

from __future__ import annotations

import json
import os
import signal

import pytest
import torch

from surgsplat.data.scene import load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.eval.run_metrics import EvalOptions, evaluate_run
from surgsplat.losses.photometric import photometric_loss
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.methods.settings import LossWeight
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train import per_gaussian
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import CHECKPOINT, CONFIG_FILE, LOG_FILE, Trainer, TrainingDiverged


def small_config(name: str, iterations: int):
    config = method_config(name)
    config.train.iterations = iterations
    config.init.max_points = 4000
    config.densify.start = 0.0
    config.densify.every = 10
    return config


def frame_loss(trainer: Trainer, index: int = 0) -> float:
    frame = trainer.scene.frames[index]
    out = render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time))
    return float(photometric_loss(out.rgb, frame.image, frame.tissue, lambda_dssim=0.2))


@pytest.mark.parametrize("method", ["deform3dgs", "endogaussian", "endoplanar"])
def test_loss_falls(small_phantom, tmp_path, method):
    trainer = Trainer(small_config(method, 60), load_scene(small_phantom), tmp_path / "run")
    before = frame_loss(trainer)
    trainer.fit()
    assert frame_loss(trainer) < 0.8 * before
    assert (tmp_path / "run" / CHECKPOINT).is_file()
    saved = json.loads((tmp_path / "run" / CONFIG_FILE).read_text())
    assert saved["name"] == method and saved["train"]["iterations"] == 60
    logged = [json.loads(line) for line in (tmp_path / "run" / LOG_FILE).read_text().splitlines()]
    assert logged[-1]["iteration"] == 60
    assert set(logged[-1]["terms"]) == {name for name, weight in saved["losses"].items()
                                        if LossWeight(**weight).active_at(60, 60)}


@pytest.mark.parametrize("method, decaying, frozen", [
    ("endogaussian", {"means", "hexplane_grid", "hexplane_time_grid", "exposure"},
     ("mlp_lr", "hexplane_mlp")),
    ("deform3dgs", {"means", "basis_weights", "basis_centres"},
     ("log_widths_lr", "basis_log_widths"))])
def test_every_scheduled_rate_ends_at_its_final_rate_and_a_frozen_group_stays_frozen(
        small_phantom, tmp_path, method, decaying, frozen):
    """The means and the deformation field's parameters decay; a rate set to 0 stays 0."""
    setting, frozen_group = frozen
    config = small_config(method, 4)
    setattr(config.components["deformation"], setting, 0.0)
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    trainer.fit()
    rates = {group["name"]: group["lr"] for group in trainer.optimizer.param_groups}
    assert decaying <= set(trainer.schedules)
    for name, schedule in trainer.schedules.items():
        assert schedule.lr_final < schedule.lr
        assert rates[name] == pytest.approx(schedule.lr_final, rel=1e-9), name
    assert rates[frozen_group] == 0.0 and frozen_group not in trainer.schedules


def rendered_test_frame(trainer: Trainer) -> torch.Tensor:
    frame = next(f for f in trainer.scene.frames if f.is_test)
    with torch.no_grad():
        return render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time)).rgb


@pytest.mark.parametrize("name", [name if name == "deform3dgs" else
                                  pytest.param(name, marks=pytest.mark.slow)
                                  for name in PRESETS])
def test_resume_continues_exactly(name, small_phantom, tmp_path):
    """A run stopped by Ctrl-C at iteration 15 and resumed from its checkpoint ends where the
    same run without the stop ends (densification at 10, 20 and LumiState's second stage
    straddle the stop). After a reload, float32 sums (on 2 threads) run in another order, and
    Adam (eps 1e-15) turns that into differences up to ~3e-4 on a few entries whose gradient
    is near zero (3 in 98,304 of a HexPlane plane): so of every float tensor of the model's
    state at most 1 entry in 1000 may lie outside rtol 1e-3 / atol 1e-4, none more than 1e-2
    off; integer and boolean state is equal; the test render within 1e-3. A resume that lost
    state moves far more (the unsaved tissue observation of the tool field: 3.5% of drawer's
    scales, up to 1.5 off)."""
    scene = load_scene(small_phantom)
    straight = Trainer(small_config(name, 30), scene, tmp_path / "a")
    straight.fit()

    first = Trainer(small_config(name, 30), scene, tmp_path / "b")

    def interrupt(stats):
        if stats.iteration == 15:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        first.fit(interrupt)
    resumed = Trainer(small_config(name, 30), scene, tmp_path / "b")
    assert resumed.load(tmp_path / "b" / CHECKPOINT) is None
    assert resumed.iteration == 15
    resumed.fit()
    expected, actual = straight.model.state_dict(), resumed.model.state_dict()
    assert actual.keys() == expected.keys()
    for key, value in expected.items():
        assert actual[key].shape == value.shape, key
        if not value.is_floating_point() or value.numel() == 0:
            assert torch.equal(actual[key], value), key
            continue
        off = ~torch.isclose(actual[key], value, rtol=1e-3, atol=1e-4)
        assert off.float().mean() <= 1e-3, f"{key}: {int(off.sum())} of {off.numel()} entries off"
        assert float((actual[key] - value).abs().max()) <= 1e-2, key
    torch.testing.assert_close(rendered_test_frame(resumed), rendered_test_frame(straight),
                               rtol=0, atol=1e-3)


def test_ctrl_c_saves_a_checkpoint(small_phantom, tmp_path):
    trainer = Trainer(small_config("deform3dgs", 50), load_scene(small_phantom), tmp_path / "run")

    def interrupt(stats):
        if stats.iteration == 7:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        trainer.fit(interrupt)
    state = torch.load(tmp_path / "run" / CHECKPOINT, weights_only=True)
    assert state["iteration"] == 7


@pytest.mark.slow  # end to end: 40 iterations and the full evaluation
def test_evaluation_of_a_short_run(small_phantom, tmp_path):
    Trainer(small_config("deform3dgs", 40), load_scene(small_phantom), tmp_path / "run").fit()
    metrics = evaluate_run(load_trained_run(tmp_path / "run"), EvalOptions())
    assert metrics["test_frames"] == 2 and metrics["iteration"] == 40
    assert 12.0 < metrics["psnr_tissue"] < 60.0 and 12.0 < metrics["psnr_zeroed"] < 60.0
    assert 0.0 < metrics["ssim"] <= 1.0
    assert 0.0 <= metrics["depth_rmse_mm"] < 20.0
    assert 0.0 <= metrics["fscore_1mm"] <= 1.0 and metrics["p2s_median_mm"] >= 0.0
    assert metrics["p2s_median_mm"] <= metrics["p2s_p95_mm"]
    assert metrics["num_gaussians"] > 0 and metrics["peak_rss_mb"] > 0
    assert (metrics["lpips"] is None) == ("lpips_note" in metrics)


@pytest.mark.slow  # end to end: a phantom generated, 60 iterations, the full evaluation
def test_training_with_known_moving_poses(moving_phantom, tmp_path):
    """The moving-camera phantom trains with each frame's camera, and its geometry is scored in
    the world frame: a run that used the cameras lands on the gt meshes."""
    scene = load_scene(moving_phantom)
    assert scene.has_moving_camera
    trainer = Trainer(small_config("deform3dgs", 60), scene, tmp_path / "run")
    before = frame_loss(trainer, 5)
    trainer.fit()
    assert frame_loss(trainer, 5) < 0.8 * before
    metrics = evaluate_run(load_trained_run(tmp_path / "run"), EvalOptions())
    assert metrics["psnr_tissue"] > 20.0
    # Points back-projected with the frames' poses: with the first frame's pose for every frame
    # they would be off by the camera's motion (ATE 4.1 mm, rotations up to 5.5 degrees at
    # ~50 mm, benchmarks/bench_poses.py); 60 iterations leave about 1 mm.
    assert metrics["p2s_median_mm"] < 2.0


def test_frames_without_depth_cost_no_depth_backward(small_phantom, tmp_path):
    """The depth term of a frame without a measured depth is a constant 0 (nothing flows back
    through the depth map), and a step whose active terms are all constant changes nothing."""
    import shutil
    shutil.copytree(small_phantom, tmp_path / "scene")
    shutil.rmtree(tmp_path / "scene" / "depth")
    scene = load_scene(tmp_path / "scene")
    assert all(frame.depth is None for frame in scene.frames)

    trainer = Trainer(small_config("deform3dgs", 5), scene, tmp_path / "both")
    stats = trainer.step()
    assert stats.terms["depth"] == 0.0 and stats.terms["photometric"] > 0.0

    config = small_config("deform3dgs", 5)
    config.losses["photometric"].weight = 0.0
    only_depth = Trainer(config, scene, tmp_path / "only_depth")
    before = {k: v.detach().clone() for k, v in only_depth.model.gaussians.params.items()}
    assert only_depth.step().loss == 0.0
    after = only_depth.model.gaussians.params
    assert all(torch.equal(after[k].detach(), v) for k, v in before.items())


def nan_term_from(trainer: Trainer, iteration: int, term: str = "photometric") -> None:
    """Make `term` of `trainer`'s loss NaN from `iteration` on."""
    losses = trainer.model.losses

    def poisoned(context, active):
        terms = losses(context, active)
        if context.iteration >= iteration:
            terms[term] = terms[term] * float("nan")
        return terms

    trainer.model.losses = poisoned


def test_a_loss_that_is_not_finite_stops_the_run_and_keeps_the_last_checkpoint(
        small_phantom, tmp_path):
    config = small_config("deform3dgs", 30)
    config.train.checkpoint_every = 5
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    nan_term_from(trainer, 8)
    with pytest.raises(TrainingDiverged, match=r"iteration 8: loss term photometric not finite; "
                                               r".*latest.pt \(iteration 5\) is kept"):
        trainer.fit()
    state = torch.load(tmp_path / "run" / CHECKPOINT, weights_only=True)
    assert state["iteration"] == 5


def test_a_trained_value_that_is_not_finite_is_never_saved(small_phantom, tmp_path):
    config = small_config("deform3dgs", 30)
    config.train.checkpoint_every = 5
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")

    def corrupt(stats):  # one mean turns NaN; the Gaussian may be culled, the loss stay finite
        if stats.iteration == 7:
            with torch.no_grad():
                trainer.model.gaussians.params["means"][0, 0] = float("nan")

    with pytest.raises(TrainingDiverged, match=r"iteration [6-9]: (means holds values that are "
                                               r"not finite|rasterize: means2d has \d+ non-finite"
                                               r" .*entries); .*\(iteration 5\) is kept"):
        trainer.fit(corrupt)
    state = torch.load(tmp_path / "run" / CHECKPOINT, weights_only=True)
    assert state["iteration"] == 5


def test_a_run_that_diverges_before_its_first_checkpoint_says_so(small_phantom, tmp_path):
    trainer = Trainer(small_config("deform3dgs", 30), load_scene(small_phantom), tmp_path / "run")
    nan_term_from(trainer, 2)
    with pytest.raises(TrainingDiverged, match="no checkpoint was written"):
        trainer.fit()
    assert not (tmp_path / "run" / CHECKPOINT).exists()


def test_a_model_with_a_value_that_is_not_finite_is_not_saved(small_phantom, tmp_path):
    trainer = Trainer(small_config("deform3dgs", 30), load_scene(small_phantom), tmp_path / "run")
    with torch.no_grad():
        trainer.model.gaussians.params["sh_dc"][3, 1] = float("inf")
    with pytest.raises(TrainingDiverged, match="iteration 0: sh_dc holds values that are not "
                                               "finite"):
        trainer.save()
    assert not (tmp_path / "run" / CHECKPOINT).exists()


def test_a_stop_during_densification_waits_for_the_end_of_the_step(small_phantom, tmp_path,
                                                                  monkeypatch):
    """SIGINT arriving between two per-Gaussian tensors' resizes (the third tensor of the first
    densification): the step finishes, the checkpoint holds one Gaussian count, and the run
    resumes from it."""
    config = small_config("endogaussian", 40)
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    resize = per_gaussian._replace
    resized: list[str] = []

    def resize_and_stop(model, optimizer, edit):
        def edit_and_stop(name, tensor, is_moment):
            resized.append(name)
            if len(resized) == 3:
                os.kill(os.getpid(), signal.SIGINT)
            return edit(name, tensor, is_moment)
        resize(model, optimizer, edit_and_stop)

    monkeypatch.setattr(per_gaussian, "_replace", resize_and_stop)
    with pytest.raises(KeyboardInterrupt):
        trainer.fit()
    assert len(resized) > 3  # the resize went on past the signal
    monkeypatch.setattr(per_gaussian, "_replace", resize)
    state = torch.load(tmp_path / "run" / CHECKPOINT, weights_only=True)
    assert state["iteration"] == config.densify.every
    resumed = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    resumed.load(tmp_path / "run" / CHECKPOINT)
    counts = {name: param.shape[0] for name, param in resumed.model.gaussians.params.items()}
    assert len(set(counts.values())) == 1, counts
    resumed.fit()
    assert resumed.iteration == 40


def test_a_loss_term_leaves_the_objective_at_its_stop(small_phantom, tmp_path):
    config = small_config("deform3dgs", 20)
    config.losses["depth"].stop = 0.5
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    terms = {}
    trainer.fit(lambda stats: terms.update({stats.iteration: set(stats.terms)}))
    assert all("depth" in terms[k] for k in range(1, 11))
    assert not any("depth" in terms[k] for k in range(11, 21))


def test_a_loss_window_that_is_empty_is_refused(small_phantom, tmp_path):
    config = small_config("deform3dgs", 20)
    config.losses["depth"].start, config.losses["depth"].stop = 0.6, 0.4
    with pytest.raises(SurgsplatError, match=r"losses.depth.stop \(0.4\) must be greater than "
                                             r"losses.depth.start \(0.6\)"):
        Trainer(config, load_scene(small_phantom), tmp_path / "run")


def test_a_zero_weight_may_name_the_loss_of_a_replaced_component(small_phantom, tmp_path):
    """endogaussian with the Gaussian-basis field: the HexPlane's regularisers are turned off by
    weight 0 and the run trains; a nonzero weight on them is still refused."""
    config = small_config("endogaussian", 4)
    config.components["deformation"] = GaussianBasisConfig()
    with pytest.raises(SurgsplatError, match="losses.plane_tv: no component of this method"):
        Trainer(config, load_scene(small_phantom), tmp_path / "refused")
    config.losses["plane_tv"].weight = config.losses["time_smoothness"].weight = 0.0
    terms = set()
    Trainer(config, load_scene(small_phantom), tmp_path / "run").fit(
        lambda stats: terms.update(stats.terms))
    assert terms == {"photometric", "depth"}
