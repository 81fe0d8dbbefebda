"""Camera poses of a moving endoscope from its frames: COLMAP structure from motion (pycolmap).

Pipeline (`SfmWorkspace`): frames are added one by one to a temporary COLMAP workspace (PNG
images, and masks where 0 = ignore: the tool, dilated by `tool_dilation_px`, and the outside
of the field of view); then SIFT features on the tissue pixels only (on the frame downscaled to
`max_image_size`), sequential matching of each frame with the next `overlap` frames and a few
further ones at powers of two (no loop detection), with geometric verification, incremental mapping with bundle adjustment, one shared
PINHOLE camera with the given intrinsics (principal point fixed, focal lengths refined only if
asked, as one focal length of a SIMPLE_PINHOLE camera when the pixels are square). Small triangulation angles are accepted (`min_triangulation_angle_deg`): an endoscope
moves millimetres in front of tissue centimetres away.

The result (`SfmPoses`): OpenCV world-to-camera poses [N, 4, 4] whose world frame is the first
registered frame's camera, scaled either from the scene's metric depth (the median over frames
of each frame's median ratio of measured depth to the sparse points' depths) or, without
depth, by the convention that the sparse points' median depth is `median_depth` scene units.
Frames that fail to register get interpolated poses (rotation slerp and centre lerp between
the registered neighbours, the nearest one's pose before the first and after the last) and are
listed as interpolated. The sparse points (world frame, scene units, RGB) can initialise the
Gaussians of a scene without depth.

SfM assumes a rigid scene; on deforming tissue the masks keep the tool out, and the short
baseline of sequential matching keeps each match within a short stretch of the tissue's motion.
"""

from __future__ import annotations

import importlib
import math
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from surgsplat.data.layout import MAX_DEPTH_MM, Intrinsics, frame_stem, write_image
from surgsplat.errors import SurgsplatError

INSTALL_HINT = "pip install 'surgsplat[sfm]' (or pip install 'pycolmap>=4.2')"
"""How to install the optional SfM dependency."""
UPSAMPLE_BELOW_PX = 400
"""SIFT starts from the frame upsampled 2x (COLMAP's default, 4x slower) only when the frame's
longer side, as SIFT sees it, is below this: small frames have too few features otherwise."""
INIT_ANGLE_DEG = 1.0
"""Smallest triangulation angle of the initial image pair, degrees (COLMAP: 16; relaxed by
the mapper when no pair has it)."""
INIT_TRIALS = 50
"""Initial image pairs the mapper tries before it relaxes its thresholds (COLMAP: 200)."""
LOG_LEVEL = 3
"""COLMAP's log level while it runs: fatal only (glog: 0 = info, 1 = warning, 2 = error,
3 = fatal). Its errors ("Failed to create any sparse model") are what surgsplat reports in its
own one line, with the way out."""
SCALE_SOURCES = ("depth", "convention")
"""How the SfM scale was set: from metric depth, or by the median-depth convention."""


def require_pycolmap() -> ModuleType:
    """The pycolmap module; SurgsplatError saying how to install it when it is missing."""
    try:
        return importlib.import_module("pycolmap")
    except ImportError:
        raise SurgsplatError(f"--poses sfm needs pycolmap, which is not installed: "
                             f"{INSTALL_HINT}") from None


