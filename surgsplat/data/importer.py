"""Import endoscopic video (or a folder of frames) as an EndoNeRF-layout scene folder.

What is written (see `surgsplat.data.layout`): images/ (RGB PNG), masks/ (255 = tool) when
masks are given, fov_mask.png (255 = inside the circular field of view) when a dark border is
found, depth/ (16-bit PNG, depth in the baseline's unit) when a right camera is given,
poses_bounds.npy (one static camera, or with --poses sfm each frame's camera from structure
from motion, `surgsplat.data.sfm_poses`, and then sparse_points.ply), and scene.json: the
camera's full intrinsics (fx, fy, cx, cy of the written frames) and, under `extra`, the source,
the frame selection, how the camera was obtained, the field of view, the stereo settings and
how the poses were obtained.

Without labels, tool masks come from the classical segmenter (`surgsplat.data.auto_tool_masks`)
or from an ONNX tool segmenter, and relative depth from the shading prior
(`surgsplat.data.shading_depth`) or from an ONNX depth network (`surgsplat.data.learned_priors`,
whose contracts it states); ONNX models are opened and checked before anything is written.

The camera comes from --calibration (an OpenCV file, see `surgsplat.data.calibration`; frames
and masks are undistorted first when it gives distortion coefficients), from
--fx/--fy and --cx/--cy, from --focal (square pixels), or from an assumed field of view; a
principal point not given is the image centre. Given principal points follow OpenCV (pixel
centres at integers) and are stored in surgsplat's convention (+ 0.5).

Frames come in this order: frame range and stride on the source's frames, then frames without
a mask are dropped (only if allowed), then every frame is resized (to between MIN_SIZE x
MIN_SIZE and MAX_FRAME_PIXELS). Stereo runs on the resized, rectified pair; fx and cx scale with
the image width, fy and cy with its height.

What import writes is checked as the scene loader will check it, and named by its source: a
tool mask (given or derived) must leave tissue in view, depth beyond the 16-bit range or
`max_depth` is stored as unknown, and a derived product (tool masks from a segmenter, depth
from stereo, shading or a network, disparity) without content on every frame (no tool pixel,
no valid depth or disparity pixel) stops the import, naming the model file, the right camera or
the frames it came from, before the scene is called done.
"""

from __future__ import annotations

import itertools
import math
import shutil
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from surgsplat.data.auto_tool_masks import (CONFIDENCE_MEANING, AutoMask, AutoMaskConfig,
                                            auto_tool_masks)
from surgsplat.data.calibration import read_calibration
from surgsplat.data.fov_mask import FovConfig, FovEstimate, brightness, estimate_fov
from surgsplat.data.frames_source import FrameSource, list_frame_files
from surgsplat.data.layout import (MAX_FRAME_PIXELS, Intrinsics, SceneMeta, SceneWriter,
                                   frame_stem, max_depth, write_image)
from surgsplat.data.learned_priors import (DepthNetworkConfig, ToolSegmenterConfig,
                                           model_tool_masks, network_depth)
from surgsplat.data.onnx_models import OnnxModel
from surgsplat.data.prompted_masks import (PROMPTED_CONFIDENCE_MEANING, PromptConfig,
                                           ToolPrompt, click_disk, prompted_tool_masks,
                                           read_prompts, seed_mask)
from surgsplat.data.scene import (CLASS_ID_HINT, MIN_SIZE, check_tissue_visible,
                                  read_tool_mask)
from surgsplat.data.sfm_poses import SfmConfig, SfmWorkspace, require_pycolmap
from surgsplat.data.shading_depth import ShadingDepthConfig, shading_depth
from surgsplat.data.sparse_points import write_sparse_points
from surgsplat.data.stereo import StereoConfig, disparity_to_depth, stereo_disparity
from surgsplat.data.tool_masks import match_masks, resolve_mask_match
from surgsplat.errors import DataError, SurgsplatError

DISPARITY_DIR = "disparity"
"""Folder of the disparity maps written with --disparity-only: 16-bit PNG holding px x
DISPARITY_STEPS, 0 = invalid."""
DISPARITY_STEPS = 256
"""Stored integer steps per pixel of disparity (the KITTI convention)."""
MIN_DEPTH_DISPARITY = 1.0
"""Disparities below this (px) are too far to give a usable depth and are stored as 0 (unknown);
the deepest stored depth is therefore fx x baseline."""
DEPTH_SOURCES = ("none", "shading")
"""Monocular depth priors of --depth by name: none, or near-light shading
(surgsplat.data.shading_depth); a path ending in MODEL_SUFFIX names a depth network instead."""
MODEL_SUFFIX = ".onnx"
"""File suffix that makes a --depth value the path of an ONNX depth network."""
SHADING_DEPTH_UNIT = "relative (shading)"
"""scene.json depth_unit of shading depth: one unknown scale; train with the scale-invariant
depth loss."""
NETWORK_DEPTH_UNIT = "relative (depth network)"
"""scene.json depth_unit of an ONNX depth network's depth: one unknown scale per frame; train
with the scale-invariant depth loss."""
FOV_SAMPLE_FRAMES = 100
"""The field of view is estimated on at most this many of the selected frames, evenly spread."""
POSE_SOURCES = ("static", "sfm")
"""Camera poses of --poses: one static camera, or structure from motion on the tissue pixels
(surgsplat.data.sfm_poses)."""

