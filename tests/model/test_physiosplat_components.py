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

from surgsplat.data.scene import Camera
from surgsplat.fields.deformation import Deformation, DeformationField
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import SplatModel, render_frame
from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.model.physics import (SEMANTIC_KEY, arap_strain, collision_energy, hull_planes,
                                     hull_sdf, neighbour_graph, tool_hull)
from surgsplat.model.specular import specular_lobe
from surgsplat.model.tool_field import ToolFieldConfig, _icp
from surgsplat.render.render import render
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


def test_hull_signed_distance_of_a_cube():
    corners = torch.tensor([[x, y, z] for x in (0.0, 2.0) for y in (0.0, 2.0) for z in (0.0, 2.0)])
    planes = hull_planes(corners)
    probes = torch.tensor([[1.0, 1.0, 1.0], [1.0, 1.0, 1.8], [3.0, 1.0, 1.0]])
    torch.testing.assert_close(hull_sdf(probes, planes), torch.tensor([-1.0, -0.2, 1.0]))
    assert hull_planes(corners[:3]) is None  # no volume
    hull = tool_hull(corners, torch.ones(8), torch.ones(8, dtype=torch.bool), 0.5)
    far = torch.tensor([[50.0, 0.0, 0.0]])
    assert hull.sdf(far, 4.0).item() == 4.0  # culled: at least the clearance away


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
    assert squeeze.volume_loss(gaussians, 0.3).item() == pytest.approx(0.04, rel=1e-4)
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
    cube = torch.tensor([[x, y, z] for x in (0.0, 2.0) for y in (0.0, 2.0) for z in (0.0, 2.0)],
                        dtype=torch.float64)
    planes = hull_planes(cube)
    probes = torch.tensor([[1.0, 1.1, 1.7], [2.3, 0.9, 1.2], [0.4, 1.0, 0.8]],
                          dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(
        lambda x: collision_energy(hull_sdf(x, planes), 0.5).sum(), (probes,))


def test_specular_lobe_peaks_facing_the_camera_and_has_checked_gradients():
    K = torch.tensor([[40.0, 0.0, 16.0], [0.0, 40.0, 12.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    depth = torch.full((24, 32), 50.0, dtype=torch.float64)  # a plane facing the camera
    albedo = torch.full((24, 32), 0.3, dtype=torch.float64, requires_grad=True)
    sharpness = torch.full((24, 32), 20.0, dtype=torch.float64, requires_grad=True)
    lobe = specular_lobe(depth, K, albedo, sharpness)
    cosine = 1.0 / math.sqrt(1.0 + 2 * (0.5 / 40.0) ** 2)  # pixel (16, 12): centre (16.5, 12.5)
    assert lobe[12, 16].item() == pytest.approx(0.3 * math.exp((cosine - 1.0) * 20.0), rel=1e-6)
    assert lobe[2, 2] < lobe[12, 16]  # oblique view at the corner: dimmer
    assert lobe[0, 0].item() == 0.0  # border pixels have no depth normal
    small_a = albedo[10:13, 14:17].detach().clone().requires_grad_()
    small_s = sharpness[10:13, 14:17].detach().clone().requires_grad_()
    assert torch.autograd.gradcheck(
        lambda a, s: specular_lobe(depth[9:14, 13:18], K, torch.nn.functional.pad(a, (1, 1, 1, 1)),
                                   torch.nn.functional.pad(s, (1, 1, 1, 1))), (small_a, small_s))
    assert math.isfinite(float(lobe.detach().sum()))
