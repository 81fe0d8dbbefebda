"""The shaft motion of a frame without its own estimate: interpolated between its neighbours."""

import numpy as np
from scipy.spatial.transform import Rotation

from surgsplat.model.articulation import Articulation


def motion(degrees: float, shift: float) -> np.ndarray:
    """[4, 4] a turn about z and a shift along x."""
    matrix = np.eye(4)
    matrix[:3, :3] = Rotation.from_euler("z", degrees, degrees=True).as_matrix()
    matrix[0, 3] = shift
    return matrix


def estimate_at(frames: list[int], motions: list[np.ndarray]) -> Articulation:
    count = len(frames)
    return Articulation(points=np.zeros((1, 3)), labels=np.zeros(1, dtype=int),
                        axis=np.array([0.0, 0.0, 1.0]), hinge_point=np.zeros(3),
                        forward=np.array([1.0, 0.0, 0.0]), frames=np.array(frames),
                        shaft_motion=np.stack(motions), jaw_angles_deg=np.zeros((count, 2)),
                        jaw_observed=np.ones((count, 2), dtype=bool),
                        canonical_jaw_deg=np.zeros(2))


def test_frames_between_estimates_are_interpolated_and_outside_take_the_nearest():
    estimate = estimate_at([2, 6], [motion(0.0, 0.0), motion(40.0, 4.0)])
    np.testing.assert_allclose(estimate.shaft_motion_at(2), motion(0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(estimate.shaft_motion_at(6), motion(40.0, 4.0), atol=1e-12)
    np.testing.assert_allclose(estimate.shaft_motion_at(3), motion(10.0, 1.0), atol=1e-9)
    np.testing.assert_allclose(estimate.shaft_motion_at(0), motion(0.0, 0.0), atol=1e-12)
    np.testing.assert_allclose(estimate.shaft_motion_at(9), motion(40.0, 4.0), atol=1e-12)