@dataclass
class SfmConfig:
    """How camera poses are estimated from the frames."""

    max_image_size: int = field(default=640, metadata={"range": "[64, inf)"})
    """Frames are downscaled to at most this many pixels along their longer side for SIFT."""
    max_features: int = field(default=1024, metadata={"range": "[64, inf)"})
    """Most SIFT features per frame."""
    overlap: int = field(default=4, metadata={"range": "[1, 16]"})
    """Sequential matching: each frame i is matched with frames i + 1 .. i + overlap and
    i + 2^k for k < overlap (COLMAP's quadratic overlap: longer baselines, less drift)."""
    tool_dilation_px: int = field(default=8, metadata={"range": "[0, inf)"})
    """Tool masks grow by this many pixels (of the frames) before features are excluded."""
    refine_focal: bool = False
    """Refine the focal lengths in bundle adjustment (the principal point stays fixed)."""
    min_triangulation_angle_deg: float = field(default=0.1, metadata={"range": "(0, 90)"})
    """Smallest angle between rays of a sparse point, degrees (COLMAP: 1.5): endoscopes move
    millimetres in front of tissue centimetres away."""
    median_depth: float = field(default=50.0, metadata={"range": f"(0, {MAX_DEPTH_MM:g}]"})
    """Scale convention without metric depth: the sparse points' median depth, scene units."""
    num_threads: int = field(default=2, metadata={"range": "[1, inf)"})
    """Threads of feature extraction, matching and mapping."""
    seed: int = field(default=0, metadata={"range": "[0, 2147483647]"})
    """Seed of COLMAP's random sampling."""

    def validate(self) -> None:
        """Raise SurgsplatError for a value outside its range."""
        checks = (("max_image_size", self.max_image_size >= 64),
                  ("max_features", self.max_features >= 64),
                  ("overlap", 1 <= self.overlap <= 16),
                  ("tool_dilation_px", self.tool_dilation_px >= 0),
                  ("min_triangulation_angle_deg", 0 < self.min_triangulation_angle_deg < 90),
                  ("median_depth", 0 < self.median_depth <= MAX_DEPTH_MM),
                  ("num_threads", self.num_threads >= 1),
                  ("seed", 0 <= self.seed <= 2147483647))
        for name, ok in checks:
            if not ok:
                spec = next(f for f in self.__dataclass_fields__.values() if f.name == name)
                raise SurgsplatError(f"sfm.{name} must lie in {spec.metadata['range']}, got "
                                     f"{getattr(self, name)!r}")


@dataclass
class SfmPoses:
    """Estimated cameras of every frame, and the sparse points."""

    world_to_camera: np.ndarray
    """[N, 4, 4] float64 OpenCV world-to-camera; world = the first registered frame's camera,
    scene units."""
    registered: np.ndarray
    """[N] bool: the frame was registered by SfM (else its pose is interpolated)."""
    intrinsics: Intrinsics
    """The camera after bundle adjustment (the given one unless focal refinement)."""
    points: np.ndarray
    """[M, 3] float64 sparse points in the world frame, scene units."""
    colors: np.ndarray
    """[M, 3] uint8 RGB of the sparse points."""
    scale_source: str
    """One of SCALE_SOURCES."""
    scale: float
    """Scene units per SfM unit."""
    reprojection_error_px: float
    """Mean reprojection error of the sparse points, pixels of the frames."""
    seconds: float
    """Wall time of feature extraction, matching, mapping and scaling."""
    stage_seconds: dict[str, float]
    """Wall time of each stage: features, matching, mapping."""

    @property
    def interpolated(self) -> list[int]:
        """Indices of the frames whose pose is interpolated."""
        return np.flatnonzero(~self.registered).tolist()

    def describe(self, config: SfmConfig) -> dict:
        """scene.json `extra.poses`."""
        return {
            "source": "sfm", "library": "COLMAP (pycolmap)",
            "registered": int(self.registered.sum()), "frames": len(self.registered),
            "interpolated": self.interpolated,
            "interpolation": "rotation slerp and centre lerp between registered neighbours; "
                             "the nearest registered pose at the ends",
            "world": "camera of the first registered frame",
            "scale_source": self.scale_source, "scale": self.scale,
            "scale_meaning": (
                "scene units per SfM unit: median over frames of median(measured depth / "
                "sparse point depth)" if self.scale_source == "depth" else
                f"convention: the sparse points' median depth is {config.median_depth:g} scene "
                "units (no metric depth; the scene's true size is unknown)"),
            "sparse_points": len(self.points),
            "reprojection_error_px": self.reprojection_error_px,
            "intrinsics": asdict(self.intrinsics), "seconds": self.seconds,
            "stage_seconds": self.stage_seconds,
            "config": asdict(config),
        }