Progress = Callable[[str, int, int], None]
"""Called as progress(stage, done, total) while importing."""


@dataclass
class ImportConfig:
    """Options of `surgsplat import`."""

    pattern: str | None = None
    """Glob picking the frame files of a source (and right) folder; None = all image files."""
    masks: Path | None = None
    """Folder of tool label images, one per frame; None = no tool masks."""
    mask_pattern: str | None = None
    """Glob picking the mask files in `masks`; None = all images."""
    tool_labels: tuple[int, ...] | None = None
    """Class IDs that are tools in class-ID masks; None = binary masks (nonzero = tool)."""
    mask_match: str = "auto"
    """Pairing of masks with frames: one of tool_masks.MASK_MATCHES (auto: number for folders,
    order for videos)."""
    allow_missing_masks: bool = False
    """Drop frames that have no mask instead of stopping with an error."""
    auto_tool_masks: bool = False
    """Find the tools in every frame with the classical segmenter (instead of `masks`)."""
    auto_masks: AutoMaskConfig = field(default_factory=AutoMaskConfig)
    """Parameters of the automatic tool segmenter."""
    tool_prompts: Path | None = None
    """JSON file of clicks on tools (and tissue) from which every frame's tool mask follows
    (`surgsplat.data.prompted_masks`); None = none."""
    prompts: PromptConfig = field(default_factory=PromptConfig)
    """How the clicks become masks and are carried through the clip."""
    tool_segmenter: Path | None = None
    """ONNX tool segmenter whose per-pixel tool probability gives the tool masks; None = none."""
    segmenter: ToolSegmenterConfig = field(default_factory=ToolSegmenterConfig)
    """How the ONNX tool segmenter is fed and read."""
    fov_mask: bool = True
    """Find the circular field of view and write it to fov_mask.png (apart from the tool masks)."""
    fov: FovConfig = field(default_factory=FovConfig)
    """How the field of view is found."""
    depth: str = "none"
    """Monocular depth prior: one of DEPTH_SOURCES, or the path of an ONNX depth network
    (ending in MODEL_SUFFIX)."""
    shading: ShadingDepthConfig = field(default_factory=ShadingDepthConfig)
    """Parameters of the shading depth prior (depth "shading")."""
    depth_network: DepthNetworkConfig = field(default_factory=DepthNetworkConfig)
    """How the ONNX depth network is fed and read (depth MODEL.onnx)."""
    right: Path | None = None
    """Right-camera video or folder of the rectified stereo pair; None = monocular."""
    baseline: float | None = None
    """Stereo baseline in the scene's depth unit (e.g. mm); needed for depth from stereo."""
    disparity_only: bool = False
    """Write disparity (px) to disparity/ instead of depth to depth/."""
    depth_unit: str = "mm"
    """Unit of `baseline`, and so of the depth maps."""
    stereo: StereoConfig = field(default_factory=StereoConfig)
    """Stereo matcher parameters."""
    focal: float | None = None
    """Focal length in pixels of the source frames (fx = fy); None = fx, fy, the calibration
    file or `assumed_hfov_deg`."""
    fx: float | None = None
    """Focal length along columns, pixels of the source frames; given together with fy."""
    fy: float | None = None
    """Focal length along rows, pixels of the source frames; given together with fx."""
    cx: float | None = None
    """Principal point column in the source frames, OpenCV convention (pixel centres at
    integers); given together with cy; None = the image centre."""
    cy: float | None = None
    """Principal point row in the source frames, OpenCV convention; given together with cx."""
    calibration: Path | None = None
    """OpenCV calibration file (YAML/XML) of the source frames' camera, instead of the above."""
    assumed_hfov_deg: float = 70.0
    """Horizontal field of view (degrees) assumed when `focal` is not given."""
    start: int = 0
    """First source frame to import (0-based)."""
    end: int | None = None
    """Source frame at which to stop (exclusive); None = the last frame."""
    stride: int = 1
    """Import every stride-th frame from `start`."""
    resize: tuple[int, int] | None = None
    """Output size (width, height); must keep the aspect ratio within 1 %."""
    scale: float | None = None
    """Output size as a factor of the source size (instead of `resize`)."""
    poses: str = "static"
    """Camera poses: one of POSE_SOURCES."""
    sfm: SfmConfig = field(default_factory=SfmConfig)
    """How poses "sfm" are estimated."""

    def validate(self) -> None:
        """Raise SurgsplatError for an impossible combination of options."""
        if self.start < 0 or self.stride < 1:
            raise SurgsplatError(f"--start must be >= 0 and --stride >= 1, got {self.start} and "
                                 f"{self.stride}")
        if self.end is not None and self.end <= self.start:
            raise SurgsplatError(f"--end ({self.end}) must be greater than --start ({self.start})")
        if self.resize is not None and self.scale is not None:
            raise SurgsplatError("give either --resize or --scale, not both")
        if self.resize is not None and min(self.resize) <= 0:
            raise SurgsplatError(f"--resize needs a positive width and height, got {self.resize}")
        if self.scale is not None and not 0 < self.scale < math.inf:
            raise SurgsplatError(f"--scale must be a positive finite number, got {self.scale}")
        self._validate_camera()
        if not 0 < self.assumed_hfov_deg < 180:
            raise SurgsplatError(f"the assumed field of view must be in (0, 180) degrees, got "
                                 f"{self.assumed_hfov_deg}")
        if self.masks is None and (self.tool_labels is not None or self.mask_pattern is not None
                                   or self.allow_missing_masks):
            raise SurgsplatError("--tool-labels, --mask-pattern and --allow-missing-masks need "
                                 "--masks")
        if self.auto_tool_masks:
            self.auto_masks.validate()
        sources = [name for name, given in (
            ("--masks", self.masks is not None), ("--auto-tool-masks", self.auto_tool_masks),
            ("--tool-prompts", self.tool_prompts is not None),
            ("--tool-segmenter", self.tool_segmenter is not None)) if given]
        if len(sources) > 1:
            raise SurgsplatError(f"give one source of tool masks, not {' and '.join(sources)}")
        if self.tool_segmenter is not None:
            self.segmenter.validate()
        if self.tool_prompts is not None:
            self.prompts.validate()
        if self.tool_labels is not None and (
                not self.tool_labels or not all(0 <= v <= 65535 for v in self.tool_labels)):
            raise SurgsplatError(f"--tool-labels must list class IDs in 0..65535, got "
                                 f"{self.tool_labels}")
        self._validate_stereo()
        if self.poses not in POSE_SOURCES:
            raise SurgsplatError(f"unknown --poses {self.poses!r}; expected one of "
                                 f"{', '.join(POSE_SOURCES)}")
        if self.poses == "sfm":
            self.sfm.validate()
            if self.sfm.refine_focal and self.right is not None:
                raise SurgsplatError("--sfm-refine-focal cannot go with --right: stereo depth "
                                     "is computed with the given focal length")

    def _validate_camera(self) -> None:
        given = {name: getattr(self, name) for name in ("focal", "fx", "fy", "cx", "cy")}
        if self.calibration is not None and any(v is not None for v in given.values()):
            raise SurgsplatError("give either --calibration or --focal / --fx --fy / --cx --cy, "
                                 "not both")
        if self.focal is not None and (self.fx is not None or self.fy is not None):
            raise SurgsplatError("give either --focal or --fx and --fy, not both")
        for first, second in (("fx", "fy"), ("cx", "cy")):
            if (given[first] is None) != (given[second] is None):
                raise SurgsplatError(f"--{first} and --{second} go together: give both")
        for name in ("focal", "fx", "fy"):
            if given[name] is not None and not given[name] > 0:
                raise SurgsplatError(f"--{name} must be positive (pixels), got {given[name]}")

    @property
    def depth_model(self) -> Path | None:
        """The ONNX depth network named by `depth`, or None."""
        return Path(self.depth) if self.depth.lower().endswith(MODEL_SUFFIX) else None

    @property
    def knows_focal(self) -> bool:
        """Whether the focal length is given rather than assumed."""
        return self.focal is not None or self.fx is not None or self.calibration is not None

    def _validate_stereo(self) -> None:
        if self.depth not in DEPTH_SOURCES and self.depth_model is None:
            raise SurgsplatError(f"unknown --depth {self.depth!r}; expected one of "
                                 f"{', '.join(DEPTH_SOURCES)} or a model file "
                                 f"*{MODEL_SUFFIX}")
        if self.depth != "none":
            if self.right is not None:
                raise SurgsplatError(f"give either --right (stereo depth) or --depth "
                                     f"{self.depth}, not both")
            if self.depth_model is None:
                self.shading.validate()
            else:
                self.depth_network.validate()
        if self.right is None:
            if self.baseline is not None or self.disparity_only:
                raise SurgsplatError("--baseline and --disparity-only need --right")
            return
        self.stereo.validate()
        if self.disparity_only:
            top = self.stereo.min_disparity + self.stereo.num_disparities
            if top * DISPARITY_STEPS > 65535:
                raise SurgsplatError(f"disparities up to {top} px do not fit 16-bit PNG at "
                                     f"1/{DISPARITY_STEPS} px; search at most "
                                     f"{65535 // DISPARITY_STEPS} px")
            return
        if self.baseline is None or not 0 < self.baseline < math.inf or not self.knows_focal:
            raise SurgsplatError("depth from stereo needs --focal, --fx/--fy or --calibration "
                                 "(of the rectified left camera) and a positive finite "
                                 "--baseline; or pass --disparity-only")


