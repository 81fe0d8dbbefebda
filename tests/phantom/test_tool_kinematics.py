"""gt/tool_kinematics.json against the generator's own tool geometry."""

import json
from pathlib import Path

import numpy as np

from surgsplat.data.phantom.kinematics import TOOL_KINEMATICS_FILE
from surgsplat.data.phantom.motion import motion_program
from surgsplat.data.phantom.scene import PhantomScene
from surgsplat.data.phantom.tool import jaw_boxes


def rotation_about(axis: np.ndarray, degrees: float) -> np.ndarray:
    """[3, 3] rotation by `degrees` about the unit `axis` (Rodrigues)."""
    angle = np.radians(degrees)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def test_kinematics_rebuild_the_jaws_of_every_frame(small_phantom: Path):
    truth = json.loads((small_phantom / TOOL_KINEMATICS_FILE).read_text())
    assert truth["units"] == {"length": "mm", "angle": "deg"}
    scene = PhantomScene(160, 128, 569.4682 / 4, 16, "pulling", 0)
    program = motion_program("pulling")
    assert len(truth["frames"]) == 16
    for index, entry in enumerate(truth["frames"]):
        shaft = np.array(entry["shaft_to_world"])
        axis, point = np.array(entry["hinge_axis"]), np.array(entry["hinge_point_mm"])
        np.testing.assert_allclose(shaft[:3, :3].T @ shaft[:3, :3], np.eye(3), atol=1e-9)
        np.testing.assert_allclose(shaft[:3, 2], axis)
        np.testing.assert_allclose(shaft[:3, 3], point)
        assert entry["jaw_opening_deg"] == program.jaw_deg(index / 16)
        pose = scene.tool_pose(index / 16)
        for (centre, axes, half), angle, side in zip(jaw_boxes(scene.geometry, pose),
                                                     entry["jaw_angles_deg"], (1.0, -1.0)):
            along = rotation_about(axis, angle) @ shaft[:3, 0]  # jaw's long axis
            np.testing.assert_allclose(along, axes[0], atol=1e-9)
            np.testing.assert_allclose(axes[2], axis, atol=1e-9)  # the hinge is the box's z
            # the jaw's inner back edge lies on the hinge axis
            edge = centre - half[0] * axes[0] - side * half[1] * axes[1]
            offset = edge - point
            np.testing.assert_allclose(offset - (offset @ axis) * axis, 0.0, atol=1e-9)
        opening = np.degrees(np.arccos(np.clip(
            jaw_boxes(scene.geometry, pose)[0][1][0] @ jaw_boxes(scene.geometry, pose)[1][1][0],
            -1, 1)))
        assert abs(opening - entry["jaw_opening_deg"]) < 1e-4
