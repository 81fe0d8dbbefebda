"""LumiState: the illumination UNet, the Retinex losses, Eq. 5's interpolation, training in two
stages, checkpoints, relighting, the decomposition metrics and the render channels."""

from types import SimpleNamespace

import pytest
import torch
from torch import Tensor

from surgsplat.pipeline.render import write_run_videos
from surgsplat.data.scene import load_scene, read_image
from surgsplat.eval.decomposition import DecompositionScores
from surgsplat.methods.lumistate.illumination import IlluminationUNet, bright_channel, brightness
from surgsplat.methods.lumistate.retinex import (bright_channel_loss, illumination_transfer_loss,
                                      retinex_loss)
from surgsplat.methods.registry import method_config
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.methods.lumistate.decomposition import (LumiState, LumiStateConfig, grid_corners,
                                       interpolate_corners)
from surgsplat.model.state import GaussianState
from surgsplat.model.timeline import interpolate_in_time
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import Trainer


def test_unet_map_is_in_unit_range_with_the_input_shape():
    torch.manual_seed(0)
    unet = IlluminationUNet(channels=4, embedding_dim=8)
    maps = torch.rand(2, 24, 32) * 5.0  # brightness beyond [0, 1] too
    illumination, embedding = unet(maps)
    assert illumination.shape == maps.shape and embedding.shape == (2, 8)
    assert illumination.min() >= 0.0 and illumination.max() <= 1.0
    # the embedding depends on the frame: a brighter frame gets another one
    assert not torch.allclose(unet(maps * 0.2)[1], embedding)


def test_retinex_losses_vanish_for_an_exact_factorisation():
    torch.manual_seed(0)
    reflectance = torch.rand(20, 24, 3)
    reflectance[..., 0] = 1.0  # a bright channel of 1: then max(R, G, B) of I is L itself
    illumination = torch.ones(20, 24) * 0.7
    image = reflectance * illumination[..., None]
    tissue = torch.ones(20, 24, dtype=torch.bool)
    tissue[:3] = False
    assert float(retinex_loss(reflectance, illumination, image, tissue)) == 0.0
    assert float(bright_channel_loss(illumination, image, tissue, radius=2)) < 1e-12
    assert float(retinex_loss(reflectance, illumination * 0.5, image, tissue)) > 0.05
    assert float(bright_channel_loss(illumination * 0.5, image, tissue, radius=2)) > 0.1
    # only tissue pixels count
    wrong = image.clone()
    wrong[:3] = 0.0
    assert float(retinex_loss(reflectance, illumination, wrong, tissue)) == 0.0
    # the bright channel is the local maximum of the brightness
    spot = torch.zeros(9, 9)
    spot[4, 4] = 1.0
    assert bright_channel(spot, 2).sum() == 25 and brightness(torch.eye(3)[None]).tolist() == [[1.0] * 3]


def test_interpolation_reproduces_training_embeddings_and_blends_between():
    values = torch.randn(4, 5)
    times = torch.tensor([0.0, 0.125, 0.5, 0.75], dtype=torch.float64)
    for value, t in zip(values, times.tolist()):
        assert torch.equal(interpolate_in_time(values, times, t), value)
    torch.testing.assert_close(interpolate_in_time(values, times, 0.25),
                               values[1] * 2 / 3 + values[2] / 3)
    assert torch.equal(interpolate_in_time(values, times, 0.9), values[-1])


def lumistate_method(iterations: int, stage2: int):
    config = method_config("lumistate")
    config.train.iterations = iterations
    config.train.checkpoint_every = 1000
    config.init.max_points = 800
    config.densify.every = iterations + 1  # no densification
    for term in ("retinex", "bright_channel", "illumination_transfer"):
        config.losses[term].start = stage2 / iterations
    return config


