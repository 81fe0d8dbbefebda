"""PhysioSplat's components: rigid tool motion, tool-free rendering, the biomechanical energies
(zero when undeformed, positive on a known violation, gradients against finite differences) and
the specular lobe."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation
from torch import Tensor

from surgsplat.data.scene import Camera, Frame
from surgsplat.fields.deformation import Deformation, DeformationField
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.methods.physiosplat.biomechanics import BiomechanicsConfig
from surgsplat.model.component import FrameTime, RenderContext, SceneInfo, SetupContext
from surgsplat.model.dynamic import SplatModel, render_frame
from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.model.physics import arap_strain, collision_energy, neighbour_graph, tool_proxy
from surgsplat.image.pinhole import depth_normals, pixel_rays
from surgsplat.methods.physiosplat.specular import (SpecularConfig, normal_view_cosine, smooth_depth,
                                      specular_lobe, view_cosine)
from surgsplat.methods.physiosplat.tool_field import (SEMANTIC_KEY, ToolFieldConfig, _icp,
                                        masked_binary_cross_entropy)
from surgsplat.render.render import RenderOutput, render
from surgsplat.render.rotation import quaternion_to_matrix

ROTVEC = torch.tensor([0.3, -0.2, 0.5])
TRANSLATION = torch.tensor([2.0, -1.0, 3.0])


def _gaussians(n_tissue: int = 40, n_tool: int = 12, seed: int = 0) -> GaussianModel:
    """Tissue on a plane at z = 20, tool Gaussians in front of it at z = 14 (scene units)."""
    generator = torch.Generator().manual_seed(seed)
    tissue = torch.cat([torch.rand(n_tissue, 2, generator=generator) * 12 - 6,
                        torch.full((n_tissue, 1), 20.0)], 1)
    tool = torch.cat([torch.rand(n_tool, 2, generator=generator) * 4 - 2,
                      torch.full((n_tool, 1), 14.0)], 1)
    points = torch.cat([tissue, tool])
    colors = torch.rand(points.shape[0], 3, generator=generator)
    logits = torch.cat([torch.full((n_tissue,), 4.0), torch.full((n_tool,), -4.0)])
    return GaussianModel.from_points(points, colors, GaussianConfig(init_opacity=0.8),
                                     {SEMANTIC_KEY: logits})


def _tool_field(frames: int = 4):
    field = ToolFieldConfig(num_frames=frames).build()
    with torch.no_grad():
        field.known[:] = True
        field.seen[:] = True
        field.rotations[2] = ROTVEC
        field.translations[2] = TRANSLATION / field.unit
    return field


def _camera() -> Camera:
    K = torch.tensor([[40.0, 0.0, 32.0], [0.0, 40.0, 24.0], [0.0, 0.0, 1.0]])
    return Camera(K=K, world_to_camera=torch.eye(4), width=64, height=48)


def test_tool_gaussians_move_by_the_frame_rigid_motion_and_tissue_stays():
    gaussians = _gaussians()
    model = SplatModel(gaussians, {"tool": _tool_field()})
    state = model.state_at(FrameTime(2, 0.5))
    tool = gaussians.params[SEMANTIC_KEY] < 0
    rotation = torch.from_numpy(Rotation.from_rotvec(ROTVEC.double().numpy()).as_matrix()).float()
    canonical = gaussians.params["means"].detach()
    expected = canonical[tool] @ rotation.T + TRANSLATION
    torch.testing.assert_close(state.means[tool], expected, atol=1e-5, rtol=1e-5)
    torch.testing.assert_close(state.means[~tool], canonical[~tool])
    turned = quaternion_to_matrix(state.quats[tool])
    torch.testing.assert_close(turned, rotation.expand_as(turned) @ quaternion_to_matrix(
        gaussians.params["quats"][tool]), atol=1e-5, rtol=1e-5)
    # A held-out frame between two registered ones interpolates them: half way at frame 1.
    with torch.no_grad():
        model.components["tool"].known[1] = False
    halfway = model.state_at(FrameTime(1, 0.25)).means[tool]
    rotation_half = Rotation.from_rotvec(0.5 * ROTVEC.double().numpy()).as_matrix()
    torch.testing.assert_close(halfway, canonical[tool] @ torch.from_numpy(rotation_half).float().T
                               + 0.5 * TRANSLATION, atol=1e-5, rtol=1e-5)


def test_icp_recovers_a_known_rigid_motion_of_a_tool_cloud():
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    shaft = np.stack([rng.uniform(0, 30, 400), 2 * np.cos(t := rng.uniform(0, 6.3, 400)),
                      2 * np.sin(t)], 1)
    jaws = rng.uniform([-6, -1, -3], [0, 1, 3], (150, 3))
    model = np.concatenate([shaft, jaws])
    rotation = Rotation.from_rotvec([0.05, -0.04, 0.08]).as_matrix()
    translation = np.array([0.8, -0.5, 0.6])
    target = model @ rotation.T + translation
    found_rotation, found_translation = _icp(cKDTree(model), model, target, np.eye(3),
                                             np.zeros(3), 40)
    np.testing.assert_allclose(found_rotation, rotation, atol=1e-3)
    np.testing.assert_allclose(found_translation, translation, atol=1e-2)


def test_tool_free_render_equals_rendering_the_tissue_subset_alone():
    gaussians = _gaussians()
    model = SplatModel(gaussians, {"tool": _tool_field()})
    camera = _camera()
    when = FrameTime(2, 0.5, tissue_only=True)
    tool_free = render_frame(model, camera, when)
    full = render_frame(model, camera, FrameTime(2, 0.5))
    state = model.state_at(FrameTime(2, 0.5))
    tissue = gaussians.params[SEMANTIC_KEY] >= 0
    with torch.no_grad():
        alone = render(state.means[tissue], state.scales[tissue], state.quats[tissue],
                       state.opacities[tissue], state.sh[tissue], camera.K, camera.width,
                       camera.height, world_to_camera=camera.world_to_camera,
                       sh_degree=state.sh_degree)
    torch.testing.assert_close(tool_free.rgb, alone.rgb, atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(tool_free.alpha, alone.alpha, atol=1e-6, rtol=1e-5)
    assert (full.rgb - tool_free.rgb).abs().max() > 0.05  # the tool was in view


def brute_force_proxy_sdf(x: Tensor, centres: Tensor, radii: Tensor) -> Tensor:
    """min_k (|x - c_k| - r_k) over every ball."""
    return ((x[:, None] - centres[None]).norm(dim=-1) - radii).min(dim=1).values


def test_tool_proxy_is_the_union_of_balls_and_leaves_the_gap_between_jaws_free():
    """Two jaws (balls of their smallest scale, 0.1, at x = -3 and 3): a point between them is
    2.9 from the tool (their convex hull would put it inside); inside a ball Psi < 0; far points
    get the clearance; equal to the brute-force minimum over all balls within 1e-6."""
    generator = torch.Generator().manual_seed(4)
    centres = torch.tensor([[-3.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    scales = torch.tensor([[0.5, 0.2, 0.1], [0.1, 0.5, 0.2]])
    proxy = tool_proxy(centres, scales, torch.ones(2), torch.ones(2, dtype=torch.bool), 0.5)
    probes = torch.tensor([[0.0, 0.0, 0.0], [3.04, 0.0, 0.0], [50.0, 0.0, 0.0]])
    torch.testing.assert_close(proxy.sdf(probes, 4.0), torch.tensor([2.9, -0.06, 4.0]))
    many = torch.randn(200, 3, generator=generator) * 2.0
    balls = torch.randn(300, 3, generator=generator) * 2.0
    radii = torch.rand(300, generator=generator) * 0.3 + 0.05
    proxy = tool_proxy(balls, radii[:, None].expand(-1, 3), torch.ones(300),
                       torch.ones(300, dtype=torch.bool), 0.5)
    expected = brute_force_proxy_sdf(many, balls, radii).clamp(max=10.0)
    torch.testing.assert_close(proxy.sdf(many, 10.0), expected, atol=1e-6, rtol=0)
    faint = tool_proxy(balls, radii[:, None].expand(-1, 3), torch.zeros(300),
                       torch.ones(300, dtype=torch.bool), 0.5)
    assert faint is None  # no tool Gaussian opaque enough


def test_collision_energy_is_zero_clear_of_the_tool_and_positive_inside():
    margin = 0.5
    clear = collision_energy(torch.tensor([0.6, 2.0, 10.0]), margin)
    assert torch.all(clear == 0)
    inside = collision_energy(torch.tensor([-0.3, 0.2]), margin)
    torch.testing.assert_close(inside, torch.tensor([0.64, 0.09]))


def test_arap_strain_is_zero_undeformed_and_positive_when_stretched():
    points = torch.rand(60, 3, generator=torch.Generator().manual_seed(1)) * 10
    graph = neighbour_graph(points, torch.ones(60, dtype=torch.bool), 6)
    assert arap_strain(points, points, graph).abs().max() < 1e-5
    moved = points @ torch.from_numpy(Rotation.from_rotvec([0.4, 0.1, -0.3]).as_matrix()).float().T
    assert arap_strain(moved + 5.0, points, graph).abs().max() < 1e-4  # rigid: no strain
    stretched = points * torch.tensor([1.2, 1.0, 1.0])
    assert arap_strain(stretched, points, graph).mean() > 1e-2


class _LinearField(DeformationField):
    """Mean offsets A x: the deformation gradient is I + A everywhere (A a plain tensor)."""

    def __init__(self, matrix: Tensor):
        super().__init__()
        self.matrix = matrix

    def per_gaussian_attributes(self, num: int) -> dict[str, Tensor]:
        return {}

    def forward(self, means, attributes, t) -> Deformation:
        zeros = torch.zeros(means.shape[0], 3, dtype=means.dtype)
        return Deformation(means @ self.matrix.T, zeros,
                           torch.zeros(means.shape[0], 4, dtype=means.dtype), None)

    def volume_samples(self) -> int:
        return 16


def test_volume_energy_is_zero_for_the_identity_and_measures_a_known_compression():
    gaussians = _gaussians()
    identity = HexPlaneConfig(volume_samples=8).build()  # starts as the identity field
    assert identity.volume_loss(gaussians, 0.3).item() == pytest.approx(0.0, abs=1e-10)
    squeeze = _LinearField(torch.diag(torch.tensor([-0.2, 0.0, 0.0])))  # det = 0.8
    squeeze.bind({"deformation": squeeze, "tool": _tool_field()})  # the tool is not tissue
    tissue = int((gaussians.params[SEMANTIC_KEY] >= 0).sum())
    # Eq. 6 is a sum over the tissue Gaussians (16 sampled of them, each (0.8 - 1)^2 = 0.04),
    # not their mean: the paper's weight is a weight of that sum (rel. tolerance: float32).
    assert tissue > squeeze.volume_samples()
    assert squeeze.volume_loss(gaussians, 0.3).item() == pytest.approx(0.04 * tissue, rel=1e-4)
    assert "volume" in squeeze.loss_names()


def test_volume_energy_gradient_matches_finite_differences():
    params = {name: value.detach().double() for name, value in _gaussians(8, 4).params.items()}
    field = _LinearField(torch.zeros(3, 3, dtype=torch.float64))
    rows = torch.arange(8)

    def energy(matrix: Tensor) -> Tensor:
        field.matrix = matrix
        return (field.jacobian_determinants(params, rows, 0.0) - 1.0).square().sum()

    generator = torch.Generator().manual_seed(3)
    matrix = 0.1 * torch.randn(3, 3, generator=generator, dtype=torch.float64)
    assert torch.autograd.gradcheck(energy, (matrix.requires_grad_(),))


def test_energies_gradients_match_finite_differences():
    points = torch.rand(20, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 5
    graph = neighbour_graph(points, torch.ones(20, dtype=torch.bool), 4)
    deformed = (points * 1.1 + 0.05 * torch.randn(20, 3, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda x: arap_strain(x, points, graph).sum(), (deformed,))
    balls = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]], dtype=torch.float64)
    proxy = tool_proxy(balls, torch.full((3, 3), 0.3, dtype=torch.float64), torch.ones(3),
                       torch.ones(3, dtype=torch.bool), 0.5)
    probes = torch.tensor([[0.4, 0.3, 0.2], [2.3, 0.2, 0.1], [0.1, 1.5, 0.3]],
                          dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x: collision_energy(proxy.sdf(x, 3.0), 0.5).sum(), (probes,))


def test_specular_lobe_peaks_facing_the_camera_and_has_checked_gradients():
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    depth = torch.full((24, 32), 50.0, dtype=torch.float64)  # a plane facing the camera
    albedo = torch.full((24, 32, 1), 0.3, dtype=torch.float64, requires_grad=True)
    sharpness = torch.full((24, 32), 20.0, dtype=torch.float64, requires_grad=True)
    lobe = specular_lobe(depth, K, albedo, sharpness)  # [24, 32, 1]
    cosine = 1.0 / math.sqrt(1.0 + 2 * (0.5 / 40.0) ** 2)  # pixel (16, 12): centre (16.5, 12.5)
    assert lobe[12, 16, 0].item() == pytest.approx(0.3 * math.exp((cosine - 1.0) * 20.0),
                                                   rel=1e-6)
    assert lobe[2, 2, 0] < lobe[12, 16, 0]  # oblique view at the corner: dimmer
    assert lobe[0, 0, 0].item() == 0.0  # border pixels have no depth normal
    small_a = albedo[10:13, 14:17].detach().clone().requires_grad_()
    small_s = sharpness[10:13, 14:17].detach().clone().requires_grad_()
    assert torch.autograd.gradcheck(
        lambda a, s: specular_lobe(depth[9:14, 13:18], K,
                                   torch.nn.functional.pad(a, (0, 0, 1, 1, 1, 1)),
                                   torch.nn.functional.pad(s, (1, 1, 1, 1))), (small_a, small_s))
    assert math.isfinite(float(lobe.detach().sum()))


def test_a_planar_models_lobe_is_shaded_from_its_rendered_normals():
    """With a normal channel (planar Gaussians) the lobe uses it, not the depth: here the depth
    is empty, the normals face the camera, so the lobe is there, with n . v = 1 / |ray|."""
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]])
    normal = torch.zeros(24, 32, 3)
    normal[..., 2] = 0.5  # blended, not normalised, facing away from the camera
    cosine, valid = normal_view_cosine(normal, K)
    ray = pixel_rays(K, 32, 24)[5, 7]
    assert valid.all()
    assert cosine[5, 7].item() == pytest.approx(1.0 / float(ray.norm()), rel=1e-6)
    assert torch.equal(normal_view_cosine(-normal, K)[0], cosine)  # either orientation
    assert not normal_view_cosine(torch.zeros(2, 2, 3), K)[1].any()
    lobe = SpecularConfig().build()
    output = RenderOutput(rgb=torch.zeros(24, 32, 3), alpha=torch.ones(24, 32),
                          depth=torch.zeros(24, 32), projection=None,
                          extras={"normal": normal, "specular_albedo": torch.full((24, 32, 1), 0.3),
                                  "specular_sharpness": torch.full((24, 32, 1), 20.0)})
    lobe.finish_render(output, Camera(K=K, world_to_camera=torch.eye(4), width=32, height=24),
                       FrameTime(0, 0.0))
    expected = 0.3 * torch.exp((cosine - 1.0) * 20.0)
    assert torch.allclose(output.rgb, expected[..., None].expand(24, 32, 3))


def _contact_scene(scale: float) -> tuple[GaussianModel, Tensor]:
    """A tool cube [-2, 2]^2 x [12, 16] (8 tool Gaussians) over tissue on the plane z = 20, with
    two tissue Gaussians inside the cube (z = 15) and one within 2 units outside (z = 17), all
    lengths times `scale`; and the tissue means stretched by 10% about the origin in x."""
    cube = torch.tensor([[x, y, z] for x in (-2.0, 2.0) for y in (-2.0, 2.0) for z in (12.0, 16.0)])
    generator = torch.Generator().manual_seed(5)
    plane = torch.cat([torch.rand(30, 2, generator=generator) * 12 - 6,
                       torch.full((30, 1), 20.0)], 1)
    near = torch.tensor([[0.5, 0.0, 15.0], [-0.5, 0.5, 15.0], [0.0, 0.0, 17.0]])
    points = torch.cat([plane, near, cube]) * scale
    logits = torch.cat([torch.full((33,), 4.0), torch.full((8,), -4.0)])
    gaussians = GaussianModel.from_points(points, torch.full_like(points, 0.5),
                                          GaussianConfig(init_opacity=0.8),
                                          {SEMANTIC_KEY: logits})
    stretched = points.clone()
    stretched[:33, 0] *= 1.1
    return gaussians, stretched


def _energies(scale: float) -> tuple[dict[str, float], dict[str, float]]:
    """The Biomechanics terms of `_contact_scene(scale)` with extent 40 * scale, and the same
    energies summed directly over the tissue Gaussians (Eq. 4, 5), divided by the extent^2."""
    gaussians, stretched = _contact_scene(scale)
    extent = 40.0 * scale
    component = BiomechanicsConfig(anchors=10_000, collision_margin=0.05).build()
    component.bind({"biomechanics": component, "tool": _tool_field()})
    component.setup(SetupContext(scene=SceneInfo(1, 64, 48, (0,)),
                                 points=gaussians.params["means"].detach(),
                                 scene_extent=extent, frames=[]))
    model = SplatModel(gaussians, {})
    state = model.state_at(FrameTime(0, 0.0)).replace(means=stretched)
    context = RenderContext(frame=None, when=FrameTime(0, 0.0), camera=None, output=None,
                            state=state, gaussians=gaussians, iteration=1)
    terms = component.losses(context, frozenset({"strain", "collision"}))
    tissue = gaussians.params[SEMANTIC_KEY] >= 0
    graph = neighbour_graph(gaussians.params["means"], tissue, 16)
    strain = arap_strain(stretched, gaussians.params["means"], graph).sum()
    radii = state.scales[~tissue].min(dim=1).values
    proxy_sdf = brute_force_proxy_sdf(stretched[tissue], stretched[~tissue], radii)
    collision = collision_energy(proxy_sdf, 0.05 * extent).sum()
    return ({name: float(value) for name, value in terms.items()},
            {"strain": float(strain) / extent ** 2, "collision": float(collision) / extent ** 2})


def test_biomechanical_energies_are_sums_over_tissue_in_units_of_the_extent():
    terms, direct = _energies(1.0)
    # Sums over the 33 tissue Gaussians (the paper's weights are weights of sums), not means:
    # equal to the direct sums within float32 rounding (rel. 1e-4).
    assert terms["strain"] == pytest.approx(direct["strain"], rel=1e-4)
    assert terms["collision"] == pytest.approx(direct["collision"], rel=1e-4)
    assert terms["strain"] > 0 and terms["collision"] > 0  # stretched; tissue in the tool
    # The same scene in metres instead of millimetres gives the same energies (rel. 1e-3:
    # float32 lengths 1000 times smaller).
    in_metres, _ = _energies(1e-3)
    assert in_metres["strain"] == pytest.approx(terms["strain"], rel=1e-3)
    assert in_metres["collision"] == pytest.approx(terms["collision"], rel=1e-3)


def _tool_before_tissue(opacity: float):
    """A tissue Gaussian (row 0, 20 mm deep) behind a large tool Gaussian (row 1, 14 mm), both
    of `opacity`, under a tool mask covering a black image: (gaussians, field, model, camera,
    frame)."""
    means = torch.tensor([[0.0, 0.0, 20.0], [0.0, 0.0, 14.0]])
    gaussians = GaussianModel.from_points(means, torch.full((2, 3), 0.5),
                                          GaussianConfig(init_opacity=opacity),
                                          {SEMANTIC_KEY: torch.tensor([4.0, -4.0])})
    with torch.no_grad():
        gaussians.params["log_scales"].fill_(math.log(3.0))
    field = _tool_field()
    with torch.no_grad():
        field.rotations.zero_()
        field.translations.zero_()
    model = SplatModel(gaussians, {"tool": field})
    camera = _camera()
    full = torch.ones(camera.height, camera.width, dtype=torch.bool)
    frame = Frame(0, 0.0, torch.zeros(camera.height, camera.width, 3), None, False, camera,
                  tool=full, fov=full)
    return gaussians, field, model, camera, frame


def test_mask_loss_never_flips_tissue_hidden_behind_the_tool():
    """A large opaque tool Gaussian in front of a tissue Gaussian, under a tool mask covering
    the image: the hidden tissue's blend weight is ~1e-3, but per-Gaussian Adam would move its
    logit by ~lr per step regardless. 300 steps at lr 0.05 (15 logit units, past the init 4)
    must leave it tissue (logit unchanged to 1e-6) while the tool's logit moves towards tool."""
    gaussians, field, model, camera, frame = _tool_before_tissue(0.99)
    logits = gaussians.params[SEMANTIC_KEY]
    optimiser = torch.optim.Adam([logits], lr=0.05)
    when = FrameTime(0, 0.0, tool_pixels=frame.tool)
    for iteration in range(1, 301):
        output, state = model.render(camera, when)
        context = RenderContext(frame=frame, when=when, camera=camera, output=output,
                                state=state, gaussians=gaussians, iteration=iteration)
        optimiser.zero_grad()
        field.losses(context, frozenset({"mask"}))["mask"].backward()
        optimiser.step()
    assert logits[0].item() == pytest.approx(4.0, abs=1e-6)
    assert logits[1].item() < -4.0 - 1.0


