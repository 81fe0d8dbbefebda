"""The tool field's articulated motion: parts split at the hinge, jaws turned about it (exactly,
with checked gradients), the tool field moving its jaws per frame, and its set-up recovering
the small phantom's hinge and jaw angles."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from surgsplat.data.phantom.kinematics import TOOL_KINEMATICS_FILE
from surgsplat.data.scene import load_scene
from surgsplat.eval.articulation_metrics import articulation_metrics
from surgsplat.export.articulation import OWN_JOINTS, articulate
from surgsplat.methods.overrides import apply_values
from surgsplat.methods.physiosplat.tool_field import SEMANTIC_KEY, ToolFieldConfig
from surgsplat.methods.physiosplat.tool_joints import Hinge, jaw_parts, turn_jaws
from surgsplat.methods.registry import method_config
from surgsplat.model.articulation import JAW_A, JAW_B, SHAFT
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.render.rotation import quaternion_to_matrix
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import Trainer

AXIS = torch.tensor([0.2, -0.3, 0.93], dtype=torch.float64)
AXIS = AXIS / AXIS.norm()
FORWARD = torch.linalg.cross(AXIS, torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
FORWARD = FORWARD / FORWARD.norm()
SIDE = torch.linalg.cross(AXIS, FORWARD)
POINT = torch.tensor([3.0, -2.0, 60.0], dtype=torch.float64)


def _hinge(angles=(-0.2, 0.3)) -> Hinge:
    return Hinge(POINT, AXIS, FORWARD, torch.tensor(angles, dtype=torch.float64))


def _tool_points() -> tuple[torch.Tensor, torch.Tensor]:
    """([N, 3] canonical points, [N] true parts): a shaft behind the hinge and the two jaws
    ahead of it along their canonical angles (-0.2 and 0.3 rad) of `_hinge`."""
    generator = torch.Generator().manual_seed(0)
    shaft = -torch.rand(30, 1, generator=generator, dtype=torch.float64) * 20
    points, parts = [POINT + shaft * FORWARD], [torch.full((30,), SHAFT)]
    for part, angle in ((JAW_A, -0.2), (JAW_B, 0.3)):
        along = 1 + torch.rand(20, 1, generator=generator, dtype=torch.float64) * 8
        direction = math.cos(angle) * FORWARD + math.sin(angle) * SIDE
        points.append(POINT + along * direction)
        parts.append(torch.full((20,), part))
    return torch.cat(points), torch.cat(parts)


def test_parts_are_the_shaft_behind_the_hinge_and_the_jaw_nearer_in_angle():
    points, parts = _tool_points()
    assert torch.equal(jaw_parts(points, _hinge()), parts)


def test_jaws_turn_about_the_hinge_by_their_angle_and_the_shaft_stays():
    points, parts = _tool_points()
    quats = torch.nn.functional.normalize(torch.randn(points.shape[0], 4, dtype=torch.float64),
                                          dim=1)
    turns = torch.tensor([0.4, -0.7], dtype=torch.float64)
    turned, turned_quats = turn_jaws(points, quats, parts, turns, _hinge())
    torch.testing.assert_close(turned[parts == SHAFT], points[parts == SHAFT])
    torch.testing.assert_close(turned_quats[parts == SHAFT], quats[parts == SHAFT])
    for part, turn in ((JAW_A, 0.4), (JAW_B, -0.7)):
        rotation = torch.from_numpy(Rotation.from_rotvec(turn * AXIS.numpy()).as_matrix())
        rows = parts == part
        torch.testing.assert_close(turned[rows], (points[rows] - POINT) @ rotation.T + POINT,
                                   atol=1e-12, rtol=0)
        torch.testing.assert_close(quaternion_to_matrix(turned_quats[rows]),
                                   rotation @ quaternion_to_matrix(quats[rows]),
                                   atol=1e-12, rtol=0)


@pytest.mark.parametrize("turns", [(0.0, 0.0), (0.4, -0.7)])
def test_turn_gradients_match_finite_differences(turns):
    """Double precision, torch.autograd.gradcheck's default tolerances (atol 1e-5, rtol 1e-3),
    also at the turn of 0 that every frame starts from at the reference frame."""
    points, parts = _tool_points()
    quats = torch.nn.functional.normalize(torch.randn(points.shape[0], 4, dtype=torch.float64),
                                          dim=1)
    hinge = _hinge()

    def turned(means, quaternions, angles):
        return turn_jaws(means, quaternions, parts, angles, hinge)

    inputs = (points[::5].clone().requires_grad_(), quats[::5].clone().requires_grad_(),
              torch.tensor(turns, dtype=torch.float64, requires_grad=True))
    parts = parts[::5]
    assert torch.autograd.gradcheck(turned, inputs)


def _articulated_field(frames: int = 3):
    """An articulated tool field with `_hinge` (single precision) whose frame 1 turns jaw a by
    +0.25 rad and jaw b by -0.1 rad from their canonical angles."""
    field = ToolFieldConfig(num_frames=frames, motion="articulated").build()
    hinge = _hinge()
    with torch.no_grad():
        field.known[:] = True
        field.seen[:] = True
        field.articulated.fill_(True)
        field.hinge_point.copy_(hinge.point)
        field.hinge_axis.copy_(hinge.axis)
        field.hinge_forward.copy_(hinge.forward)
        field.canonical_jaws.copy_(hinge.canonical_angles)
        field.jaw_angles[:] = field.canonical_jaws
        field.jaw_angles[1] += torch.tensor([0.25, -0.1])
    return field


def test_the_articulated_field_turns_each_jaw_at_its_frame_and_learns_the_angles():
    points, parts = _tool_points()
    logits = torch.full((points.shape[0],), -4.0)
    gaussians = GaussianModel.from_points(points.float(), torch.rand(points.shape[0], 3),
                                          GaussianConfig(init_opacity=0.8),
                                          {SEMANTIC_KEY: logits})
    field = _articulated_field()
    model = SplatModel(gaussians, {"tool": field})
    canonical = gaussians.params["means"].detach()
    torch.testing.assert_close(model.state_at(FrameTime(0, 0.0)).means, canonical)
    moved = model.state_at(FrameTime(1, 1 / 3)).means
    torch.testing.assert_close(moved[parts == SHAFT], canonical[parts == SHAFT])
    for part, turn in ((JAW_A, 0.25), (JAW_B, -0.1)):
        rotation = Rotation.from_rotvec(turn * AXIS.numpy()).as_matrix()
        expected = (canonical[parts == part].double() - POINT) @ torch.from_numpy(rotation).T
        torch.testing.assert_close(moved[parts == part].double(), expected + POINT,
                                   atol=1e-4, rtol=0)
    moved[parts == JAW_A].sum().backward()
    assert field.jaw_angles.grad[1, 0] != 0 and field.jaw_angles.grad[1, 1] == 0
    assert field.jaw_angles.grad[0].abs().sum() == 0


@pytest.mark.slow
def test_articulated_set_up_recovers_the_phantom_hinge_and_jaw_angles(small_phantom, tmp_path):
    """Before any training step, the field's own articulation against the phantom's kinematics:
    measured 1.3 deg jaw angle RMSE and 0.14 mm hinge offset; bounds 3 deg and 0.5 mm."""
    scene = load_scene(small_phantom)
    config = apply_values(method_config("physiosplat"),
                          {"train": {"iterations": 1},
                           "components": {"tool": {"motion": "articulated"}}})
    Trainer(config, scene, tmp_path / "run").fit()
    run = load_trained_run(tmp_path / "run")
    assert bool(run.model.components["tool"].articulated)
    estimate = articulate(run)
    assert estimate["method"] == OWN_JOINTS
    truth = json.loads((small_phantom / TOOL_KINEMATICS_FILE).read_text())
    frames = [index for index, record in enumerate(truth["frames"])
              if scene.frames[index].tool.any()]
    metrics = articulation_metrics(estimate, truth, frames, [])
    assert metrics["jaw_angle_rmse_deg"] < 3.0
    assert metrics["hinge_offset_mm"] < 0.5


def test_without_depth_the_articulated_field_stays_rigid(small_phantom, tmp_path):
    """No depth: the tool pixels lie on a plane, no shaft can be fitted, the field is rigid."""
    import shutil
    shutil.copytree(small_phantom, tmp_path / "scene")
    shutil.rmtree(tmp_path / "scene" / "depth")
    scene = load_scene(tmp_path / "scene")
    config = apply_values(method_config("physiosplat"),
                          {"train": {"iterations": 1},
                           "components": {"tool": {"motion": "articulated"}}})
    trainer = Trainer(config, scene, tmp_path / "run")
    field = trainer.model.components["tool"]
    assert field.seen.any() and not bool(field.articulated)
    assert field.articulation(trainer.model.gaussians) is None