@pytest.mark.slow
def test_lumistate_trains_in_two_stages_restores_and_relights(small_phantom, tmp_path):
    scene = load_scene(small_phantom)
    trainer = Trainer(lumistate_method(10, stage2=5), scene, tmp_path / "run")
    component = trainer.model.components["lumistate"]
    assert isinstance(component, LumiState)
    stages = []
    trainer.fit(lambda stats: stages.append(set(stats.terms)))
    assert "retinex" not in stages[3]
    assert {"retinex", "bright_channel", "illumination_transfer"} <= stages[5]
    assert {"retinex", "bright_channel"} <= stages[-1]
    assert "illumination_transfer" not in stages[-1]  # the tie stops at 2/3 of the run
    trained = [frame.index for frame in scene.train_frames]
    # Stage 2 stored maps of the frames it saw; the UNet weights changed in both stages
    assert (component.illumination_maps[trained] != 1.0).any()

    # a loaded run (evaluation mode) holds the caches of the final UNet, as the trained model
    # does once it leaves training mode
    trainer.model.eval()
    run = load_trained_run(tmp_path / "run")
    restored = run.model.components["lumistate"]
    torch.testing.assert_close(restored.embeddings, component.embeddings)
    torch.testing.assert_close(restored.illumination_maps, component.illumination_maps)
    frame = scene.train_frames[3]
    when = FrameTime(frame.index, frame.time)
    normal = render_frame(run.model, frame.camera, when)
    assert normal.extras["reflectance"].shape == (scene.height, scene.width, 3)
    assert normal.extras["illumination"].shape == (scene.height, scene.width, 1)
    with restored.relit(frame.index):
        relit = render_frame(run.model, frame.camera, when)
    torch.testing.assert_close(relit.rgb, normal.rgb)
    torch.testing.assert_close(relit.extras["illumination"], normal.extras["illumination"])
    with restored.relit("uniform"):
        uniform = render_frame(run.model, frame.camera, when)
        other = render_frame(run.model, frame.camera, FrameTime(0, 0.0))
        mean_embedding = restored.embedding(when)
    assert not torch.equal(uniform.rgb, normal.rgb)
    assert (mean_embedding - restored.embedding(when)).abs().max() > 1e-4
    torch.testing.assert_close(uniform.extras["illumination"], other.extras["illumination"])
    # the reflectance does not depend on the illumination state
    torch.testing.assert_close(uniform.extras["reflectance"], normal.extras["reflectance"])

    videos = write_run_videos(run, tmp_path / "videos", 10.0, ("reflectance", "illumination"),
                              relight="uniform")
    assert [path.name for path in videos] == ["reflectance-relit-uniform.mp4",
                                              "illumination-relit-uniform.mp4"]
    assert all(path.stat().st_size > 0 for path in videos)


def test_decomposition_scores_are_scale_free_and_catch_leaking_light(small_phantom):
    scene = load_scene(small_phantom)
    frames = scene.test_frames
    albedos = [torch.from_numpy(read_image(small_phantom / "gt" / "albedo" /
                                           f"{f.index:06d}.png")).float() / 255 for f in frames]
    exact, naive = DecompositionScores(), DecompositionScores()
    for number, (frame, albedo) in enumerate(zip(frames, albedos)):
        light = 0.5 + 0.4 * number  # a light that changes over the clip
        exact.add(frame, {"reflectance": albedo * 0.6}, albedo, small_phantom)
        naive.add(frame, {}, albedo * light, small_phantom)
    scores, baseline = exact.metrics(), naive.metrics()
    assert scores["reflectance_error"] < 1e-6 and scores["r_var"] < 1e-12
    assert baseline["reflectance_error"] > 0.02 and baseline["r_var"] > 1e-3
    assert baseline["decomposition_source"].startswith("rendered colour")
    assert "shading_error" not in scores  # the standard phantom has no gt/shading


def test_render_options_are_checked_at_the_boundary(tmp_path, cli, one_error_line):
    """An empty --channels is refused before the run is read; which channels a run renders is
    its method's to say (tests/train/test_toy_component.py checks an unknown one)."""
    line = one_error_line(cli("render", str(tmp_path), "--channels", ","))
    assert "--channels" in line and "rgb,depth,normal,side_by_side" in line


