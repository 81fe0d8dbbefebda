"""OpenCV camera calibration files: YAML or XML as written by cv2.FileStorage.

The convention read (for each item, the first key found wins):

- rectified camera: `P1`, the 3x4 left projection matrix of cv2.stereoRectify (as in OpenCV's
  stereo_calib sample). When present the frames must already be rectified with it (the
  convention of `surgsplat import --right`); its left 3x3 is the camera, and distortion is
  ignored (rectification removed it).
- otherwise the camera matrix: `camera_matrix` (OpenCV's calibration sample), `K`, `M1`
  (stereo_calib's left camera) or `cameraMatrix`, 3x3, with optional distortion coefficients
  `distortion_coefficients`, `D`, `D1`, `dist_coeffs` or `distCoeffs` (OpenCV's order). When
  they are not all zero the frames are undistorted on import (`undistortion_maps`) to the
  pinhole camera of the same matrix, the camera written.
- `image_width` and `image_height` (optional): the calibrated image size, checked against the
  frames.

Pixel coordinates in these files follow OpenCV (pixel centres at integers); `read_calibration`
returns surgsplat's convention (centres at + 0.5, so cx = cx_opencv + 0.5).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from surgsplat.data.layout import Intrinsics
from surgsplat.errors import DataError

RECTIFIED_KEYS = ("P1",)
"""Keys of a rectified left projection matrix [3, 4]."""
MATRIX_KEYS = ("camera_matrix", "K", "M1", "cameraMatrix")
"""Keys of a camera matrix [3, 3]."""
DISTORTION_KEYS = ("distortion_coefficients", "D", "D1", "dist_coeffs", "distCoeffs")
"""Keys of distortion coefficients (any length)."""
OPENCV_TO_SURGSPLAT_PX = 0.5
"""Added to an OpenCV principal point to give surgsplat's (pixel centres at + 0.5)."""


@dataclass(frozen=True)
class Calibration:
    """The camera of a calibration file, in surgsplat's pixel convention."""

    intrinsics: Intrinsics
    """fx, fy, cx, cy at the calibrated image size."""
    size: tuple[int, int] | None
    """Calibrated (width, height) in pixels; None when the file does not say."""
    key: str
    """The key the camera was read from (e.g. "P1" or "camera_matrix")."""
    distortion: np.ndarray | None
    """OpenCV distortion coefficients [K] of the frames; None when they have none (all zero,
    absent, or frames rectified with P1)."""

    def undistortion_maps(self, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
        """cv2.remap maps (x, y), each float32 [H, W], from the distorted frames to the pinhole
        camera `intrinsics` (OpenCV's cv2.undistort with the same camera matrix)."""
        matrix = self.intrinsics.matrix()
        matrix[:2, 2] -= OPENCV_TO_SURGSPLAT_PX  # back to OpenCV's pixel convention
        return cv2.initUndistortRectifyMap(matrix, self.distortion, None, matrix,
                                           (width, height), cv2.CV_32FC1)


def read_calibration(path: str | Path) -> Calibration:
    """The camera of an OpenCV calibration file (see the module doc for the keys read)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "does not exist: expected an OpenCV calibration file (YAML/XML)")
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as err:  # OpenCV's parser raises SystemError from Python
        raise DataError(path, f"cannot be parsed as an OpenCV YAML/XML file ({err})") from None
    if not storage.isOpened():
        raise DataError(path, "cannot be opened as an OpenCV YAML/XML file")
    try:
        distortion = None
        key, matrix = _first_matrix(storage, RECTIFIED_KEYS, (3, 4), path)
        if matrix is None:
            key, matrix = _first_matrix(storage, MATRIX_KEYS, (3, 3), path)
            if matrix is None:
                raise DataError(path, f"holds no camera matrix: expected one of the keys "
                                      f"{', '.join(RECTIFIED_KEYS + MATRIX_KEYS)}")
            distortion = _distortion(storage, path)
        size = _image_size(storage, path)
    finally:
        storage.release()
    if matrix[0, 1] != 0 or np.any(matrix[2, :3] != (0.0, 0.0, 1.0)) or matrix[1, 0] != 0:
        raise DataError(path, f"{key} is not a pinhole camera matrix [[fx, 0, cx], [0, fy, cy], "
                              f"[0, 0, 1]]: got {matrix[:3, :3].tolist()}")
    intrinsics = Intrinsics(fx=float(matrix[0, 0]), fy=float(matrix[1, 1]),
                            cx=float(matrix[0, 2]) + OPENCV_TO_SURGSPLAT_PX,
                            cy=float(matrix[1, 2]) + OPENCV_TO_SURGSPLAT_PX)
    try:
        intrinsics.check(*(size or (None, None)))
    except ValueError as err:
        raise DataError(path, f"{key}: {err}") from None
    return Calibration(intrinsics=intrinsics, size=size, key=key, distortion=distortion)


def _first_matrix(storage: cv2.FileStorage, keys: tuple[str, ...], shape: tuple[int, int],
                  path: Path) -> tuple[str, np.ndarray | None]:
    """(key, float64 matrix) of the first of `keys` present, or ("", None)."""
    for key in keys:
        node = storage.getNode(key)
        if node.empty():
            continue
        matrix = node.mat()
        if matrix is None or matrix.shape != shape:
            got = "not a matrix" if matrix is None else f"shape {matrix.shape}"
            raise DataError(path, f"{key} must be a {shape[0]}x{shape[1]} matrix, got {got}")
        matrix = matrix.astype(np.float64)
        if not np.isfinite(matrix).all():
            raise DataError(path, f"{key} holds NaN or infinite values")
        return key, matrix
    return "", None


def _distortion(storage: cv2.FileStorage, path: Path) -> np.ndarray | None:
    """The first distortion coefficients found as float64 [K], or None if absent or all zero."""
    for key in DISTORTION_KEYS:
        node = storage.getNode(key)
        if node.empty():
            continue
        coefficients = node.mat()
        if coefficients is None or coefficients.size not in (4, 5, 8, 12, 14):
            raise DataError(path, f"{key} must hold 4, 5, 8, 12 or 14 distortion coefficients "
                                  "(OpenCV's model)")
        coefficients = coefficients.astype(np.float64).ravel()
        if not np.isfinite(coefficients).all():
            raise DataError(path, f"{key} holds NaN or infinite values")
        return coefficients if np.any(coefficients != 0) else None
    return None


def _image_size(storage: cv2.FileStorage, path: Path) -> tuple[int, int] | None:
    width, height = storage.getNode("image_width"), storage.getNode("image_height")
    if width.empty() and height.empty():
        return None
    if width.empty() or height.empty() or width.real() <= 0 or height.real() <= 0:
        raise DataError(path, "expected both image_width and image_height as positive numbers")
    return int(width.real()), int(height.real())
