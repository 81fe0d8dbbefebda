"""Articulation metrics: orientation-free axis error, jaw order and axis sign aligned."""

import numpy as np
import pytest

from surgsplat.eval.articulation_metrics import articulation_metrics


def kinematics(axes, points, angles, key="hinge_point_mm") -> dict:
    return {"frames": [{"hinge_axis": list(a), key: list(p), "jaw_angles_deg": list(j),
                        "jaw_opening_deg": abs(j[1] - j[0]), "estimated": True}
                       for a, p, j in zip(axes, points, angles)]}


def test_a_flipped_axis_and_swapped_jaws_score_zero():
    axes = np.tile([0.0, 0.6, 0.8], (4, 1))
    points = np.tile([1.0, 2.0, 80.0], (4, 1))
    angles = np.array([[-17.5, 17.5], [-10.0, 10.0], [0.0, 0.0], [-5.0, 5.0]])
    truth = kinematics(axes, points, angles)
    estimate = kinematics(-axes, points + 3.0 * axes, -angles[:, ::-1], key="hinge_point")
    metrics = articulation_metrics(estimate, truth, [0, 1, 2, 3], [1])
    assert metrics["hinge_axis_error_deg"] == pytest.approx(0.0, abs=1e-6)
    assert metrics["hinge_offset_mm"] == pytest.approx(0.0, abs=1e-9)  # moved along the axis
    assert metrics["jaw_angle_rmse_deg"] == pytest.approx(0.0, abs=1e-9)
    assert metrics["jaw_opening_rmse_deg"] == pytest.approx(0.0, abs=1e-9)
    assert metrics["articulation_frames"] == 4 and "jaw_angle_rmse_deg_test" in metrics
    assert metrics["hinge_axis_error_deg_estimated"] == pytest.approx(0.0, abs=1e-6)


def test_known_errors_are_reported():
    axes = np.tile([0.0, 0.0, 1.0], (2, 1))
    tilted = np.tile([np.sin(np.radians(4)), 0.0, np.cos(np.radians(4))], (2, 1))
    points = np.zeros((2, 3))
    truth = kinematics(axes, points, [[-10.0, 10.0], [-20.0, 20.0]])
    estimate = kinematics(tilted, points + [2.0, 0.0, 0.0], [[-13.0, 13.0], [-17.0, 17.0]],
                          key="hinge_point")
    metrics = articulation_metrics(estimate, truth, [0, 1], [])
    assert metrics["hinge_axis_error_deg"] == pytest.approx(4.0)
    assert metrics["hinge_offset_mm"] == pytest.approx(2.0 * np.cos(np.radians(4)), rel=1e-6)
    assert metrics["jaw_angle_rmse_deg"] == pytest.approx(3.0)
    assert metrics["jaw_opening_rmse_deg"] == pytest.approx(6.0)
