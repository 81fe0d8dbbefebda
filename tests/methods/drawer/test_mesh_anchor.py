"""Mesh-anchored Gaussians (DRAWER): face frames, clips, straight-through gradients, re-anchoring,
the bind / before_render / after_step hooks, and a tiny `drawer` run."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
import torch
from torch import Tensor, nn

from surgsplat.data.scene import load_scene
from surgsplat.export.mesh import MeshExtractor, MeshOptions
from surgsplat.methods.endogsg.sdf import SDFConfig, SDFField
from surgsplat.methods.registry import method_config
from surgsplat.model.capabilities import SignedDistanceField
from surgsplat.model.component import Component, ComponentConfig, FrameTime, RenderContext
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.methods.drawer.mesh_anchor import (ANCHOR_KEY, MeshAnchor, MeshAnchorConfig, clip_tilt,
                                         clip_in_triangle, face_frames, inradius,
                                         planar_corners, to_face_local, to_world)
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState
from surgsplat.render.rotation import quaternion_third_axis, quaternion_to_matrix
from surgsplat.train.per_gaussian import append_gaussians
from surgsplat.train.trainer import Trainer

pytest.importorskip("skimage")


FLAT_ANCHORS = MeshAnchorConfig(resolution=24, normal_scale_ratio=0.25, max_tilt_deg=30.0)
"""Every clip acting: the normal scale below the in-face ones, the tilt bounded."""


def random_faces(count: int, generator: torch.Generator) -> Tensor:
    """[count, 3, 3] float64 triangles of random shape, position and orientation."""
    return torch.randn(count, 3, 3, dtype=torch.float64, generator=generator) * 2.0


def barycentric(points: Tensor, corners: Tensor) -> Tensor:
    """[P, 3] barycentric coordinates of in-plane points [P, 2] (face coordinates)."""
    p1, p2 = planar_corners(corners)
    matrix = torch.stack([p1, p2], dim=-1)  # [P, 2, 2] columns p1, p2
    lambdas = torch.linalg.solve(matrix, points)
    return torch.cat([1.0 - lambdas.sum(dim=1, keepdim=True), lambdas], dim=1)


def test_face_local_coordinates_round_trip_in_float64():
    generator = torch.Generator().manual_seed(0)
    corners = random_faces(500, generator)
    points = torch.randn(500, 3, dtype=torch.float64, generator=generator) * 5.0
    frames = face_frames(corners)
    eye = torch.eye(3, dtype=torch.float64).expand(500, 3, 3)
    torch.testing.assert_close(frames.transpose(1, 2) @ frames, eye, atol=1e-12, rtol=0)
    assert torch.all(torch.linalg.det(frames) > 0)  # right-handed
    local = to_face_local(points, corners)
    torch.testing.assert_close(to_world(local, corners[:, 0], face_frames(corners)), points, atol=1e-12, rtol=0)
    # v1 lies on the x axis, v2 above it, every corner in the plane z = 0
    corner_local = to_face_local(corners, corners[:, None].expand(-1, 3, 3, 3))
    torch.testing.assert_close(corner_local[:, :, 2], torch.zeros(500, 3, dtype=torch.float64),
                               atol=1e-12, rtol=0)
    assert torch.all(corner_local[:, 2, 1] > 0)


def test_clip_keeps_positions_in_the_face_and_offsets_in_their_band():
    generator = torch.Generator().manual_seed(1)
    corners = random_faces(400, generator)
    local = torch.randn(400, 3, dtype=torch.float64, generator=generator) * 4.0
    band = inradius(corners) * 2.0
    clipped = clip_in_triangle(local, *planar_corners(corners), band)
    assert torch.all(clipped[:, 2].abs() <= band + 1e-12)
    assert torch.all(barycentric(clipped[:, :2], corners) >= -1e-9)
    # a point already inside the triangle and the band is left where it is
    weights = torch.rand(400, 3, dtype=torch.float64, generator=generator)
    weights = weights / weights.sum(dim=1, keepdim=True)
    inside = to_face_local((weights[:, :, None] * corners).sum(dim=1), corners)
    inside[:, 2] = band * 0.5
    torch.testing.assert_close(clip_in_triangle(inside, *planar_corners(corners), band), inside, atol=1e-10, rtol=0)


def test_tilt_clip_bounds_the_angle_to_the_normal_and_keeps_small_tilts():
    generator = torch.Generator().manual_seed(2)
    quats = torch.randn(300, 4, dtype=torch.float64, generator=generator)
    normals = nn.functional.normalize(torch.randn(300, 3, dtype=torch.float64,
                                                  generator=generator), dim=1)
    limit = math.radians(20.0)
    clipped = clip_tilt(quats, normals, limit)
    axis3 = quaternion_to_matrix(clipped)[..., 2]
    tilt = torch.arccos((axis3 * normals).sum(dim=1).abs().clamp(max=1.0))
    assert float(tilt.max()) <= limit + 1e-6
    before = quaternion_to_matrix(quats)[..., 2]
    small = torch.arccos((before * normals).sum(dim=1).abs().clamp(max=1.0)) <= limit
    assert small.any()
    torch.testing.assert_close(quaternion_to_matrix(clipped[small]),
                               quaternion_to_matrix(quats[small]), atol=1e-9, rtol=0)


@dataclass
class BallConfig(ComponentConfig, kind="test_ball_sdf"):
    """A sphere of `radius` as the method's signed distance field."""

    radius: float = 1.0

    def build(self) -> "Ball":
        return Ball(self.radius)