Progress = Callable[[str, int, int], None]
"""Called as progress(stage, done, total)."""


class SfmWorkspace:
    """A temporary COLMAP workspace for one run: `add` every frame, then `solve`, which removes
    the workspace's folder (as does collecting a workspace that was never solved)."""

    def __init__(self, intrinsics: Intrinsics, config: SfmConfig):
        self.pycolmap = require_pycolmap()
        self.intrinsics = intrinsics
        self.config = config
        self._folder = tempfile.TemporaryDirectory(prefix="surgsplat-sfm-")
        self.root = Path(self._folder.name)
        for sub in ("images", "masks", "depth"):
            (self.root / sub).mkdir()
        self.count = 0
        self.has_depth: bool | None = None
        self.size: tuple[int, int] | None = None  # (H, W)

    def add(self, image: np.ndarray, excluded: np.ndarray, depth: np.ndarray | None = None
            ) -> None:
        """Add the next frame: image uint8 [H, W, 3] RGB; excluded bool [H, W] (tool or outside
        the field of view; the tool part is dilated here); depth float [H, W] in scene units
        (0 = unknown) or None; every frame must have depth or none."""
        if self.size is None:
            self.size = image.shape[:2]
        if image.shape[:2] != self.size or excluded.shape != self.size:
            raise ValueError(f"frame {self.count}: image {image.shape} and mask "
                             f"{excluded.shape} differ from the first frame's {self.size}")
        if self.has_depth is None:
            self.has_depth = depth is not None
        if self.has_depth != (depth is not None):
            raise ValueError(f"frame {self.count}: every frame needs depth, or none")
        radius = self.config.tool_dilation_px
        if radius:
            kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1,) * 2)
            excluded = cv2.dilate(excluded.astype(np.uint8), kernel).astype(bool)
        name = f"{frame_stem(self.count)}.png"
        write_image(self.root / "images" / name, image[..., ::-1])
        write_image(self.root / "masks" / f"{name}.png",
                    np.where(excluded, 0, 255).astype(np.uint8))
        if depth is not None:
            np.save(self.root / "depth" / f"{frame_stem(self.count)}.npy",
                    np.asarray(depth, dtype=np.float32))
        self.count += 1

    def solve(self, progress: Progress | None = None) -> SfmPoses:
        """Run COLMAP on the added frames; SurgsplatError if no model with two frames forms."""
        if self.count < 2 or self.size is None:
            raise SurgsplatError(f"--poses sfm needs at least 2 frames, got {self.count}")
        report = progress or (lambda stage, done, total: None)
        started = time.perf_counter()
        quiet = self.pycolmap.logging.minloglevel
        self.pycolmap.logging.minloglevel = LOG_LEVEL
        try:
            reconstruction, stage_seconds = self._reconstruct(report)
            scale_source, scale = self._scale(reconstruction)
        finally:
            self.pycolmap.logging.minloglevel = quiet
            self._folder.cleanup()
        registered = np.zeros(self.count, dtype=bool)
        world_to_camera = np.tile(np.eye(4), (self.count, 1, 1))
        for image in reconstruction.images.values():
            if image.has_pose:
                index = int(Path(image.name).stem)
                registered[index] = True
                world_to_camera[index, :3] = image.cam_from_world().matrix()
        first = int(np.flatnonzero(registered)[0])
        world_to_camera[registered] = world_to_camera[registered] @ np.linalg.inv(
            world_to_camera[first])  # world = the first registered frame's camera
        points, colors = _points(reconstruction)
        points = points @ world_to_camera[first, :3, :3].T + world_to_camera[first, :3, 3]
        world_to_camera[:, :3, 3] *= scale
        camera = next(iter(reconstruction.cameras.values()))  # the one shared camera
        return SfmPoses(
            world_to_camera=interpolate_poses(world_to_camera, registered), registered=registered,
            intrinsics=Intrinsics(camera.focal_length_x, camera.focal_length_y,
                                  camera.principal_point_x, camera.principal_point_y),
            points=points * scale, colors=colors,
            scale_source=scale_source, scale=scale,
            reprojection_error_px=float(reconstruction.compute_mean_reprojection_error()),
            seconds=time.perf_counter() - started, stage_seconds=stage_seconds)

    def _reconstruct(self, report: Progress):  # -> (pycolmap.Reconstruction, dict)
        """The incremental map with the most registered frames, and the seconds of each stage
        (features, matching, mapping)."""
        pycolmap, config = self.pycolmap, self.config
        pycolmap.set_random_seed(config.seed)
        database = self.root / "database.db"
        k = self.intrinsics
        # One focal length to refine when the pixels are square: better conditioned.
        square = config.refine_focal and math.isclose(k.fx, k.fy)
        reader = pycolmap.ImageReaderOptions(
            camera_model="SIMPLE_PINHOLE" if square else "PINHOLE",
            camera_params=f"{k.fx},{k.cx},{k.cy}" if square else f"{k.fx},{k.fy},{k.cx},{k.cy}",
            mask_path=str(self.root / "masks"))
        extraction = pycolmap.FeatureExtractionOptions(
            max_image_size=config.max_image_size, num_threads=config.num_threads)
        extraction.sift.max_num_features = config.max_features
        seen = min(config.max_image_size, max(self.size))  # longer side as SIFT sees it
        extraction.sift.first_octave = -1 if seen < UPSAMPLE_BELOW_PX else 0
        clock = _StageClock(report, ("features", "matching", "mapping"))
        pycolmap.extract_features(database, self.root / "images",
                                  camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                                  extraction_options=extraction, device=pycolmap.Device.cpu)
        clock.done("features")
        matching = pycolmap.FeatureMatchingOptions(num_threads=config.num_threads)
        pairing = pycolmap.SequentialPairingOptions(overlap=config.overlap,
                                                    quadratic_overlap=True,
                                                    loop_detection=False,
                                                    num_threads=config.num_threads)
        verification = pycolmap.TwoViewGeometryOptions()
        verification.ransac.random_seed = config.seed
        verification.detect_watermark = False  # the field of view's border is masked already
        pycolmap.match_sequential(database, matching_options=matching, pairing_options=pairing,
                                  verification_options=verification,
                                  device=pycolmap.Device.cpu)
        clock.done("matching")
        outputs = self.root / "sparse"
        outputs.mkdir()
        maps = pycolmap.incremental_mapping(database, self.root / "images", outputs,
                                            options=self._mapping_options())
        clock.done("mapping")
        best = max(maps.values(), key=lambda r: r.num_reg_images(), default=None)
        if best is None or best.num_reg_images() < 2:
            raise SurgsplatError(
                f"--poses sfm: COLMAP registered fewer than 2 of the {self.count} frames (too "
                "little texture, or tools covering the tissue); import without --poses sfm, "
                "or with more frames")
        return best, clock.seconds

    def _mapping_options(self):  # -> pycolmap.IncrementalPipelineOptions
        """Incremental mapping for short baselines: small triangulation angles allowed, one
        model, the principal point fixed."""
        config, pycolmap = self.config, self.pycolmap
        angle = config.min_triangulation_angle_deg
        options = pycolmap.IncrementalPipelineOptions(
            num_threads=config.num_threads, random_seed=config.seed, multiple_models=False,
            ba_refine_focal_length=config.refine_focal, ba_refine_principal_point=False,
            ba_refine_extra_params=False)
        options.mapper.init_min_tri_angle = INIT_ANGLE_DEG
        options.init_num_trials = INIT_TRIALS
        # Global bundle adjustment after every 40 % growth of the map (not 10 %), fewer
        # refinement rounds, both threads from small problems on; the final one always runs.
        options.ba_global_frames_ratio = options.ba_global_points_ratio = 1.4
        options.ba_local_max_refinements = 1
        options.ba_global_max_refinements = 2
        options.ba_min_num_residuals_for_cpu_multi_threading = 5000
        options.mapper.filter_min_tri_angle = angle
        options.mapper.ba_local_min_tri_angle = angle
        options.mapper.abs_pose_refine_focal_length = config.refine_focal
        options.mapper.abs_pose_refine_extra_params = False
        options.mapper.random_seed = config.seed
        options.triangulation.min_angle = angle
        options.triangulation.random_seed = config.seed
        return options

    def _scale(self, reconstruction) -> tuple[str, float]:
        """(scale source, scene units per SfM unit) from the observations' depths."""
        ratios, depths = [], []
        for image in reconstruction.images.values():
            if not image.has_pose:
                continue
            index = int(Path(image.name).stem)
            observed = [p for p in image.points2D if p.has_point3D()]
            if not observed:
                continue
            xyz = np.array([reconstruction.points3D[p.point3D_id].xyz for p in observed])
            pose = image.cam_from_world().matrix()
            z = xyz @ pose[2, :3] + pose[2, 3]  # [K] SfM units
            depths.append(z)
            if self.has_depth:
                measured = np.load(self.root / "depth" / f"{frame_stem(index)}.npy")
                uv = np.array([p.xy for p in observed])  # pixel centres at +0.5
                cols = np.clip(uv[:, 0].astype(int), 0, measured.shape[1] - 1)
                rows = np.clip(uv[:, 1].astype(int), 0, measured.shape[0] - 1)
                d = measured[rows, cols]
                good = (d > 0) & (z > 0)
                if good.any():
                    ratios.append(float(np.median(d[good] / z[good])))
        if self.has_depth and ratios:
            return "depth", float(np.median(ratios))
        return "convention", self.config.median_depth / float(np.median(np.concatenate(depths)))