def import_scene(source: str | Path, out_dir: str | Path, config: ImportConfig,
                 progress: Progress | None = None) -> Path:
    """Import `source` (video file or folder of frames) into the new scene folder `out_dir`.

    The sources are opened, counted and paired before anything is written; if writing fails
    (an unreadable mask, a frame of another size, Ctrl-C), the partial output is removed again.
    """
    config.validate()
    out_dir = Path(out_dir)
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise SurgsplatError(f"{out_dir} already exists and is not empty; choose a new --out "
                             "folder")
    report = progress or (lambda stage, done, total: None)
    plan = _plan(Path(source), config, report)
    existed = out_dir.is_dir()
    try:
        return _write_scene(plan, out_dir, config, report)
    except BaseException:
        # The folder was empty or absent: everything in it is this import's partial output.
        shutil.rmtree(out_dir, ignore_errors=True)
        if existed:
            out_dir.mkdir()
        raise


class _Fitter:
    """Checks that frames and masks have the source size, undistorts them (given cv2.remap
    maps) and resizes them to the output size."""

    def __init__(self, source_size: tuple[int, int], out_size: tuple[int, int],
                 undistort: tuple[np.ndarray, np.ndarray] | None = None):
        self.source_size = source_size  # (H, W)
        self.out_size = out_size  # (H, W)
        self.undistort = undistort  # (map x, map y), each float32 [H, W] at the source size

    def __call__(self, image: np.ndarray, path: Path, label: str) -> np.ndarray:
        self._check(image.shape, path, label)
        if self.undistort is not None:
            image = cv2.remap(image, *self.undistort, cv2.INTER_LINEAR)
        if self.out_size == self.source_size:
            return image
        shrink = self.out_size[1] < self.source_size[1]
        return cv2.resize(image, self.out_size[::-1],
                          interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)

    def mask(self, tool: np.ndarray, path: Path) -> np.ndarray:
        self._check(tool.shape, path, "mask")
        if self.undistort is not None:
            tool = cv2.remap(tool.astype(np.uint8), *self.undistort,
                             cv2.INTER_NEAREST).astype(bool)
        if self.out_size == self.source_size:
            return tool
        return cv2.resize(tool.astype(np.uint8), self.out_size[::-1],
                          interpolation=cv2.INTER_NEAREST).astype(bool)

    def _check(self, shape: tuple[int, ...], path: Path, label: str) -> None:
        if tuple(shape[:2]) != self.source_size:
            raise DataError(path, f"{label} is {shape[1]}x{shape[0]} (WxH) but the first frame "
                                  f"is {self.source_size[1]}x{self.source_size[0]}")