class Ball(Component):
    phase = Phase.LOSS  # offers a signed distance field, changes nothing
    provides = (SignedDistanceField,)

    def __init__(self, radius: float):
        super().__init__()
        self.radius = radius
        self.register_buffer("box", torch.tensor([[-1.5] * 3, [1.5] * 3]))

    def signed_distance(self, points: Tensor) -> Tensor:
        return points.norm(dim=1) - self.radius


def anchored_model(count: int, ball: Ball, config: MeshAnchorConfig) -> tuple[MeshAnchor,
                                                                               GaussianModel]:
    generator = torch.Generator().manual_seed(3)
    direction = nn.functional.normalize(torch.randn(count, 3, generator=generator), dim=1)
    points = direction * (ball.radius + 0.2 * torch.randn(count, 1, generator=generator))
    buffers = {ANCHOR_KEY: torch.full((count,), -1, dtype=torch.long)}
    gaussians = GaussianModel.from_points(points, torch.rand(count, 3, generator=generator),
                                          GaussianConfig(), buffers=buffers)
    gaussians.params["quats"].data = torch.randn(count, 4, generator=generator)
    gaussians.params["log_scales"].data += 1.0  # larger than the clip allows
    anchor = config.build()
    anchor.bind({"anchor": anchor, "sdf": ball})
    return anchor, gaussians


def state_of(gaussians: GaussianModel) -> GaussianState:
    params = gaussians.params
    return GaussianState(params["means"], params["log_scales"].exp(), params["quats"],
                         torch.sigmoid(params["opacity_logits"]), gaussians.sh_coeffs(), 1)


def within_band(anchor: MeshAnchor, gaussians: GaussianModel, state: GaussianState,
                tolerance: float) -> None:
    """Every anchored centre lies in its face's triangle and normal band, with scales and tilt
    within their limits (tolerance: scene units)."""
    config = anchor.config
    corners = anchor.vertices[anchor.faces[gaussians.buffer_dict[ANCHOR_KEY]]].double()
    radius = inradius(corners).clamp_min(config.min_face_radius * float(anchor.cell))
    local = to_face_local(state.means.detach().double(), corners)
    assert torch.all(local[:, 2].abs() <= config.offset_band * radius + tolerance)
    # inside the triangle: the distance to each edge's line (barycentric coordinate times the
    # height over that edge) is at least -tolerance; in barycentric units a float32 rounding of
    # the centre would look large on the marching-cubes mesh's sliver faces
    v0, v1, v2 = corners.unbind(-2)
    double_area = torch.cross(v1 - v0, v2 - v0, dim=-1).norm(dim=-1)
    edges = torch.stack([(v2 - v1).norm(dim=-1), (v0 - v2).norm(dim=-1), (v1 - v0).norm(dim=-1)],
                        dim=-1)  # the edge opposite each corner
    heights = double_area.unsqueeze(-1) / edges
    assert torch.all(barycentric(local[:, :2], corners) * heights >= -tolerance)
    limit = config.scale_limit * radius
    scales = state.scales.detach().double()
    assert torch.all(scales[:, :2] <= limit[:, None] + tolerance)
    assert torch.all(scales[:, 2] <= limit * config.normal_scale_ratio + tolerance)
    axis3 = quaternion_to_matrix(state.quats.detach().double())[..., 2]
    cosine = (axis3 * face_frames(corners)[..., 2]).sum(dim=1).abs().clamp(max=1.0)
    assert float(torch.arccos(cosine).max()) <= math.radians(config.max_tilt_deg) + 1e-4