class _StageClock:
    """Reports the SfM stages as progress("SfM", done, total) and times each one."""

    def __init__(self, report: Progress, stages: tuple[str, ...]):
        self.report, self.stages = report, stages
        self.seconds: dict[str, float] = {}
        self.last = time.perf_counter()
        report("SfM", 0, len(stages))

    def done(self, stage: str) -> None:
        now = time.perf_counter()
        self.seconds[stage] = now - self.last
        self.last = now
        self.report("SfM", len(self.seconds), len(self.stages))


def _points(reconstruction) -> tuple[np.ndarray, np.ndarray]:
    """([M, 3] float64 xyz in SfM's world, [M, 3] uint8 RGB) of the sparse points."""
    points = list(reconstruction.points3D.values())
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    return (np.array([p.xyz for p in points], dtype=np.float64),
            np.array([p.color for p in points], dtype=np.uint8))


def interpolate_poses(world_to_camera: np.ndarray, known: np.ndarray) -> np.ndarray:
    """world_to_camera [N, 4, 4] with the rows not `known` ([N] bool, at least one True)
    replaced: camera rotation slerped and centre lerped between the known neighbours, the
    nearest known pose before the first and after the last."""
    indices = np.flatnonzero(known)
    if len(indices) == 0:
        raise ValueError("no known pose to interpolate from")
    camera_to_world = np.linalg.inv(world_to_camera[indices])  # [K, 4, 4]
    times = np.arange(len(known), dtype=np.float64)
    clamped = np.clip(times, indices[0], indices[-1])
    if len(indices) == 1:
        rotations = Rotation.from_matrix(np.repeat(camera_to_world[:, :3, :3], len(known), 0))
    else:
        rotations = Slerp(indices, Rotation.from_matrix(camera_to_world[:, :3, :3]))(clamped)
    centres = np.stack([np.interp(clamped, indices, camera_to_world[:, axis, 3])
                        for axis in range(3)], axis=1)  # [N, 3]
    result = np.array(world_to_camera, dtype=np.float64, copy=True)
    rotation_t = rotations.as_matrix().transpose(0, 2, 1)  # world-to-camera rotations
    missing = ~known
    result[missing, :3, :3] = rotation_t[missing]
    result[missing, :3, 3] = -np.einsum("nij,nj->ni", rotation_t[missing], centres[missing])
    result[missing, 3] = [0.0, 0.0, 0.0, 1.0]
    return result
