"""camera_refine: per-frame pose corrections applied through the camera hook, learnt from the
render (recovering a known perturbation), pulled to the imported pose by the prior,
interpolated at test frames, and kept by checkpoints."""

from __future__ import annotations

import math

import pytest
import torch

from surgsplat.data.scene import Camera, load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.methods.registry import method_config
from surgsplat.model.camera_refine import PRIOR, CameraRefineConfig, correction_transform
from surgsplat.model.capabilities import HeldOutPoses
from surgsplat.model.component import FrameTime, RenderContext, SceneInfo, SetupContext
from surgsplat.model.dynamic import SplatModel, render_frame
from surgsplat.model.gaussians import GaussianModel
from surgsplat.methods.settings import LossWeight
from surgsplat.render.native import native_module
from surgsplat.train.trainer import CHECKPOINT, Trainer

W, H = 64, 48
K = torch.tensor([[50.0, 0, W / 2], [0, 50.0, H / 2], [0, 0, 1]])
FRAMES = 4
TRAIN = (0, 2, 3)  # frame 1 is held out
EXTENT = 2.0


def textured_cloud(num: int = 600, seed: int = 0) -> GaussianModel:
    """Small opaque Gaussians of random colours at depths 2.5 to 5.5 in front of the camera."""
    generator = torch.Generator().manual_seed(seed)
    depth = 2.5 + 3.0 * torch.rand(num, generator=generator)
    xy = (torch.rand(num, 2, generator=generator) - 0.5) * torch.tensor([W / 50, H / 50])
    params = {
        "means": torch.cat([xy * depth[:, None], depth[:, None]], dim=1),
        "log_scales": torch.full((num, 3), math.log(0.08)),
        "quats": torch.tensor([1.0, 0, 0, 0]).repeat(num, 1),
        "opacity_logits": torch.full((num,), 2.0),
        "sh_dc": torch.randn(num, 3, generator=generator),
        "sh_rest": torch.zeros(num, 0, 3),
    }
    return GaussianModel(params, sh_degree=0)


def refined_model(train=TRAIN) -> SplatModel:
    component = CameraRefineConfig(lr=1e-2).resolve(
        SceneInfo(num_frames=FRAMES, width=W, height=H, train_indices=train)).build()
    component.setup(SetupContext(scene=SceneInfo(FRAMES, W, H, train), points=torch.zeros(1, 3),
                                 scene_extent=EXTENT, frames=[]))
    return SplatModel(textured_cloud(), {"camera_refine": component})


def camera(pose: torch.Tensor) -> Camera:
    return Camera(K=K, world_to_camera=pose, width=W, height=H)


def pose_error(pose: torch.Tensor, truth: torch.Tensor) -> tuple[float, float]:
    """Rotation (degrees; from the skew part, exact for small angles) and translation (scene
    units) of the residual pose @ truth^-1, in float64."""
    residual = pose.double() @ torch.linalg.inv(truth.double())
    skew = residual[:3, :3] - residual[:3, :3].T
    sine = 0.5 * torch.stack([skew[2, 1], skew[0, 2], skew[1, 0]]).norm()
    return math.degrees(float(torch.arcsin(sine.clamp(max=1)))), float(residual[:3, 3].norm())


def test_zero_corrections_and_no_component_leave_the_camera_as_it_is():
    pose = correction_transform(torch.tensor([0.1, -0.2, 0.05, 0.3, 0.1, -0.2]), 1.0)
    seen = camera(pose)
    model = refined_model()
    for index in range(FRAMES):  # trained frames and the interpolated one
        assert torch.equal(model.camera_at(seen, FrameTime(index, index / FRAMES))
                           .world_to_camera, pose)
    plain = SplatModel(textured_cloud(), {})
    assert plain.camera_at(seen, FrameTime(0, 0.0)) is seen
    when = FrameTime(0, 0.0)
    assert torch.equal(render_frame(model, seen, when).rgb, render_frame(plain, seen, when).rgb)


