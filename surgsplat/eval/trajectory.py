"""Camera trajectory errors after a similarity alignment: ATE, rotation error and RPE.

An estimated trajectory (e.g. from structure from motion) has its own world frame and, without
metric depth, its own scale, so it is first aligned to the true one by a similarity (Sim(3):
scale s, rotation R, translation t; `similarity_alignment`). Its rotation comes from the camera
orientations, not from the centres as in Umeyama (1991)'s point alignment: an endoscope's path
is short and nearly straight, which leaves the rotation about it undetermined by the centres
(a 30 degree twist changes the fit by noise), while the orientations fix it. Scale and
translation then fit the centres by least squares. Per frame i, with true camera-to-world
rotations Q_i and centres c_i, and estimated ones P_i, e_i aligned to Q'_i = R P_i,
c'_i = s R e_i + t:

- ATE: sqrt(mean_i |c'_i - c_i|^2), the absolute trajectory error in the true unit;
- rotation error: the angle of Q_i^T Q'_i, degrees, mean and max over frames;
- RPE (relative pose error, consecutive frames): the translation of the relative motion
  (c_i -> c_{i+1} in camera i's frame) compared between aligned estimate and truth, RMSE in the
  true unit, and the angle between the relative rotations, mean in degrees.

The phantom's tissue breathes: it translates rigidly in the world (`TissueSurface.breathing`,
up to 1.6 mm), which no image can tell from the camera moving the other way, so an image-only
estimate follows the camera relative to the tissue; `phantom_tissue_poses` gives those true
poses beside the world ones (gt/camera_poses.npy).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from surgsplat.data.layout import META_FILE
from surgsplat.data.phantom.generate import CAMERA_POSES_FILE
from surgsplat.data.phantom.motion import motion_program
from surgsplat.data.phantom.surface import TissueSurface


@dataclass(frozen=True)
class Similarity:
    """x -> scale * rotation @ x + translation."""

    scale: float
    rotation: np.ndarray  # [3, 3]
    translation: np.ndarray  # [3]

    def apply(self, points: np.ndarray) -> np.ndarray:
        """[N, 3] -> [N, 3]."""
        return self.scale * points @ self.rotation.T + self.translation


@dataclass(frozen=True)
class TrajectoryErrors:
    """Errors of an estimated trajectory after Sim(3) alignment (see the module doc)."""

    ate: float
    """RMSE of the aligned camera centres, true unit."""
    rotation_mean_deg: float
    """Mean rotation error, degrees."""
    rotation_max_deg: float
    """Largest rotation error, degrees."""
    rpe_translation: float
    """RMSE of the consecutive-frame relative translation, true unit."""
    rpe_rotation_deg: float
    """Mean consecutive-frame relative rotation error, degrees."""
    scale: float
    """Scale of the alignment (true unit per estimated unit)."""


def similarity_alignment(estimated_c2w: np.ndarray, true_c2w: np.ndarray) -> Similarity:
    """The similarity mapping estimated camera-to-world poses [N, 4, 4] onto true ones: the
    rotation from the orientations (the chordal mean of Q_i P_i^T, Umeyama's SVD projection
    onto SO(3)), then scale and translation minimising sum |s R e_i + t - c_i|^2 over the
    centres e_i, c_i (Umeyama's closed form with the rotation fixed)."""
    orientation_sum = (true_c2w[:, :3, :3] @ estimated_c2w[:, :3, :3].transpose(0, 2, 1)).sum(0)
    u, _, vt = np.linalg.svd(orientation_sum)
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    rotation = u @ sign @ vt
    source, target = estimated_c2w[:, :3, 3], true_c2w[:, :3, 3]
    centred_s = (source - source.mean(0)) @ rotation.T
    centred_t = target - target.mean(0)
    variance = (centred_s ** 2).sum()
    if variance == 0:
        raise ValueError("the estimated camera centres coincide: no scale to align")
    scale = float((centred_s * centred_t).sum() / variance)
    return Similarity(scale, rotation, target.mean(0) - scale * rotation @ source.mean(0))


def rotation_angle_deg(rotations: np.ndarray) -> np.ndarray:
    """Angles in degrees of rotations [N, 3, 3] (through quaternions: exact near 0, unlike the
    arccos of the trace)."""
    return np.degrees(Rotation.from_matrix(rotations).magnitude())


def trajectory_errors(estimated: np.ndarray, true: np.ndarray) -> TrajectoryErrors:
    """Errors of `estimated` against `true`, both [N, 4, 4] world-to-camera (any convention
    shared by both, e.g. OpenCV), N >= 3."""
    if estimated.shape != true.shape or estimated.shape[1:] != (4, 4) or len(estimated) < 3:
        raise ValueError(f"expected two [N, 4, 4] pose arrays with N >= 3, got "
                         f"{estimated.shape} and {true.shape}")
    est_c2w, true_c2w = np.linalg.inv(estimated), np.linalg.inv(true)
    align = similarity_alignment(est_c2w, true_c2w)
    aligned = np.tile(np.eye(4), (len(true), 1, 1))
    aligned[:, :3, :3] = align.rotation @ est_c2w[:, :3, :3]
    aligned[:, :3, 3] = align.apply(est_c2w[:, :3, 3])
    centre_error = np.linalg.norm(aligned[:, :3, 3] - true_c2w[:, :3, 3], axis=1)
    angles = rotation_angle_deg(true_c2w[:, :3, :3].transpose(0, 2, 1) @ aligned[:, :3, :3])
    rel_true = np.linalg.inv(true_c2w[:-1]) @ true_c2w[1:]  # [N-1, 4, 4] camera i -> i+1
    rel_est = np.linalg.inv(aligned[:-1]) @ aligned[1:]
    step_error = np.linalg.norm(rel_est[:, :3, 3] - rel_true[:, :3, 3], axis=1)
    step_angles = rotation_angle_deg(rel_true[:, :3, :3].transpose(0, 2, 1) @ rel_est[:, :3, :3])
    return TrajectoryErrors(
        ate=float(np.sqrt((centre_error ** 2).mean())),
        rotation_mean_deg=float(angles.mean()), rotation_max_deg=float(angles.max()),
        rpe_translation=float(np.sqrt((step_error ** 2).mean())),
        rpe_rotation_deg=float(step_angles.mean()), scale=align.scale)


def phantom_tissue_poses(phantom: Path) -> tuple[np.ndarray, np.ndarray]:
    """(world, tissue) true poses [N, 4, 4] OpenCV world-to-camera of a phantom folder: the
    world ones of gt/camera_poses.npy, and the same cameras in the frame of the breathing tissue
    (the world shifted by the tissue's rigid breathing translation since frame 0)."""
    phantom = Path(phantom)
    extra = json.loads((phantom / META_FILE).read_text())["extra"]
    world = np.load(phantom / CAMERA_POSES_FILE)
    surface = TissueSurface(extra["seed"], motion_program(extra["motion"]))
    shifts = []
    for index in range(len(world)):
        (shift_x, shift_y), shift_z = surface.breathing(index / len(world))
        shifts.append([shift_x, shift_y, shift_z])
    shifts = np.array(shifts) - shifts[0]  # [N, 3] mm, tissue translation since frame 0
    tissue = world.copy()
    tissue[:, :3, 3] += np.einsum("nij,nj->ni", world[:, :3, :3], shifts)
    return world, tissue
