"""The endoscope's path: its pose at each time of the sequence.

The world frame is the camera frame of the first frame (OpenCV axes: x right, y down, z
forward, millimetres), in which the tissue height field and the tool's trocar are defined. A
static endoscope stays there; a moving one translates a few millimetres and turns a few degrees
along smooth keyframe curves (continuous position and velocity, see `motion.Keyframes`), so
the first frame's pose is the identity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from surgsplat.data.phantom.motion import Keyframes

CAMERAS = ("static", "moving")
"""Valid camera path names."""


@dataclass(frozen=True)
class CameraPath:
    """The camera centre and orientation in the world over time t in [0, 1)."""

    name: str
    """One of CAMERAS."""
    centre_mm: tuple[Keyframes, Keyframes, Keyframes]
    """World x, y, z of the camera centre, mm."""
    turn_deg: tuple[Keyframes, Keyframes, Keyframes]
    """Rotation angles about the first frame's x (tilt), y (pan) and z (roll) axes, degrees;
    the camera-to-world rotation is Rz(roll) Ry(pan) Rx(tilt)."""

    def camera_to_world(self, t: float) -> np.ndarray:
        """[4, 4] float64 camera-to-world at time t."""
        tilt, pan, roll = (np.radians(curve(t)) for curve in self.turn_deg)
        pose = np.eye(4)
        pose[:3, :3] = _rotation_z(roll) @ _rotation_y(pan) @ _rotation_x(tilt)
        pose[:3, 3] = [curve(t) for curve in self.centre_mm]
        return pose

    def world_to_camera(self, t: float) -> np.ndarray:
        """[4, 4] float64 world-to-camera at time t: [R^T | -R^T c]."""
        camera_to_world = self.camera_to_world(t)
        rotation_t = camera_to_world[:3, :3].T
        pose = np.eye(4)
        pose[:3, :3] = rotation_t
        pose[:3, 3] = -rotation_t @ camera_to_world[:3, 3]
        return pose + 0.0  # no negative zeros


def _rotation_x(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _rotation_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def camera_path(name: str) -> CameraPath:
    """The path of camera `name` (one of CAMERAS)."""
    still = Keyframes((0.0,), (0.0,))
    if name == "static":
        return CameraPath(name, (still, still, still), (still, still, still))
    if name == "moving":
        # Slide right and up while pulling back a little, then drift back part of the way;
        # tilt, pan and roll by up to 2.5, 3 and 4 degrees on their own schedules.
        keys = (0.0, 0.45, 1.0)
        return CameraPath(
            name,
            (Keyframes(keys, (0.0, 4.0, 2.5)), Keyframes(keys, (0.0, -2.5, -1.0)),
             Keyframes(keys, (0.0, -3.0, -1.5))),
            (Keyframes((0.0, 0.6, 1.0), (0.0, 2.5, 1.0)), Keyframes(keys, (0.0, -3.0, 1.5)),
             Keyframes((0.0, 0.3, 1.0), (0.0, 4.0, 4.0))),
        )
    raise ValueError(f"unknown camera {name!r}; valid cameras: {', '.join(CAMERAS)}")