def test_anchored_centres_are_clipped_straight_through_and_the_shapes_are_projected():
    ball = Ball(1.0)
    anchor, gaussians = anchored_model(600, ball, FLAT_ANCHORS)
    raw = state_of(gaussians)
    assert anchor.transform(raw, gaussians, FrameTime(0, 0.0)) is raw  # no mesh yet
    log_scales = gaussians.params["log_scales"].detach().clone()
    anchor.before_render(gaussians, FrameTime(0, 0.0))
    assert anchor.unanchored(gaussians).numel() == 0  # anchored before the first render
    assert float((log_scales - gaussians.params["log_scales"].detach()).max()) > 0.1  # projected
    raw = state_of(gaussians)
    state = anchor.transform(raw, gaussians, FrameTime(0, 0.0))
    # resolution 24 over a box of side 3: cells of 0.125; floats: tolerance 1e-5
    within_band(anchor, gaussians, state, 1e-5)
    assert state.scales is raw.scales and state.quats is raw.quats  # the parameters, drawn
    assert float((state.means.detach() - raw.means.detach()).norm(dim=1).max()) > 0.05
    weights = torch.randn(600, 3)
    loss = (weights * state.means).sum() + (weights * state.scales).sum() \
        + (weights[:, :1] * state.quats).sum()
    loss.backward()
    params = gaussians.params
    torch.testing.assert_close(params["means"].grad, weights, atol=0, rtol=0)  # straight-through
    torch.testing.assert_close(params["log_scales"].grad, weights * params["log_scales"].exp(),
                               atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(params["quats"].grad[:, 0], weights[:, 0], atol=0, rtol=0)


def test_after_a_step_the_shapes_are_projected_again_and_the_centres_stay_raw():
    ball = Ball(1.0)
    anchor, gaussians = anchored_model(400, ball, FLAT_ANCHORS)
    anchor.before_render(gaussians, FrameTime(0, 0.0))
    params = gaussians.params
    generator = torch.Generator().manual_seed(4)
    with torch.no_grad():  # an optimiser step that grows most past their clips, and turns them
        params["log_scales"] += torch.randn(400, 3, generator=generator)
        params["quats"] += torch.randn(400, 4, generator=generator)
    stepped = {name: params[name].detach().clone() for name in ("means", "log_scales", "quats")}
    anchor.after_step(gaussians, 1)  # not a re-anchoring step
    within_band(anchor, gaussians, anchor.transform(state_of(gaussians), gaussians,
                                                    FrameTime(0, 0.0)), 1e-5)
    assert torch.equal(params["means"], stepped["means"])
    assert float((stepped["log_scales"] - params["log_scales"].detach()).max()) > 0.1  # clipped
    assert torch.all(params["log_scales"] <= stepped["log_scales"])  # only ever shrunk
    assert (params["log_scales"] == stepped["log_scales"]).any()  # a scale within its clip
    projected = {name: params[name].detach().clone() for name in ("log_scales", "quats")}
    anchor.after_step(gaussians, 2)  # idempotent
    torch.testing.assert_close(params["log_scales"], projected["log_scales"], atol=0, rtol=0)
    torch.testing.assert_close(params["quats"], projected["quats"], atol=1e-6, rtol=0)


def test_the_third_axis_is_the_rotation_matrix_third_column():
    quats = torch.randn(200, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    torch.testing.assert_close(quaternion_third_axis(quats), quaternion_to_matrix(quats)[..., 2],
                               atol=1e-12, rtol=0)


def test_reanchoring_after_densification_keeps_every_gaussian_on_a_valid_face():
    ball = Ball(1.0)
    anchor, gaussians = anchored_model(300, ball, FLAT_ANCHORS)
    anchor.before_render(gaussians, FrameTime(0, 0.0))
    optimizer = torch.optim.Adam([{"name": name, "params": [param]}
                                  for name, param in gaussians.params.items()])
    rows = gaussians.per_gaussian()
    copies = {name: value.detach()[:50].clone() for name, value in rows.items()}
    fresh = {name: value.detach()[50:80].clone() for name, value in rows.items()}
    fresh[ANCHOR_KEY].fill_(-1)  # Gaussians no face was given yet
    append_gaussians(gaussians, optimizer, {name: torch.cat([copies[name], fresh[name]])
                                            for name in copies})
    ball.radius = 0.8  # the surface moved: the next mesh has other faces
    anchor.after_step(gaussians, anchor.config.reanchor_every)
    assert anchor.unanchored(gaussians).numel() == 0
    radius = anchor.vertices.norm(dim=1)
    assert float((radius - 0.8).abs().max()) < 0.02  # the new mesh (cells of 0.125)
    state = anchor.transform(state_of(gaussians), gaussians, FrameTime(0, 0.0))
    within_band(anchor, gaussians, state, 1e-5)


class BallField(SDFField):
    """Endo-GSG's SDF component with the analytic field of a unit sphere."""

    def signed_distance(self, points: Tensor) -> Tensor:
        return points.norm(dim=1) - 1.0


def test_the_mesh_export_uses_the_anchored_centres_and_the_sdf_the_raw_means():
    """Without deformation nothing moves: the exported mesh at any time is the canonical one (no
    anchor clip offset added; tolerance 1e-6). The SDF's bell and losses are taken at the raw
    means: at the anchored centres f is 0 by construction, and the projection loss could never
    pull a drifting mean back (on the full phantom that lost half the mesh, issue 28)."""
    field = BallField(SDFConfig(resolutions=(2,)))
    field.box.copy_(torch.tensor([[-1.5] * 3, [1.5] * 3]))
    anchor, gaussians = anchored_model(400, Ball(1.0), FLAT_ANCHORS)
    model = SplatModel(gaussians, {"anchor": anchor, "sdf": field})
    when = FrameTime(3, 0.5)
    model.before_render(when)
    rendered = model.state_at(when).means.detach()
    raw = gaussians.params["means"].detach()
    assert float((rendered - raw).norm(dim=1).max()) > 0.05  # the clip acted
    torch.testing.assert_close(model.canonical_means().detach(), rendered, atol=0, rtol=0)
    torch.testing.assert_close(model.opacity_factor(), field.bell(field.signed_distance(raw)),
                               atol=1e-6, rtol=0)
    context = RenderContext(frame=None, when=when, camera=None, output=None, state=None,
                            gaussians=gaussians, iteration=1)
    loss = field.losses(context, frozenset({"projection"}))["projection"]
    loss.backward()
    off_surface = (raw.norm(dim=1) - 1.0).abs() > 1e-3
    assert float(loss.detach()) > 0
    assert bool(torch.all(gaussians.params["means"].grad[off_surface].abs().sum(dim=1) > 0))
    extractor = MeshExtractor(model, MeshOptions(resolution=24, fit_radius=0.0))
    vertices, _, _ = extractor.canonical_mesh()
    np.testing.assert_allclose(extractor._carry(vertices, when), vertices, atol=1e-6, rtol=0)


def test_a_run_saves_and_restores_the_mesh_of_its_anchors():
    ball = Ball(1.0)
    anchor, gaussians = anchored_model(100, ball, MeshAnchorConfig(resolution=16))
    anchor.before_render(gaussians, FrameTime(0, 0.0))
    restored = MeshAnchorConfig(resolution=16).build()
    restored.load_state_dict(anchor.state_dict())
    assert torch.equal(restored.faces, anchor.faces)
    assert torch.equal(restored.vertices, anchor.vertices)


def test_mesh_anchor_without_a_signed_distance_field_is_one_clear_error():
    with pytest.raises(Exception, match="mesh_anchor needs a component with a signed distance"):
        anchor = MeshAnchorConfig().build()
        anchor.bind({"anchor": anchor})


STEPS_SEEN: list[int] = []


@dataclass
class StepRecorderConfig(ComponentConfig, kind="test_step_recorder"):
    """Records the iterations after_step is called with."""

    def build(self) -> "StepRecorder":
        return StepRecorder()


class StepRecorder(Component):
    phase = Phase.LOSS

    def after_step(self, gaussians: GaussianModel, iteration: int) -> None:
        assert not torch.is_grad_enabled()
        STEPS_SEEN.append(iteration)


@pytest.mark.slow
def test_a_tiny_drawer_run_keeps_its_gaussians_in_the_band_of_the_mesh(small_phantom, tmp_path):
    scene = load_scene(small_phantom)
    config = method_config("drawer")
    config.train.iterations = 8
    config.components["anchor"].reanchor_every = 4
    config.components["anchor"].resolution = 64
    config.components["sdf"].fit_steps = 40
    config.components["recorder"] = StepRecorderConfig()
    config.densify.start, config.densify.every = 0.5, 4  # densify before the last re-anchor
    STEPS_SEEN.clear()
    trainer = Trainer(config, scene, tmp_path / "run")
    count = trainer.model.gaussians.num_gaussians
    trainer.fit()
    assert STEPS_SEEN == list(range(1, 9))
    model = trainer.model
    anchor = model.components["anchor"]
    gaussians = model.gaussians
    assert gaussians.num_gaussians != count  # densification changed the Gaussians
    assert anchor.unanchored(gaussians).numel() == 0
    state = anchor.transform(model.canonical_state(), gaussians, FrameTime(0, 0.0))
    tissue = gaussians.params["semantic_logit"].detach() >= 0
    assert tissue.sum() > 0 and (~tissue).sum() > 0  # the tool field kept its tool Gaussians
    sub = GaussianState(state.means[tissue], state.scales[tissue], state.quats[tissue],
                        state.opacities[tissue], state.sh[tissue], state.sh_degree)
    keep = GaussianModel({name: value.detach()[tissue] for name, value in gaussians.params.items()},
                         gaussians.sh_degree,
                         {name: value[tissue] for name, value in gaussians.buffer_dict.items()})
    within_band(anchor, keep, sub, 1e-4)  # scene units (mm), float32 on a ~50 mm scene
