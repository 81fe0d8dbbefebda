"""The phantom tool's true kinematics per frame, as written to gt/tool_kinematics.json.

The tool is a rigid shaft with two jaws on one revolute joint (see `tool`). Per frame the file
holds, in the world frame (= frame 0's camera frame, OpenCV axes) and millimetres:

- `shaft_to_world`: [4, 4] pose of the shaft frame, whose origin is the hinge point, x axis the
  shaft's forward direction (from the shaft into the jaws), z axis the hinge axis and y = z x x;
- `hinge_point_mm`, `hinge_axis`: the revolute joint (a point on its axis and its unit axis);
- `jaw_opening_deg`: the angle between the two jaws (0 = closed);
- `jaw_angles_deg`: each jaw's rotation about `hinge_axis` (right-hand rule) that takes the
  shaft's forward direction to the jaw's long axis: [-opening / 2, +opening / 2], in the order of
  `tool.jaw_boxes`.
"""

from __future__ import annotations

from dataclasses import asdict

import numpy as np

from surgsplat.data.phantom.tool import ToolPose

TOOL_KINEMATICS_FILE = "gt/tool_kinematics.json"
"""Where a phantom keeps its tool kinematics, relative to the scene folder."""


def hinge_frame(forward: np.ndarray, axis: np.ndarray, point: np.ndarray) -> np.ndarray:
    """[4, 4] float64 shaft frame: x `forward`, z the hinge `axis`, y = z x x, origin at the
    hinge `point` (each [3], forward normal to axis)."""
    matrix = np.eye(4)
    matrix[:3, 0] = forward
    matrix[:3, 1] = np.cross(axis, forward)
    matrix[:3, 2] = axis
    matrix[:3, 3] = point
    return matrix


def shaft_to_world(pose: ToolPose) -> np.ndarray:
    """[4, 4] float64: the shaft frame of the tool `pose` in the world."""
    return hinge_frame(pose.forward, pose.hinge, pose.joint)


def jaw_angles_deg(pose: ToolPose) -> list[float]:
    """Each jaw's angle about the hinge axis from the shaft's forward direction, degrees."""
    return [-pose.jaw_deg / 2.0, pose.jaw_deg / 2.0]


def frame_kinematics(pose: ToolPose) -> dict:
    """One frame's entry of gt/tool_kinematics.json (world frame, mm)."""
    return {"shaft_to_world": shaft_to_world(pose).tolist(),
            "hinge_point_mm": np.asarray(pose.joint, dtype=float).tolist(),
            "hinge_axis": np.asarray(pose.hinge, dtype=float).tolist(),
            "jaw_opening_deg": float(pose.jaw_deg),
            "jaw_angles_deg": jaw_angles_deg(pose)}


def tool_kinematics(poses: list[ToolPose], geometry) -> dict:
    """The whole file: units, conventions, the tool's dimensions and one entry per frame."""
    return {
        "units": {"length": "mm", "angle": "deg"},
        "frame": "world = frame 0's camera frame (OpenCV: x right, y down, z forward)",
        "conventions": {
            "shaft_to_world": "shaft frame: origin at the hinge point, x = forward (shaft into "
                              "jaws), z = hinge axis, y = z cross x",
            "jaw_angles_deg": "rotation of each jaw's long axis from the shaft's forward "
                              "direction about hinge_axis (right-hand rule); the jaws are at "
                              "-opening/2 and +opening/2",
        },
        "tool_geometry_mm": asdict(geometry),
        "frames": [frame_kinematics(pose) for pose in poses],
    }