@dataclass
class _Plan:
    """What will be imported, decided (and checked) before anything is written."""

    frames: FrameSource
    right: FrameSource | None
    selected: list[int]  # source frame indices to write, ascending
    dropped: list[int]  # selected source frames dropped for lack of a mask
    mask_of: list[Path | None] | None  # mask file of each source frame; None = no masks
    fit: _Fitter
    intrinsics: Intrinsics  # at the output size
    camera_note: str  # how the intrinsics were obtained
    fov: FovEstimate | None  # None = not searched
    tool_model: OnnxModel | None  # the ONNX tool segmenter, opened and checked
    depth_model: OnnxModel | None  # the ONNX depth network, opened and checked
    prompts: list[ToolPrompt] | None  # clicks of --tool-prompts, checked; None = none


def _plan(source: Path, config: ImportConfig, report: Progress) -> _Plan:
    if config.poses == "sfm":
        require_pycolmap()
    frames = FrameSource(source, config.pattern)
    right = _open_right(config, frames)
    stop = frames.count if config.end is None else min(config.end, frames.count)
    selected = list(range(config.start, stop, config.stride))
    if not selected:
        raise SurgsplatError(f"--start {config.start} selects no frame: {source} has "
                             f"{frames.count} frames")
    mask_of = _pair_masks(frames, config)
    dropped = []
    if mask_of is not None:
        dropped = [i for i in selected if mask_of[i] is None]
        if dropped and not config.allow_missing_masks:
            others = f" and {len(dropped) - 1} other frames" if len(dropped) > 1 else ""
            raise DataError(config.masks, f"has no mask for {frames.frame_label(dropped[0])}"
                                          f"{others}; pass --allow-missing-masks to drop frames "
                                          "without a mask")
        selected = [i for i in selected if mask_of[i] is not None]
        if not selected:
            raise DataError(config.masks, "has a mask for none of the selected frames")
        first_mask = mask_of[selected[0]]
        hint = CLASS_ID_HINT if config.tool_labels is None else ""  # one class everywhere?
        check_tissue_visible(read_tool_mask(first_mask, config.tool_labels), None, first_mask,
                             hint)
    _, first = next(frames.read(selected[:1]))
    source_size = first.shape[:2]  # (H, W)
    out_size = _output_size(source_size, config)
    intrinsics, camera_note, undistort = _camera(source_size, out_size, config)
    fit = _Fitter(source_size, out_size, undistort)
    tool_model = (OnnxModel(config.tool_segmenter, config.segmenter.input, out_size)
                  if config.tool_segmenter is not None else None)
    depth_model = (OnnxModel(config.depth_model, config.depth_network.input, out_size)
                   if config.depth_model is not None else None)
    fov = _find_fov(frames, selected, fit, config.fov, report) if config.fov_mask else None
    prompts = None
    if config.tool_prompts is not None:
        prompts = read_prompts(config.tool_prompts, len(selected), source_size)
        _check_clicks_in_view(config.tool_prompts, prompts, fit, fov, config.prompts)
    return _Plan(frames, right, selected, dropped, mask_of, fit, intrinsics, camera_note, fov,
                 tool_model, depth_model, prompts)