def test_correction_is_applied_in_the_camera_frame_in_scene_extents():
    model = refined_model()
    component = model.components["camera_refine"]
    imported = correction_transform(torch.tensor([0.3, 0.1, -0.2, 0.5, 0.0, 1.0]), 1.0)
    point = torch.tensor([1.0, 0.0, 3.0, 1.0])
    seen = imported @ point  # the point in the imported camera's frame
    # a rotation of 90 degrees about the camera's z; a shift of 0.1 extent along its x
    for correction, expected in (([0.0, 0.0, math.pi / 2, 0, 0, 0], [-seen[1], seen[0], seen[2]]),
                                 ([0, 0, 0, 0.1, 0, 0], [seen[0] + 0.1 * EXTENT, seen[1], seen[2]])):
        with torch.no_grad():
            component.corrections[2] = torch.tensor(correction)
        moved = model.camera_at(camera(imported), FrameTime(2, 0.5)).world_to_camera
        torch.testing.assert_close((moved @ point)[:3], torch.tensor(expected))


def test_recovers_a_known_small_pose_perturbation():
    """Only the correction is trained (Adam, lr 1e-2, 120 steps, MSE against the render of the
    fixed model from the true pose) from a pose off by 2.2 degrees and 0.078 scene units (4 % of
    the extent): both errors drop at least 100-fold (measured: ~600-fold and ~470-fold)."""
    model = refined_model()
    truth = torch.eye(4)
    truth[:3, 3] = torch.tensor([0.05, -0.02, 0.1])
    when = FrameTime(0, 0.0)
    with torch.no_grad():
        target = model.render(camera(truth), when)[0].rgb
    perturbation = correction_transform(torch.tensor([0.02, -0.03, 0.015, 0.02, 0.015, -0.03]),
                                        EXTENT)
    imported = camera(perturbation @ truth)
    before = pose_error(imported.world_to_camera, truth)
    assert before[0] > 2.0 and before[1] > 0.07
    component = model.components["camera_refine"]
    (group,) = component.param_groups()
    optimizer = torch.optim.Adam(group.params, lr=group.lr)
    for _ in range(120):
        optimizer.zero_grad()
        rgb = model.render(model.camera_at(imported, when), when)[0].rgb
        (rgb - target).square().mean().backward()
        optimizer.step()
    after = pose_error(model.camera_at(imported, when).world_to_camera.detach(), truth)
    assert after[0] < before[0] / 100 and after[1] < before[1] / 100, (before, after)
    if native_module() is not None:  # the pose's gradients came from the native kernel
        projection = model.render(model.camera_at(imported, when), when)[0].projection
        assert projection.means2d.grad_fn.name().endswith("_NativeProjectBackward")


def test_prior_pulls_the_correction_to_zero():
    model = refined_model()
    component = model.components["camera_refine"]
    with torch.no_grad():
        component.corrections[3] = torch.tensor([0.05, -0.02, 0.01, 0.1, 0.0, -0.05])
    when = FrameTime(3, 0.75)
    # the prior reads nothing of the context but the frame's time
    context = RenderContext(frame=None, when=when, camera=None, output=None, state=None,
                            gaussians=None, iteration=1)
    (group,) = component.param_groups()
    optimizer = torch.optim.Adam(group.params, lr=group.lr)
    start = float(component.corrections[3].detach().norm())
    for _ in range(30):
        optimizer.zero_grad()
        prior = model.losses(context, frozenset({PRIOR}))[PRIOR]
        prior.backward()
        optimizer.step()
    assert float(component.corrections[3].detach().norm()) < 0.2 * start
    assert not component.corrections[[0, 1, 2]].any()  # other frames untouched


def test_test_frames_interpolate_the_nearest_training_frames_and_say_so():
    model = refined_model()
    component = model.components["camera_refine"]
    with torch.no_grad():
        component.corrections[0] = torch.tensor([0.02, 0, 0, 0.1, 0, 0])
        component.corrections[2] = torch.tensor([0.04, 0, 0, 0.3, 0, 0])
        component.corrections[1] = 5.0  # never trained: never used
    held_out = FrameTime(1, 0.25)
    torch.testing.assert_close(component.correction(held_out),
                               torch.tensor([0.03, 0, 0, 0.2, 0, 0]))
    diagnostics = model.diagnostics(held_out)
    assert math.isclose(diagnostics.averaged["pose_correction_deg"], math.degrees(0.03),
                        rel_tol=1e-5)
    assert math.isclose(diagnostics.averaged["pose_correction_translation"], 0.2 * EXTENT,
                        rel_tol=1e-5)
    assert "interpolated" in diagnostics.conventions["test_frame_poses"]
    assert "no test-time optimisation" in diagnostics.conventions["test_frame_poses"]


