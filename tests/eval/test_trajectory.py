"""Trajectory errors after a similarity alignment, on trajectories with known errors."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from surgsplat.eval.trajectory import trajectory_errors


def camera_to_world(rotations: Rotation, centres: np.ndarray) -> np.ndarray:
    """[N, 4, 4] camera-to-world poses."""
    poses = np.tile(np.eye(4), (len(centres), 1, 1))
    poses[:, :3, :3] = rotations.as_matrix()
    poses[:, :3, 3] = centres
    return poses


def true_path(count: int = 20) -> np.ndarray:
    """[N, 4, 4] world-to-camera of a short, nearly straight endoscope path (mm)."""
    t = np.linspace(0.0, 1.0, count)
    centres = np.stack([4 * t, -2.5 * t + 0.3 * t ** 2, -3 * t], axis=1)
    rotations = Rotation.from_euler("xyz", np.stack([2 * t, -3 * t, 4 * t ** 2], 1), degrees=True)
    return np.linalg.inv(camera_to_world(rotations, centres))


def test_a_similar_copy_has_no_error_and_its_scale_is_found():
    true = true_path()
    change = np.eye(4)  # world_new = s R world + t, applied to the camera-to-world poses
    change[:3, :3] = Rotation.from_euler("zyx", [40, -25, 70], degrees=True).as_matrix()
    change[:3, 3] = [10.0, -3.0, 7.0]
    estimated_c2w = change @ np.linalg.inv(true)
    estimated_c2w[:, :3, 3] /= 0.02  # in units of 1/50 mm: the alignment's scale is 0.02
    errors = trajectory_errors(np.linalg.inv(estimated_c2w), true)
    assert errors.scale == pytest.approx(0.02)
    for value in (errors.ate, errors.rotation_max_deg, errors.rpe_translation,
                  errors.rpe_rotation_deg):
        assert value == pytest.approx(0.0, abs=1e-6)


def test_known_errors_are_measured():
    true = true_path()
    estimated_c2w = np.linalg.inv(true)
    estimated_c2w[5, :3, 3] += [0.0, 0.0, 0.3]  # one centre 0.3 mm off the path
    turn = Rotation.from_euler("y", 2.0, degrees=True).as_matrix()
    estimated_c2w[9, :3, :3] = estimated_c2w[9, :3, :3] @ turn  # one camera turned by 2 degrees
    errors = trajectory_errors(np.linalg.inv(estimated_c2w), true)
    # The alignment absorbs a little of the offset: ATE a bit under 0.3 / sqrt(20).
    assert 0.9 * 0.3 / np.sqrt(20) < errors.ate <= 0.3 / np.sqrt(20) + 1e-9
    # The alignment's rotation (the mean of the orientations) takes 1/20 of the turn.
    assert errors.rotation_max_deg == pytest.approx(2.0 * 19 / 20, abs=1e-3)
    assert errors.rotation_mean_deg == pytest.approx(2 * 2.0 * 19 / 20 / 20, abs=1e-3)
    assert errors.rpe_rotation_deg == pytest.approx(2 * 2.0 / 19, abs=1e-3)  # steps 8-9, 9-10


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="N >= 3"):
        trajectory_errors(true_path(2), true_path(2))