def _check_clicks_in_view(path: Path, prompts: list[ToolPrompt], fit: _Fitter,
                          fov: FovEstimate | None, config: PromptConfig) -> None:
    """DataError naming the first click whose disk, as imported, misses the field of view."""
    if fov is None or fov.kind == "full":
        return
    for prompt in prompts:
        for kind in ("tool", "tissue"):
            for point in getattr(prompt, kind):
                disk = fit.mask(click_disk(point, fit.source_size, config.click_radius), path)
                if not (disk & fov.inside).any():
                    raise DataError(path, f"entry for frame {prompt.frame}: {kind} point "
                                          f"[{point[0]:g}, {point[1]:g}] lies outside the field "
                                          "of view")


def _write_scene(plan: _Plan, out_dir: Path, config: ImportConfig, report: Progress) -> Path:
    """Write the selected frames, tool masks, field of view and depth (or disparity), then the
    camera and scene.json."""
    frames, right, fit = plan.frames, plan.right, plan.fit
    fx = plan.intrinsics.fx
    meta = SceneMeta(depth_unit="unknown", intrinsics=plan.intrinsics,
                     source=str(frames.path.resolve()))
    depth_scale = 0.01
    if right is not None and not config.disparity_only:
        meta.depth_unit = config.depth_unit
        # 16-bit range spans depths up to fx x baseline (disparity MIN_DEPTH_DISPARITY px).
        depth_scale = fx * config.baseline / MIN_DEPTH_DISPARITY / 65535
    if config.depth != "none":
        shading = config.depth_model is None
        meta.depth_unit = SHADING_DEPTH_UNIT if shading else NETWORK_DEPTH_UNIT
        median = config.shading.median_depth if shading else config.depth_network.median_depth
        depth_scale = 4 * median / 65535  # up to 4x the median depth
    writer = SceneWriter(out_dir, fx, meta, depth_scale=depth_scale)
    outside = None  # [H, W] bool, True = outside the field of view; None = all inside
    if plan.fov is not None and plan.fov.kind != "full":
        writer.set_fov(plan.fov.inside)
        outside = ~plan.fov.inside
    sfm = SfmWorkspace(plan.intrinsics, config.sfm) if config.poses == "sfm" else None
    if config.disparity_only:
        (out_dir / DISPARITY_DIR).mkdir()
    fitted = _fitted_frames(plan)
    inside = plan.fov.inside if plan.fov is not None else None
    automatic = learned_depth = itertools.repeat(None)
    confidences: list[float] = []
    # The segmenters and the depth network look a few frames ahead (their temporal window or
    # batch); tee holds only those frames.
    if config.auto_tool_masks:
        fitted, ahead = itertools.tee(fitted)
        automatic = _recording_confidence(
            auto_tool_masks((image for _, image, _ in ahead), inside, config.auto_masks),
            confidences)
    if plan.prompts is not None:
        fitted, ahead = itertools.tee(fitted)
        automatic = _prompted_masks(plan, config, inside, ahead, confidences, report)
    if plan.tool_model is not None:
        fitted, ahead = itertools.tee(fitted)
        automatic = model_tool_masks(
            plan.tool_model, (image for _, image, _ in ahead), inside, config.segmenter,
            lambda done: report("tool segmenter", done, len(plan.selected)))
    if plan.depth_model is not None:
        fitted, ahead = itertools.tee(fitted)
        learned_depth = plan.depth_model.run(
            (image for _, image, _ in ahead),
            lambda done: report("depth network", done, len(plan.selected)))
    products = _DerivedProducts.of(plan, config)
    fov = None if outside is None else ~outside  # [H, W] bool as the scene will load it
    depth_limit = min(65535 * depth_scale, max_depth(meta.depth_unit))
    for done, ((index, image, right_image), tool, network_output) in enumerate(
            zip(fitted, automatic, learned_depth), 1):
        if plan.mask_of is not None:
            mask_path = plan.mask_of[index]
            tool = fit.mask(read_tool_mask(mask_path, config.tool_labels), mask_path)
            check_tissue_visible(tool, fov, mask_path)
        elif tool is not None:
            check_tissue_visible(tool, fov, products.masks.source)
            products.masks.count(tool.any())
        depth = None
        if right is not None:
            right_image = fit(right_image, right.frame_path(index), right.frame_label(index))
            disparity = stereo_disparity(image, right_image, config.stereo)  # [H, W] px
            if config.disparity_only:
                products.disparity.count((disparity > 0).any())
                stored = np.rint(disparity * DISPARITY_STEPS).astype(np.uint16)
                disparity_path = out_dir / DISPARITY_DIR / f"{frame_stem(writer.count)}.png"
                write_image(disparity_path, stored)
            else:
                disparity[disparity < MIN_DEPTH_DISPARITY] = 0.0
                depth = disparity_to_depth(disparity, fx, config.baseline)
        excluded = np.zeros(image.shape[:2], bool) if outside is None else outside
        if tool is not None:
            excluded = excluded | tool
        if sfm is not None:  # metric depth (stereo) sets the SfM scale, relative priors do not
            sfm.add(image, excluded, depth)
        if config.depth != "none":
            depth = (shading_depth(image, plan.intrinsics, excluded, config.shading)
                     if network_output is None else
                     network_depth(network_output, excluded, config.depth_network))
        if depth is not None:
            depth[depth > depth_limit] = 0.0  # beyond the 16-bit range or MAX_DEPTH_MM: unknown
            products.depth.count((depth > 0).any())
        writer.add_frame(image, depth, tool)
        report("import", done, len(plan.selected))
    products.check()
    meta.extra = _provenance(plan, config, confidences)
    if sfm is not None:
        poses = sfm.solve(report)
        writer.set_camera(poses.world_to_camera,
                          poses.intrinsics if config.sfm.refine_focal else None)
        write_sparse_points(out_dir, poses.points, poses.colors)
        meta.extra["poses"] = poses.describe(config.sfm)
    return writer.finish()