def test_checkpoint_resume_keeps_the_corrections(small_phantom, tmp_path):
    config = method_config("deform3dgs")
    config.components["camera_refine"] = CameraRefineConfig()
    config.losses[PRIOR] = LossWeight(0.1)
    config.train.iterations = 8
    config.init.max_points = 2000
    scene = load_scene(small_phantom)
    trainer = Trainer(config, scene, tmp_path / "run")
    trainer.fit()
    trained = trainer.model.components["camera_refine"]
    assert trained.corrections.abs().sum() > 0  # learnt from the render
    assert not trained.corrections[[f.index for f in scene.test_frames]].any()
    resumed = Trainer(config, scene, tmp_path / "run")
    assert resumed.load(tmp_path / "run" / CHECKPOINT) is None
    loaded = resumed.model.components["camera_refine"]
    for name, value in trained.state_dict().items():
        assert torch.equal(loaded.state_dict()[name], value), name
    saved, restored = (t.optimizer.state_dict() for t in (trainer, resumed))
    group = [g["name"] for g in resumed.optimizer.param_groups].index("camera_refine")
    (slot,) = restored["param_groups"][group]["params"]
    (saved_slot,) = saved["param_groups"][group]["params"]
    assert torch.equal(restored["state"][slot]["exp_avg"], saved["state"][saved_slot]["exp_avg"])
    frame = scene.test_frames[0]
    when = FrameTime(frame.index, frame.time)
    assert torch.equal(resumed.model.camera_at(frame.camera, when).world_to_camera,
                       trainer.model.camera_at(frame.camera, when).world_to_camera)



def test_evaluation_sees_a_frame_by_its_refined_camera():
    """FrameView.seen: the frame's pixels, the camera the model renders it with (the refined
    pose), so that geometry placed in the world by the frame's camera uses the refined pose."""
    from types import SimpleNamespace

    from surgsplat.data.scene import Frame
    from surgsplat.eval.metric_family import FrameView

    model = refined_model()
    with torch.no_grad():
        model.components["camera_refine"].corrections[2] = torch.tensor(
            [0.0, 0.02, 0.0, 0.05, 0.0, 0.0])
    full = torch.ones(H, W, dtype=torch.bool)
    frame = Frame(2, 0.5, torch.rand(H, W, 3), None, False, camera(torch.eye(4)),
                  tool=~full, fov=full)
    view = FrameView(SimpleNamespace(model=model), frame, render=None, background=None)
    expected = model.camera_at(frame.camera, FrameTime(2, 0.5)).world_to_camera
    assert not torch.equal(expected, frame.camera.world_to_camera)
    assert torch.equal(view.seen.camera.world_to_camera, expected)
    assert view.seen.image is frame.image and torch.equal(view.seen.tissue, frame.tissue)


def test_a_held_out_frame_is_fitted_at_test_time_and_says_so():
    """fit_held_out moves only the held-out frame's correction (Adam, lr 1e-2 decaying to 1e-3,
    100 steps, MSE against the render from the true pose) from a pose off by 0.86 degrees and
    0.02 scene units: both errors drop at least 10-fold; the model and the training frames'
    corrections stay as they were; metrics say the test poses were fitted."""
    model = refined_model()
    component = model.components["camera_refine"]
    component.config.test_time_lr = 1e-2
    held_out = FrameTime(1, 0.25)
    with torch.no_grad():
        target = model.render(camera(torch.eye(4)), held_out)[0].rgb
    imported = camera(correction_transform(torch.tensor([0.01, -0.008, 0.006, 0.005, 0.004,
                                                         -0.006]), EXTENT))
    before = pose_error(imported.world_to_camera, torch.eye(4))
    trained_before = component.corrections.detach().clone()
    means_before = model.gaussians.params["means"].detach().clone()

    def loss():
        rgb = model.render(model.camera_at(imported, held_out), held_out)[0].rgb
        return (rgb - target).square().mean()

    assert model.find(HeldOutPoses) is component
    component.fit_held_out(1, 0.25, loss)
    after = pose_error(model.camera_at(imported, held_out).world_to_camera.detach(),
                       torch.eye(4))
    assert after[0] < before[0] / 10 and after[1] < before[1] / 10, (before, after)
    assert torch.equal(component.corrections.detach(), trained_before)
    assert torch.equal(model.gaussians.params["means"].detach(), means_before)
    assert "fitted to the frame's tissue pixels" in \
        model.diagnostics(held_out).conventions["test_frame_poses"]
    with pytest.raises(SurgsplatError, match="frame 2 is a training frame"):
        component.fit_held_out(2, 0.5, loss)
    component.config.test_time_steps = 0
    assert model.find(HeldOutPoses) is None
