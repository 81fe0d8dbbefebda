"""The articulation estimator on a synthetic grasper with known hinge and jaw angles."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from surgsplat.model.articulation import (JAW_A, JAW_B, SHAFT, Observation,
                                          estimate_articulation)

AXIS = np.array([0.2, -0.3, 0.93]) / np.linalg.norm([0.2, -0.3, 0.93])
FORWARD = np.cross(AXIS, [1.0, 0.0, 0.0])
FORWARD /= np.linalg.norm(FORWARD)
HINGE = np.array([3.0, -2.0, 60.0])


def box_surface(rng, half: np.ndarray, count: int) -> np.ndarray:
    """[count, 3] points on the surface of the axis-aligned box of half extents `half`."""
    points = rng.uniform(-1, 1, (count, 3)) * half
    face = rng.integers(0, 3, count)
    points[np.arange(count), face] = np.sign(rng.uniform(-1, 1, count)) * half[face]
    return points


def grasper(rng, jaw_deg: tuple[float, float], count: int) -> tuple[np.ndarray, np.ndarray]:
    """(points [N, 3], labels [N]) of a 4 mm shaft and two 12 x 1.6 x 3.6 mm jaws at the given
    angles about AXIS through HINGE."""
    opening = np.cross(FORWARD, AXIS)
    frame = np.stack([FORWARD, opening, AXIS], axis=1)  # columns: local x, y, z
    theta = rng.uniform(0, np.pi, count)  # the half of the shaft facing a camera
    along = rng.uniform(-25, 0, count)
    shaft = np.stack([along, 4 * np.cos(theta), 4 * np.sin(theta)], axis=1)
    parts, labels = [shaft @ frame.T + HINGE], [np.full(count, SHAFT)]
    for label, side, angle in ((JAW_A, 1.0, jaw_deg[0]), (JAW_B, -1.0, jaw_deg[1])):
        local = box_surface(rng, np.array([6.0, 0.8, 1.8]), count // 3)
        local += [6.0, -side * 0.8, 0.0]
        rotation = Rotation.from_rotvec(np.radians(angle) * np.array([0, 0, 1.0])).as_matrix()
        parts.append((local @ rotation.T) @ frame.T + HINGE)
        labels.append(np.full(count // 3, label))
    return np.concatenate(parts), np.concatenate(labels)


def test_hinge_and_angles_of_a_synthetic_grasper_are_recovered():
    rng = np.random.default_rng(0)
    canonical, truth = grasper(rng, (-3.0, 3.0), 1500)
    openings = np.concatenate([np.linspace(35, 0, 6), np.zeros(4), np.linspace(0, 30, 6)])
    observations = []
    for index, opening in enumerate(openings):
        points, _ = grasper(rng, (-opening / 2, opening / 2), 1200)
        wobble = Rotation.from_rotvec(rng.normal(0, np.radians(0.7), 3))
        points = wobble.apply(points - HINGE) + HINGE + rng.normal(0, 0.2, 3)
        points += rng.normal(0, 0.05, points.shape)
        observations.append(Observation(index, points, np.ones(len(canonical), dtype=bool)))
    result = estimate_articulation(canonical, observations)
    axis_error = np.degrees(np.arccos(min(abs(result.axis @ AXIS), 1.0)))
    assert axis_error < 3.0
    offset = result.hinge_point - HINGE
    assert np.linalg.norm(offset - (offset @ AXIS) * AXIS) < 1.0  # mm off the true axis
    sign = np.sign(result.axis @ AXIS)
    angles = sign * result.jaw_angles_deg
    truth_angles = np.stack([-openings / 2, openings / 2], axis=1)
    if np.abs(angles - truth_angles).mean() > np.abs(angles[:, ::-1] - truth_angles).mean():
        angles = angles[:, ::-1]
    assert np.sqrt(((angles - truth_angles) ** 2).mean()) < 3.0  # the target
    labels = result.labels[:len(truth)]  # the canonical points come first
    agreement = max((labels == truth).mean(),
                    (labels == np.choose(truth, [SHAFT, JAW_B, JAW_A])).mean())
    assert agreement > 0.85  # jaw points near the hinge hardly move: some join the shaft


def test_a_tool_whose_jaws_never_move_is_refused():
    rng = np.random.default_rng(1)
    canonical, _ = grasper(rng, (-5.0, 5.0), 600)
    observations = [Observation(i, grasper(rng, (-5.0, 5.0), 600)[0],
                                np.ones(len(canonical), dtype=bool)) for i in range(4)]
    with pytest.raises(ValueError):
        estimate_articulation(canonical, observations)
