"""EndoPlanar's planar Gaussians as a component: unbiased depth, flattening and normal losses."""

import math

import torch

from surgsplat.data.scene import Camera, Frame
from surgsplat.image.pinhole import pixel_rays
from surgsplat.model.component import FrameTime, RenderContext
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GaussianModel
from surgsplat.model.planar import PlanarConfig

W, H = 48, 40
K = torch.tensor([[40.0, 0, W / 2], [0, 40.0, H / 2], [0, 0, 1]])
CAMERA = Camera(K=K, world_to_camera=torch.eye(4), width=W, height=H)
ANGLE, DISTANCE = 0.5, 3.0


def tilted_plane_model(spacing: float = 0.05, thickness: float = 1e-6) -> SplatModel:
    """Flat Gaussians tiling n . X = DISTANCE cos(ANGLE), n = (sin a, 0, cos a)."""
    xs = torch.arange(-2.5, 2.5, spacing)
    x, y = (v.reshape(-1) for v in torch.meshgrid(xs, xs, indexing="ij"))
    z = (DISTANCE * math.cos(ANGLE) - x * math.sin(ANGLE)) / math.cos(ANGLE)
    n = x.shape[0]
    params = {
        "means": torch.stack([x, y, z], dim=1),
        "log_scales": torch.tensor([spacing, spacing, thickness]).log().repeat(n, 1),
        "quats": torch.tensor([math.cos(ANGLE / 2), 0, math.sin(ANGLE / 2), 0]).repeat(n, 1),
        "opacity_logits": torch.full((n,), 3.0),
        "sh_dc": torch.zeros(n, 3),
        "sh_rest": torch.zeros(n, 0, 3),
    }
    return SplatModel(GaussianModel(params, sh_degree=0), {"planar": PlanarConfig().build()})


def true_depth() -> torch.Tensor:
    normal = torch.tensor([math.sin(ANGLE), 0.0, math.cos(ANGLE)])
    return DISTANCE * math.cos(ANGLE) / (pixel_rays(K, W, H) @ normal)


def context_for(model: SplatModel, measured: torch.Tensor) -> RenderContext:
    when = FrameTime(0, 0.0)
    output, state = model.render(CAMERA, when)
    frame = Frame(index=0, time=0.0, image=torch.zeros(H, W, 3), depth=measured, is_test=False,
                  camera=CAMERA, tool=torch.zeros(H, W, dtype=torch.bool),
                  fov=torch.ones(H, W, dtype=torch.bool))
    return RenderContext(frame=frame, when=when, camera=CAMERA, output=output, state=state,
                         gaussians=model.gaussians, iteration=1)


def test_render_depth_is_the_unbiased_plane_depth():
    model = tilted_plane_model()
    output, _ = model.render(CAMERA, FrameTime(0, 0.0))
    covered = output.alpha > 0.99
    assert covered.float().mean() > 0.9
    relative = ((output.depth - true_depth()).abs() / true_depth())[covered]
    assert relative.max() < 1e-3
    # the expected depth of thin discs is close too, but it is kept apart
    assert "expected_depth" in output.extras and "plane_distance" not in output.extras


def test_losses_vanish_on_a_flat_consistent_plane_and_not_otherwise():
    model = tilted_plane_model()
    context = context_for(model, true_depth())
    terms = model.losses(context, frozenset({"flatten", "normal"}))
    assert float(terms["flatten"].detach()) < 1e-5  # the smallest scale is 1e-6
    assert float(terms["normal"].detach()) < 0.02  # rendered normals agree with the depth's normals
    thick = tilted_plane_model(thickness=0.05)
    assert float(thick.losses(context_for(thick, true_depth()), frozenset({"flatten"}))["flatten"].detach()) \
        > 0.04
    # rotate every Gaussian's disc away from the plane: the normals now disagree with the depth
    tilted = tilted_plane_model()
    with torch.no_grad():
        tilted.gaussians.params["quats"][:] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    assert float(tilted.losses(context_for(tilted, true_depth()),
                               frozenset({"normal"}))["normal"].detach()) > 0.1


def test_edge_aware_weight_ignores_measured_depth_steps():
    """Where the measured depth changes steeply (relative gradient >= 1 per pixel), the normal
    error is not counted."""
    tilted = tilted_plane_model()
    with torch.no_grad():
        tilted.gaussians.params["quats"][:] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    columns = torch.arange(W, dtype=torch.float32)
    steps = true_depth() * torch.exp(1.5 * (columns - W // 2))  # 1.5 e-folds per pixel
    aware = tilted.losses(context_for(tilted, steps), frozenset({"normal"}))["normal"]
    assert float(aware.detach()) < 1e-6
    tilted.components["planar"].config.edge_aware = False
    plain = tilted.losses(context_for(tilted, steps), frozenset({"normal"}))["normal"]
    assert float(plain.detach()) > 0.1
