"""SGBM disparity on a synthetic rectified pair with a known disparity; depth from disparity."""

import cv2
import numpy as np
import pytest

from surgsplat.data.stereo import StereoConfig, disparity_to_depth, fill_invalid, stereo_disparity
from surgsplat.errors import SurgsplatError

SHIFT = 12  # px, the true disparity


def textured_pair(height: int = 96, width: int = 128) -> tuple[np.ndarray, np.ndarray]:
    """left(x) = right(x - SHIFT): a blurred random texture seen by two rectified cameras."""
    rng = np.random.default_rng(0)
    wide = rng.integers(0, 255, (height, width + SHIFT, 3), dtype=np.uint8)
    wide = cv2.GaussianBlur(wide, (3, 3), 0)
    return np.ascontiguousarray(wide[:, :width]), np.ascontiguousarray(wide[:, SHIFT:])


@pytest.mark.parametrize("config", [StereoConfig(), StereoConfig(num_disparities=32, mode="hh")])
def test_known_disparity_recovered(config: StereoConfig):
    left, right = textured_pair()
    disparity = stereo_disparity(left, right, config)
    assert disparity.dtype == np.float32 and disparity.shape == left.shape[:2]
    # Columns left of SHIFT have no match in the right image.
    valid = disparity[:, SHIFT + 4:] > 0
    assert valid.mean() > 0.9
    assert np.abs(disparity[:, SHIFT + 4:][valid] - SHIFT).max() < 1.0  # px


def test_disparity_to_depth_and_invalid_pixels():
    disparity = np.array([[10.0, 0.0], [20.0, -1.0]], np.float32)
    depth = disparity_to_depth(disparity, focal=500.0, baseline=4.0)
    assert np.allclose(depth, [[200.0, 0.0], [100.0, 0.0]])  # mm, exact
    filled = fill_invalid(np.array([[0.0, 5.0, 0.0, 0.0, 9.0]], np.float32))
    assert filled.tolist() == [[5.0, 5.0, 5.0, 9.0, 9.0]]


def test_bad_stereo_config_is_a_user_error():
    left, right = textured_pair()
    with pytest.raises(SurgsplatError, match="multiple of 16"):
        stereo_disparity(left, right, StereoConfig(num_disparities=40))