def test_no_loss_through_the_render_reaches_hidden_tissue():
    """The tool Gaussian in front of the tissue Gaussian: the photometric and mask losses
    against a dark tool reach the tool's colour, opacity, position, scale and rotation, but
    not the hidden tissue's (exactly 0: through the tool's residual transmittance they would
    paint the tissue in the tool's colours and move it out from behind the tool); a loss on
    the state itself (as the biomechanical energies are) still moves the hidden tissue. With
    the tool moved aside but the frame's mask still marking tool there (a rendered tool
    thinner than the frame's), the mask loss still must not reach the tissue (it would fade
    and move it away); once the frame shows tissue there, its render gradients are back, and
    where the frame shows tissue on half of the image only, the tissue Gaussian centred on the
    tool half learns from the tissue half (the gate is per pixel, not per Gaussian)."""
    gaussians, field, model, camera, frame = _tool_before_tissue(0.9)
    with torch.no_grad():  # anisotropic and turned, so that rotations have a gradient
        gaussians.params["log_scales"].copy_(torch.tensor([[3.0, 2.0, 1.0]]).log())
        gaussians.params["quats"].copy_(torch.tensor([[0.9, 0.3, 0.2, 0.1]]))
    names = ("sh_dc", "opacity_logits", "means", "log_scales", "quats")

    def gradients(state_weight: float = 0.0, seen: Frame = frame) -> dict[str, Tensor]:
        """|gradient| per Gaussian [2] of each parameter in `names`, against frame `seen`."""
        for parameter in gaussians.params.values():
            parameter.grad = None
        when = FrameTime(0, 0.0, tool_pixels=seen.tool)
        output, state = model.render(camera, when)
        context = RenderContext(frame=seen, when=when, camera=camera, output=output,
                                state=state, gaussians=gaussians, iteration=1)
        loss = field.losses(context, frozenset({"mask"}))["mask"] + output.rgb.abs().mean()
        (loss + state_weight * state.means.sum()).backward()
        return {name: gaussians.params[name].grad.abs().reshape(2, -1).sum(dim=1)
                for name in names}

    hidden = gradients()
    for name in names:
        assert hidden[name][0] == 0, name  # hidden tissue
        assert hidden[name][1] > 0, name  # the tool
    assert gradients(state_weight=1.0)["means"][0] > 0
    with torch.no_grad():
        field.translations[0, 0] = 30.0  # the tool leaves the view
    on_tool_pixels = gradients()  # the frame's mask still says tool there
    for name in names:
        assert on_tool_pixels[name][0] == 0, name
    visible = gradients(seen=frame.with_tool(torch.zeros_like(frame.tool)))  # tissue shown
    for name in names:
        assert visible[name][0] > 0, name
    left = torch.zeros_like(frame.tool)
    left[:, :camera.width // 2 + 4] = True  # the tissue's centre is on a tool pixel
    half = gradients(seen=frame.with_tool(left))
    for name in names:
        assert half[name][0] > 0, name


def test_specular_normals_are_smoothed_against_depth_jitter():
    """A plane facing the camera at 90 mm with 0.05 mm of white depth jitter, at the phantom's
    focal length (569 px): one-pixel differences tilt the normal by ~15 degrees (median), the
    smoothed depth by < 3; a plane without jitter keeps its exact depth (abs. 1e-4 mm)."""
    K = torch.tensor([[569.5, 0.0, 80.0], [0.0, 569.5, 64.0], [0.0, 0.0, 1.0]])
    generator = torch.Generator().manual_seed(0)
    noisy = 90.0 + 0.05 * torch.randn(128, 160, generator=generator)

    def median_tilt_deg(depth: Tensor) -> float:
        normals, valid = depth_normals(depth, K)
        tilt = torch.acos(normals[..., 2][valid].abs().clamp(max=1.0))
        return float(torch.rad2deg(tilt).median())

    assert median_tilt_deg(noisy) > 10.0
    assert median_tilt_deg(smooth_depth(noisy)) < 3.0
    flat = torch.full((128, 160), 90.0)
    flat[:, :20] = 0.0  # no depth there: stays 0, and does not pull its neighbours down
    smoothed = smooth_depth(flat)
    assert torch.all(smoothed[:, :20] == 0)
    torch.testing.assert_close(smoothed[:, 20:], flat[:, 20:], atol=1e-4, rtol=0)


def test_view_cosine_matches_the_normals_of_depth_normals():
    """The closed-form n . v equals the cosine between `depth_normals` and the pixel rays on a
    tilted, curved surface with holes (float64, abs. 1e-9), with the same valid pixels."""
    K = torch.tensor([[50.0, 0.0, 20.0], [0.0, 45.0, 14.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    y, x = torch.meshgrid(torch.arange(30, dtype=torch.float64),
                          torch.arange(40, dtype=torch.float64), indexing="ij")
    depth = 60.0 + 0.4 * x - 0.3 * y + 2.0 * torch.sin(x / 5.0) * torch.cos(y / 7.0)
    depth[5:8, 10:14] = 0.0
    cosine, valid = view_cosine(depth, K)
    normals, expected_valid = depth_normals(depth, K)
    rays = torch.nn.functional.normalize(pixel_rays(K, 40, 30, torch.float64), dim=-1)
    expected = (normals * rays).sum(-1).clamp(0.0, 1.0)
    assert torch.equal(valid, expected_valid)
    torch.testing.assert_close(cosine[valid], expected[valid], atol=1e-9, rtol=0)


def test_the_mask_loss_is_torch_binary_cross_entropy_over_the_masked_pixels():
    """The mask loss against F.binary_cross_entropy of the gathered pixels: value and gradient
    (float64, tolerance 1e-12); 0 on an empty mask."""
    generator = torch.Generator().manual_seed(0)
    probability = (torch.rand(12, 9, generator=generator, dtype=torch.float64) * 0.98
                   + 0.01).requires_grad_()
    target = torch.rand(12, 9, generator=generator) > 0.6
    mask = torch.rand(12, 9, generator=generator) > 0.3
    ours = masked_binary_cross_entropy(probability, target, mask)
    (ours_grad,) = torch.autograd.grad(ours, probability)
    reference = torch.nn.functional.binary_cross_entropy(probability[mask],
                                                         target[mask].double())
    (reference_grad,) = torch.autograd.grad(reference, probability)
    torch.testing.assert_close(ours, reference, atol=1e-12, rtol=1e-12)
    torch.testing.assert_close(ours_grad, reference_grad, atol=1e-12, rtol=1e-12)
    empty = masked_binary_cross_entropy(probability, target, torch.zeros_like(mask))
    assert float(empty) == 0.0


@pytest.mark.parametrize("band", [0.0, 4.0])
def test_tissue_gradient_weights_ramp_away_from_the_tool_mask(band):
    """The tissue Gaussians' gradient weights of a training render: 0 on the tool mask, and with
    edge_band_px, distance / band beyond it up to 1 (without, 1 on every tissue pixel); the tool
    Gaussians are not among the weighted ones."""
    field = ToolFieldConfig(num_frames=2, edge_band_px=band).build()
    tool = torch.zeros(6, 12, dtype=torch.bool)
    tool[:, :3] = True  # columns 0..2; column 3 is 1 px from the tool, column 7 is 5 px
    points = torch.arange(12, dtype=torch.float32).reshape(4, 3)
    gaussians = GaussianModel.from_points(  # two tissue Gaussians (s >= 0), then two tool ones
        points, torch.full((4, 3), 0.5), GaussianConfig(),
        attributes={SEMANTIC_KEY: torch.tensor([4.0, 4.0, -4.0, -4.0])})
    weights = field.gradient_weights(gaussians, FrameTime(1, 0.5, tool_pixels=tool))
    assert weights.members.tolist() == [True, True, False, False]
    expected_row = torch.tensor([0, 0, 0, *(min(d / band, 1.0) if band else 1.0
                                            for d in range(1, 10))], dtype=torch.float32)
    assert torch.allclose(weights.weights, expected_row.expand(6, 12), atol=1e-6)
    assert field.gradient_weights(gaussians, FrameTime(1, 0.5)) is None  # not a training render


@pytest.mark.parametrize("densify_tool", [False, True])
def test_densification_near_the_tool_is_kept_from_tissue_and_from_the_tool_unless_asked(
        densify_tool):
    """A tissue Gaussian inside the tool proxy gets densification weight 0 either way; the tool
    Gaussian too by default, and its full weight with `densify_tool`."""
    means = torch.tensor([[0.0, 0.0, 14.5], [0.0, 0.0, 14.0]])  # tissue, then tool
    gaussians = GaussianModel.from_points(means, torch.full((2, 3), 0.5),
                                          GaussianConfig(init_opacity=0.9),
                                          {SEMANTIC_KEY: torch.tensor([4.0, -4.0])})
    with torch.no_grad():
        gaussians.params["log_scales"].fill_(math.log(3.0))
    field = ToolFieldConfig(num_frames=4, densify_tool=densify_tool).build()
    with torch.no_grad():
        field.known[:] = True
        field.seen[:] = True
    model = SplatModel(gaussians, {"tool": field})
    camera = _camera()
    full = torch.ones(camera.height, camera.width, dtype=torch.bool)
    frame = Frame(0, 0.0, torch.zeros(camera.height, camera.width, 3), None, False, camera,
                  tool=full, fov=full)
    when = FrameTime(0, 0.0, tool_pixels=frame.tool)
    output, state = model.render(camera, when)
    context = RenderContext(frame=frame, when=when, camera=camera, output=output, state=state,
                            gaussians=gaussians, iteration=1)
    weights = field.densify_weights(context)
    assert weights.tolist() == [0.0, 1.0 if densify_tool else 0.0]