def _fitted_frames(plan: _Plan, with_right: bool = True
                   ) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
    """(source index, frame at the output size, right frame as read or None) of the selected
    frames, in order; the right frames only `with_right`."""
    frames, fit = plan.frames, plan.fit
    right = plan.right if with_right else None
    for index, image, right_image in _read_pairs(frames, right, plan.selected):
        yield index, fit(image, frames.frame_path(index), frames.frame_label(index)), right_image


def _prompted_masks(plan: _Plan, config: ImportConfig, inside: np.ndarray | None,
                    fitted: Iterator[tuple[int, np.ndarray, np.ndarray | None]],
                    confidences: list[float], report: Progress) -> Iterator[np.ndarray]:
    """The tool masks (bool [H, W]) of the frames `fitted` yields, from the clicks of
    --tool-prompts: a first pass over the clip decides them at the working size, then each is
    brought to its frame's size as `fitted` yields the frame. Appends the confidences."""
    assert plan.prompts is not None and config.tool_prompts is not None
    fit, radius = plan.fit, config.prompts.click_radius
    seeds = [(prompt.frame,
              fit.mask(seed_mask(prompt, "tool", fit.source_size, radius), config.tool_prompts),
              fit.mask(seed_mask(prompt, "tissue", fit.source_size, radius),
                       config.tool_prompts)) for prompt in plan.prompts]
    decided = prompted_tool_masks(
        (image for _, image, _ in _fitted_frames(plan, with_right=False)), inside, seeds,
        config.prompts,
        lambda done, total: report("tool prompts", done, total))
    for result, (_, image, _) in zip(decided, fitted):
        confidences.append(result.confidence)
        yield result.at_frame_size(image, inside, config.prompts)


@dataclass
class _DerivedProduct:
    """A product that import derives for every frame (depth, disparity or tool masks), with
    the number of frames on which it had content (a valid depth or disparity pixel, a tool
    pixel) so far."""

    source: Path
    """What derives it, named by the error: a model file, the right camera, the frames."""
    problem: str
    """What it means when no frame had content: the error's text."""
    frames: int = 0
    """Frames on which it had content so far."""

    def count(self, has_content: bool) -> None:
        """Count one more frame, with content or not."""
        self.frames += bool(has_content)

    def check(self) -> None:
        """DataError naming the source when no frame had content."""
        if self.frames == 0:
            raise DataError(self.source, self.problem)


@dataclass
class _DerivedProducts:
    """The products an import derives (None: not derived; tool masks from label files are
    given, not derived), each validated for content over the whole clip (`_DerivedProduct`)
    before the scene is called done."""

    masks: _DerivedProduct | None = None
    depth: _DerivedProduct | None = None
    disparity: _DerivedProduct | None = None

    @staticmethod
    def of(plan: _Plan, config: ImportConfig) -> "_DerivedProducts":
        """The products `config` derives from the frames of `plan`, with their sources."""
        count = len(plan.selected)
        products = _DerivedProducts()
        if plan.tool_model is not None:
            products.masks = _DerivedProduct(
                plan.tool_model.path, f"found no tool pixel in any of the {count} frames: "
                "check --tool-segmenter-output, the threshold and the model's mean and std")
        elif config.auto_tool_masks:
            products.masks = _DerivedProduct(
                plan.frames.path, f"shows no tool to the automatic tool segmenter in any of "
                f"its {count} frames; import it without --auto-tool-masks")
        elif config.tool_prompts is not None:
            products.masks = _DerivedProduct(
                config.tool_prompts, f"gives no tool pixel in any of the {count} frames: do "
                "its tool points lie on the tools?")
        if config.right is not None:
            matched = _DerivedProduct(
                config.right, f"matches no pixel of {plan.frames.path} in any of the {count} "
                "frames (no valid disparity): is it the other camera of a rectified pair, and "
                "not the same images again?")
            if config.disparity_only:
                products.disparity = matched
            else:
                products.depth = matched
        elif plan.depth_model is not None:
            products.depth = _DerivedProduct(
                plan.depth_model.path, f"gave no valid depth (an output that is positive and "
                f"finite) on any of the {count} frames: check --depth-model-output and the "
                "model's mean and std")
        elif config.depth == "shading":
            products.depth = _DerivedProduct(
                plan.frames.path, f"gives no shading depth on any of its {count} frames")
        return products

    def check(self) -> None:
        """DataError naming the source of the first product without content on every frame."""
        for product in (self.masks, self.depth, self.disparity):
            if product is not None:
                product.check()