def test_colour_modulation_sends_no_gradient_to_the_means():
    """Hypothesis 15 of issue 28: the positional encoding's input is detached, as in the
    Deformable-3DGS family, so the colour loss moves colours, not geometry."""
    torch.manual_seed(0)
    component = LumiState(LumiStateConfig(num_frames=2, map_height=8, map_width=8)).eval()
    component.known[0] = True
    torch.nn.init.normal_(component.fusion.last.weight, std=0.1)  # a modulation that varies
    means = torch.randn(6, 3, requires_grad=True)
    sh = torch.randn(6, 4, 3, requires_grad=True)
    state = GaussianState(means=means, scales=torch.ones(6, 3), quats=torch.ones(6, 4),
                          opacities=torch.ones(6), sh=sh, sh_degree=1)
    component.transform(state, None, FrameTime(0, 0.0)).sh.square().sum().backward()
    assert means.grad is None
    assert sh.grad.abs().min() > 0.0  # the colours do get the gradient
    assert component.fusion.last.weight.grad.abs().max() > 0.0  # and so does the MLP


def test_grid_interpolation_reproduces_linear_functions_and_corners():
    """The fusion MLP runs on the occupied corners of a grid; trilinear interpolation is exact
    for a function linear in the position (tolerance 1e-5, float32) and at the corners."""
    torch.manual_seed(0)
    points = torch.cat([torch.rand(500, 3) * 2 - 1, torch.rand(20, 3) * 3 + 2])  # some outside
    cells = 8
    corners, index, weights = grid_corners(points, cells)
    assert index.shape == weights.shape == (520, 8) and (weights >= 0).all()
    torch.testing.assert_close(weights.sum(1), torch.ones(520))
    assert corners.shape[0] == torch.unique(corners, dim=0).shape[0] <= 520 * 8  # distinct
    slope, intercept = torch.randn(3, 5), torch.randn(5)
    values = corners @ slope + intercept  # [U, 5] a linear function at the corners
    interpolated = (weights[:, :, None] * values[index]).sum(1)
    torch.testing.assert_close(interpolated, points @ slope + intercept, atol=1e-5, rtol=1e-5)
    # a point on a corner takes that corner's value alone
    on_corner = torch.tensor([[0.25, -0.5, 0.75]])  # multiples of the spacing 2 / 8
    corners, index, weights = grid_corners(on_corner, cells)
    assert weights.max() == 1.0
    torch.testing.assert_close(corners[index[0, weights[0].argmax()]], on_corner[0])


def test_corner_interpolation_matches_the_gather_in_values_and_gradients():
    """interpolate_corners against the plain gather-and-sum, forward and gradient (float64,
    tolerance 1e-12); the weights and indices take no gradient."""
    generator = torch.Generator().manual_seed(3)
    points = torch.rand(700, 3, generator=generator, dtype=torch.float64) * 2 - 1
    corners, index, weights = grid_corners(points, 6)
    at_corners = torch.randn(corners.shape[0], 5, generator=generator, dtype=torch.float64,
                             requires_grad=True)
    upstream = torch.randn(700, 5, generator=generator, dtype=torch.float64)
    fast = interpolate_corners(at_corners, index, weights)
    (fast_grad,) = torch.autograd.grad(fast, at_corners, upstream)
    plain = (weights[:, :, None] * at_corners[index]).sum(1)
    (plain_grad,) = torch.autograd.grad(plain, at_corners, upstream)
    torch.testing.assert_close(fast, plain, atol=1e-12, rtol=1e-12)
    torch.testing.assert_close(fast_grad, plain_grad, atol=1e-12, rtol=1e-12)


def six_gaussians_seen_from_the_origin(sh: Tensor):
    """(a GaussianState of 6 Gaussians with SH coefficients sh [6, 4, 3] (degree 1), stand-ins
    of the canonical Gaussians holding the same coefficients and of a camera at the origin)."""
    state = GaussianState(means=torch.randn(6, 3), scales=torch.ones(6, 3),
                          quats=torch.ones(6, 4), opacities=torch.ones(6), sh=sh, sh_degree=1)
    canonical = SimpleNamespace(sh_coeffs=lambda: sh)
    return state, canonical, SimpleNamespace(world_to_camera=torch.eye(4))