def _recording_confidence(results: Iterator[AutoMask], confidences: list[float]
                          ) -> Iterator[np.ndarray]:
    """The masks (bool [H, W]) of the automatic segmenter's results, appending each frame's
    confidence to `confidences`."""
    for result in results:
        confidences.append(result.confidence)
        yield result.mask


def _open_right(config: ImportConfig, frames: FrameSource) -> FrameSource | None:
    if config.right is None:
        return None
    right = FrameSource(config.right, config.pattern)
    if right.count != frames.count:
        raise DataError(right.path, f"has {right.count} frames but the left source "
                                    f"{frames.path} has {frames.count}")
    return right


def _pair_masks(frames: FrameSource, config: ImportConfig) -> list[Path | None] | None:
    if config.masks is None:
        return None
    if (config.masks.resolve() == frames.path.resolve()
            and (config.pattern is None or config.mask_pattern is None)):
        raise SurgsplatError(f"frames and masks share the folder {config.masks}: pick each kind "
                             "with --pattern and --mask-pattern (e.g. '*_endo.png' and "
                             "'*_endo_watershed_mask.png')")
    mask_files = list_frame_files(config.masks, config.mask_pattern, what="mask")
    mode = resolve_mask_match(config.mask_match, frames.is_video)
    return match_masks(frames.files, frames.count, mask_files, mode)


def _output_size(source_size: tuple[int, int], config: ImportConfig) -> tuple[int, int]:
    """(H, W) of the written frames: the source size, or the size --scale or --resize asks
    for, which must lie between MIN_SIZE x MIN_SIZE and MAX_FRAME_PIXELS."""
    height, width = source_size
    if config.scale is not None:
        option = f"--scale {config.scale:g}"
        out_w, out_h = round(width * config.scale), round(height * config.scale)
    elif config.resize is not None:
        option = f"--resize {config.resize[0]}x{config.resize[1]}"
        out_w, out_h = config.resize
        if abs((out_w / out_h) / (width / height) - 1) > 0.01:
            raise SurgsplatError(f"{option} changes the aspect ratio of the {width}x{height} "
                                 "frames, which would stretch them; keep the ratio (e.g. use "
                                 "--scale)")
    else:
        return source_size
    if min(out_w, out_h) < MIN_SIZE or out_w * out_h > MAX_FRAME_PIXELS:
        side = math.isqrt(MAX_FRAME_PIXELS)
        raise SurgsplatError(f"{option} makes the {width}x{height} frames {out_w}x{out_h}; "
                             f"frames must be at least {MIN_SIZE}x{MIN_SIZE} and at most "
                             f"{MAX_FRAME_PIXELS:,} pixels ({side}x{side})")
    return out_h, out_w


def _camera(source_size: tuple[int, int], out_size: tuple[int, int], config: ImportConfig
            ) -> tuple[Intrinsics, str, tuple[np.ndarray, np.ndarray] | None]:
    """The camera at the output size, how it was obtained, and the cv2.remap maps that
    undistort the source frames (None when they need none)."""
    source_height, source_width = source_size
    undistort = None
    if config.calibration is not None:
        calibration = read_calibration(config.calibration)
        if calibration.size not in (None, (source_width, source_height)):
            raise DataError(config.calibration, f"is for {calibration.size[0]}x"
                                                f"{calibration.size[1]} (WxH) images but the "
                                                f"frames are {source_width}x{source_height}")
        intrinsics = calibration.intrinsics
        note = f"calibration: {calibration.key} of {config.calibration.resolve()}"
        if calibration.distortion is not None:
            if config.right is not None:
                raise DataError(config.calibration, "gives distortion but no rectified camera "
                                                    "P1: stereo needs rectified frames "
                                                    "(cv2.stereoRectify)")
            undistort = calibration.undistortion_maps(source_width, source_height)
            note += f"; frames undistorted ({calibration.distortion.tolist()})"
    else:
        if config.fx is not None:
            fx, fy, note = config.fx, config.fy, "given: --fx, --fy"
        elif config.focal is not None:
            fx = fy = config.focal
            note = "given: --focal"
        else:
            fx = fy = source_width / 2 / math.tan(math.radians(config.assumed_hfov_deg) / 2)
            note = (f"assumed: {config.assumed_hfov_deg:g} degree horizontal field of view "
                    "(pass --focal, --fx/--fy or --calibration for the real value)")
        if config.cx is not None:
            intrinsics = Intrinsics(fx, fy, config.cx + 0.5, config.cy + 0.5)
            note += "; principal point given (--cx, --cy)"
        else:
            intrinsics = Intrinsics(fx, fy, source_width / 2.0, source_height / 2.0)
            note += "; principal point at the image centre"
    try:
        intrinsics.check(source_width, source_height)
    except ValueError as err:
        raise SurgsplatError(f"camera of the {source_width}x{source_height} source frames: "
                             f"{err}") from None
    note += f" (source size {source_width}x{source_height})"
    scaled = intrinsics.scaled(out_size[1] / source_width, out_size[0] / source_height)
    return scaled, note, undistort