def test_gain_channel_is_the_modulation_and_the_transfer_loss_moves_the_mlp():
    """Issue 28, hypothesis 13: the modulation must carry L_t for the reflectance to lose the
    static shading. The gain channel is each Gaussian's rendered colour over its reflectance
    (exactly the gain exp(sigma) for delta = 0, tolerance 1e-5), and the transfer loss, which
    ties it to L_t, sends a gradient to the fusion MLP (which Eq. 7 alone never does)."""
    torch.manual_seed(0)
    component = LumiState(LumiStateConfig(num_frames=2, map_height=8, map_width=8)).eval()
    component.known[0] = True
    coeffs = component.fusion.coeffs
    with torch.no_grad():  # sigma = log 0.4 on every coefficient, delta = 0
        component.fusion.last.bias[:coeffs * 3] = torch.log(torch.tensor(0.4))
    sh = torch.zeros(6, 4, 3)
    sh[:, 0] = torch.rand(6, 3) + 0.5  # colours well above the floor
    state, canonical, camera = six_gaussians_seen_from_the_origin(sh)
    modulated = component.transform(state, None, FrameTime(0, 0.0))
    gain = component.render_channels(modulated, canonical, camera, FrameTime(0, 0.0))["gain"]
    bound = component.config.max_log_gain  # sigma passes through bound tanh(sigma / bound)
    expected = float(torch.exp(bound * torch.tanh(torch.log(torch.tensor(0.4)) / bound)))
    torch.testing.assert_close(gain, torch.full((6, 1), expected), atol=1e-5, rtol=1e-5)
    # the loss vanishes when the rendered gain is the map (times alpha), and otherwise reaches
    # the MLP through the gain
    tissue = torch.ones(4, 4, dtype=torch.bool)
    alpha = torch.full((4, 4), 0.9)
    assert float(illumination_transfer_loss(torch.full((4, 4, 1), 0.36),
                                            torch.full((4, 4), 0.4), alpha, tissue)) < 1e-7
    rendered = gain.mean().expand(4, 4, 1)  # stand-in for the rasterised channel
    illumination_transfer_loss(rendered, torch.full((4, 4), 0.8), alpha, tissue).backward()
    assert component.fusion.last.bias.grad[:coeffs * 3].abs().max() > 0.0


@pytest.mark.parametrize("losses, channels", [
    (None, {"reflectance", "gain"}),  # a render for its own sake: every channel
    (frozenset({"photometric", "depth"}), set()),  # Stage 1
    (frozenset({"photometric", "retinex", "bright_channel", "illumination_transfer"}),
     {"reflectance", "gain"}),  # Stage 2 with the tie
    (frozenset({"photometric", "retinex", "bright_channel"}), {"reflectance"}),  # tie stopped
])
def test_a_training_render_holds_only_the_channels_its_losses_read(losses, channels):
    component = LumiState(LumiStateConfig(num_frames=2, map_height=8, map_width=8)).eval()
    component.known[0] = True
    state, canonical, camera = six_gaussians_seen_from_the_origin(torch.rand(6, 4, 3))
    when = FrameTime(0, 0.0, losses=losses)
    rendered = component.render_channels(state, canonical, camera, when)
    assert set(rendered) == channels


@pytest.mark.parametrize("radius", [0, 1, 2, 5])
def test_the_bright_channel_is_a_max_pooling(radius):
    brightness_map = torch.rand(37, 52, generator=torch.Generator().manual_seed(radius))
    pooled = torch.nn.functional.max_pool2d(brightness_map[None, None], 2 * radius + 1, stride=1,
                                            padding=radius)[0, 0]
    assert torch.equal(bright_channel(brightness_map, radius), pooled)