def _find_fov(frames: FrameSource, selected: list[int], fit: _Fitter, config: FovConfig,
              report: Progress) -> FovEstimate:
    """Field of view from the max brightness over up to FOV_SAMPLE_FRAMES selected frames."""
    picks = np.linspace(0, len(selected) - 1, min(len(selected), FOV_SAMPLE_FRAMES))
    sample = sorted({selected[int(round(p))] for p in picks})
    stat = None  # [H, W] uint8
    for done, (index, image) in enumerate(frames.read(sample), 1):
        light = brightness(fit(image, frames.frame_path(index), frames.frame_label(index)))
        stat = light if stat is None else np.maximum(stat, light)
        report("field of view", done, len(sample))
    return estimate_fov(stat, config)


def _read_pairs(frames: FrameSource, right: FrameSource | None,
                selected: list[int]) -> Iterator[tuple[int, np.ndarray, np.ndarray | None]]:
    """(index, left frame, right frame or None) for the selected frames."""
    if right is None:
        for index, image in frames.read(selected):
            yield index, image, None
        return
    for (index, image), (_, right_image) in zip(frames.read(selected), right.read(selected)):
        yield index, image, right_image


def _provenance(plan: _Plan, config: ImportConfig, confidences: list[float]) -> dict:
    """scene.json `extra`: what was imported and how; `confidences` are the automatic
    segmenter's per-frame confidences (empty without it)."""
    frames = plan.frames
    (source_h, source_w), (out_h, out_w) = plan.fit.source_size, plan.fit.out_size
    extra = {
        "importer": "surgsplat import",
        "source_frame_count": frames.count,
        "frame_range": {"start": config.start, "end": config.end, "stride": config.stride},
        "source_frames": [frames.frame_label(i) for i in plan.selected],
        "dropped_without_mask": [frames.frame_label(i) for i in plan.dropped],
        "source_size_wh": [source_w, source_h],
        "size_wh": [out_w, out_h],
        "focal_px": plan.intrinsics.fx,
        "camera_source": plan.camera_note,
        "fov_mask": plan.fov.describe() if plan.fov is not None else "off",
    }
    if config.masks is not None:
        extra["masks"] = {
            "automatic": False, "folder": str(config.masks.resolve()),
            "pattern": config.mask_pattern,
            "tool_labels": (list(config.tool_labels) if config.tool_labels is not None
                            else "binary (nonzero = tool)"),
            "matched_by": resolve_mask_match(config.mask_match, frames.is_video),
        }
    if config.auto_tool_masks:
        extra["masks"] = {"automatic": True, "segmenter": "surgsplat.data.auto_tool_masks",
                          "config": config.auto_masks.describe(),
                          "confidence": [round(value, 4) for value in confidences],
                          "confidence_meaning": CONFIDENCE_MEANING}
    if plan.prompts is not None:
        extra["masks"] = {"automatic": False, "segmenter": "surgsplat.data.prompted_masks",
                          "prompts_file": str(config.tool_prompts.resolve()),
                          "prompts": [prompt.describe() for prompt in plan.prompts],
                          "config": config.prompts.describe(),
                          "confidence": [round(value, 4) for value in confidences],
                          "confidence_meaning": PROMPTED_CONFIDENCE_MEANING}
    if plan.tool_model is not None:
        extra["masks"] = {"automatic": True, "segmenter": "onnx",
                          "model": str(plan.tool_model.path.resolve()),
                          "input_size_wh": list(plan.tool_model.input_size[::-1]),
                          "config": config.segmenter.describe()}
    if config.depth == "shading":
        extra["depth"] = {"source": "shading", "config": config.shading.describe(),
                          "scale": "relative: every frame's median depth is median_depth; train "
                                   "with --set components.depth.form=scale_invariant"}
    if plan.depth_model is not None:
        reading = "1 / output" if config.depth_network.output == "inverse_depth" else "output"
        extra["depth"] = {
            "source": "onnx", "model": str(plan.depth_model.path.resolve()),
            "input_size_wh": list(plan.depth_model.input_size[::-1]),
            "config": config.depth_network.describe(),
            "scale": f"relative: depth = {reading} (shift 0), every frame's median depth is "
                     "median_depth; train with --set components.depth.form=scale_invariant"}
    if config.right is not None:
        extra["stereo"] = {
            "right": str(config.right.resolve()), "baseline": config.baseline,
            "unit": config.depth_unit, "matcher": asdict(config.stereo),
            "output": (f"{DISPARITY_DIR}/ (px x {DISPARITY_STEPS}, 0 = invalid)"
                       if config.disparity_only else
                       f"depth/ (disparity < {MIN_DEPTH_DISPARITY:g} px stored as 0)"),
        }
    return extra
