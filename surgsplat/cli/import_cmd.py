"""`surgsplat import SRC --out DIR`: video or frames (+ masks, + right camera) to a scene folder."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from surgsplat.cli.info import print_summary_table
from surgsplat.cli.progress import progress_bar
from surgsplat.data.importer import ImportConfig, import_scene
from surgsplat.data.layout import MAX_FRAME_PIXELS, META_FILE, SceneMeta
from surgsplat.data.learned_priors import (DEPTH_OUTPUTS, TOOL_OUTPUTS, DepthNetworkConfig,
                                           ToolSegmenterConfig)
from surgsplat.data.onnx_models import IMAGENET_MEAN, IMAGENET_STD, ModelInput
from surgsplat.data.scene import MIN_SIZE, load_scene
from surgsplat.data.sfm_poses import INSTALL_HINT, SfmConfig
from surgsplat.data.shading_depth import ShadingDepthConfig
from surgsplat.data.stereo import SGBM_MODES, StereoConfig
from surgsplat.data.tool_masks import MASK_MATCHES
from surgsplat.errors import SurgsplatError
from surgsplat.export.mask_preview import PREVIEW_FILE, write_mask_preview


def parse_labels(text: str | None) -> tuple[int, ...] | None:
    """"31,32" -> (31, 32)."""
    if text is None:
        return None
    try:
        return tuple(int(part) for part in text.split(",") if part.strip())
    except ValueError:
        raise SurgsplatError(f"--tool-labels expects comma-separated integers, got "
                             f"{text!r}") from None


def parse_size(text: str | None, option: str = "--resize") -> tuple[int, int] | None:
    """"640x360" -> (640, 360) as (width, height)."""
    if text is None:
        return None
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise SurgsplatError(f"{option} expects WIDTHxHEIGHT, e.g. 640x360, got {text!r}")
    return int(parts[0]), int(parts[1])


def parse_triple(text: str, option: str) -> tuple[float, float, float]:
    """"0.485,0.456,0.406" -> (0.485, 0.456, 0.406)."""
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3:
        raise SurgsplatError(f"{option} expects three comma-separated numbers (R,G,B), got "
                             f"{text!r}")
    return values


def model_input(size: str | None, multiple: int, mean: str, std: str, batch: int,
                prefix: str) -> ModelInput:
    """A model's ModelInput from the CLI options named `prefix`-input, -multiple, -mean, -std;
    `size` is WIDTHxHEIGHT or one number, the short side."""
    short_side = None
    if size is not None and size.strip().isdigit():
        short_side, size = int(size), None
    return ModelInput(size=parse_size(size, f"{prefix}-input (or one number, the short side)"),
                      short_side=short_side, multiple=multiple,
                      mean=parse_triple(mean, f"{prefix}-mean"),
                      std=parse_triple(std, f"{prefix}-std"), batch=batch)


CONTRACT = ("ONNX Runtime on the CPU (pip install 'surgsplat[onnx]'; no weights are shipped or "
            "fetched). Contract: one float32 NCHW input [N, 3, h, w], RGB, (pixel / 255 - mean) "
            "/ std, h x w the model's own if fixed, else from the -input option, else the frame "
            "size; one output [N, 1, h', w'] or [N, h', w'] at the input's aspect ratio, resized "
            "back to the frame bilinearly.")
"""The shared model contract, for --help (surgsplat.data.onnx_models states it in full)."""
IMAGENET_TEXT = ",".join(map(repr, IMAGENET_MEAN)), ",".join(map(repr, IMAGENET_STD))
"""ImageNet's mean and std (ModelInput's defaults) as the CLI spells them: `parse_triple` reads
them back to the same floats."""
InputSizeOption = Annotated[str | None, typer.Option(
    help="Input size of the model when its own is not fixed: WIDTHxHEIGHT, or one number, the "
         "short side (keeping the frames' aspect ratio; e.g. 518 for Depth Anything). Default: "
         "the frame size.")]
"""--tool-segmenter-input and --depth-model-input."""
MultipleOption = Annotated[int, typer.Option(
    help="Round both input sides chosen by the -input option (or the frame size) to a multiple "
         "of this: 14 for Depth Anything, 32 for a five-level UNet.")]
"""--tool-segmenter-multiple and --depth-model-multiple."""
MeanOption = Annotated[str, typer.Option(
    help="R,G,B mean subtracted from pixel / 255 (default ImageNet's; 0,0,0 with std 1,1,1 for "
         "0..1 input).")]
"""--tool-segmenter-mean and --depth-model-mean."""
StdOption = Annotated[str, typer.Option(
    help="R,G,B standard deviation dividing pixel / 255 - mean (default ImageNet's).")]
"""--tool-segmenter-std and --depth-model-std."""


def import_command(
    source: Annotated[Path, typer.Argument(help="Video file (mp4, avi, ...) or folder of frames "
                                                "(sorted naturally: frame_2 before frame_10).")],
    out: Annotated[Path, typer.Option(
        help="New scene folder to write (must not exist or be empty).")],
    pattern: Annotated[str | None, typer.Option(
        help="Glob picking the frame files in the source (and --right) folder, e.g. "
             "'*_endo.png'. Default: all image files.")] = None,
    masks: Annotated[Path | None, typer.Option(
        help="Folder of tool label images, one per frame.")] = None,
    mask_pattern: Annotated[str | None, typer.Option(
        help="Glob picking the mask files in --masks, e.g. '*_endo_watershed_mask.png'.")] = None,
    tool_labels: Annotated[str | None, typer.Option(
        help="Comma-separated class IDs that are tools in class-ID masks, e.g. 31,32 "
             "(CholecSeg8k). Without it masks are binary: nonzero = tool.")] = None,
    mask_match: Annotated[str, typer.Option(
        help=f"Pair masks with frames by: {', '.join(MASK_MATCHES)} (auto = the numbers in the "
             "file names for a folder, sorted order for a video).")] = ImportConfig.mask_match,
    allow_missing_masks: Annotated[bool, typer.Option(
        help="Drop frames that have no mask (default: stop with an error).")
    ] = ImportConfig.allow_missing_masks,
    auto_tool_masks: Annotated[bool, typer.Option(
        help="Find the tools (grey metal, black plastic) in every frame automatically, for "
             "video without --masks; scene.json records that the masks are automatic.")
    ] = ImportConfig.auto_tool_masks,
    tool_prompts: Annotated[Path | None, typer.Option(
        help='Tool masks from clicks: a JSON list of {"frame": INDEX, "tool": [[x, y], ...], '
             '"tissue": [[x, y], ...]}, INDEX the position among the imported frames, x, y '
             "pixels of the source frame; one click on each tool of one frame is often "
             "enough. The masks of every frame follow from them; scene.json records them.")
    ] = None,
    tool_segmenter: Annotated[Path | None, typer.Option(
        help="ONNX tool segmenter (MODEL.onnx) whose per-pixel tool probability gives the tool "
             "masks, inside the field of view; scene.json records the model. " + CONTRACT
             + " Its output is the tool's logit or probability "
             "(--tool-segmenter-output); a two-class model fits by giving "
             "logit(tool) - logit(background).")] = None,
    tool_segmenter_output: Annotated[str, typer.Option(
        help=f"What the tool segmenter's output holds: {' or '.join(TOOL_OUTPUTS)}.")
    ] = ToolSegmenterConfig.output,
    tool_segmenter_threshold: Annotated[float, typer.Option(
        help="Tool probability at and above which a pixel is tool.")
    ] = ToolSegmenterConfig.threshold,
    tool_segmenter_input: InputSizeOption = None,
    tool_segmenter_multiple: MultipleOption = ModelInput.multiple,
    tool_segmenter_mean: MeanOption = IMAGENET_TEXT[0],
    tool_segmenter_std: StdOption = IMAGENET_TEXT[1],
    fov_mask: Annotated[bool, typer.Option(
        help="Find the circular field of view (black border) and write it to fov_mask.png, "
             "apart from the tool masks.")] = ImportConfig.fov_mask,
    depth: Annotated[str, typer.Option(
        help="Monocular depth prior: none (the default), shading (relative depth from the light "
             "at the camera, I ~ albedo cos / r^2, by a near-light shape-from-shading fit; weak "
             "on real frames: on the real SCARED pair its rank correlation with true depth is "
             "far below 0.5 and its error no better than a constant depth, as albedo changes, "
             "sheen and the light's fall-off read as depth; see bench_shading_depth), or "
             "MODEL.onnx, a depth network giving relative inverse depth (or depth, "
             "--depth-model-output). " + CONTRACT + " Depth is 1 / "
             "output with its shift taken as 0, unknown where the output is not positive. "
             "Shading and model depth have one unknown scale: every frame's median depth is set "
             "to --shading-median-depth or --depth-model-median-depth; train with "
             "--set components.depth.form=scale_invariant.")] = ImportConfig.depth,
    shading_gamma: Annotated[float, typer.Option(
        help="Display gamma of the frames for --depth shading (1 = linear).")
    ] = ShadingDepthConfig.gamma,
    shading_median_depth: Annotated[float, typer.Option(
        help="Median depth of every frame for --depth shading, in scene units (the unknown "
             "absolute scale; 50 is also the distance training assumes without depth).")
    ] = ShadingDepthConfig.median_depth,
    depth_model_output: Annotated[str, typer.Option(
        help=f"What the --depth MODEL.onnx output holds: {' or '.join(DEPTH_OUTPUTS)} (both "
             "relative).")] = DepthNetworkConfig.output,
    depth_model_median_depth: Annotated[float, typer.Option(
        help="Median depth of every frame for --depth MODEL.onnx, in scene units (the unknown "
             "absolute scale).")] = DepthNetworkConfig.median_depth,
    depth_model_input: InputSizeOption = None,
    depth_model_multiple: MultipleOption = ModelInput.multiple,
    depth_model_mean: MeanOption = IMAGENET_TEXT[0],
    depth_model_std: StdOption = IMAGENET_TEXT[1],
    model_batch: Annotated[int, typer.Option(
        help="Frames per run of an ONNX model whose batch size is not fixed (else the model's "
             "own batch size).")] = ModelInput.batch,
    right: Annotated[Path | None, typer.Option(
        help="Right-camera video or folder of a stereo pair. Both cameras must be RECTIFIED "
             "(corresponding points on the same row); depth = focal x baseline / "
             "disparity.")] = None,
    focal: Annotated[float | None, typer.Option(
        help="Focal length in pixels of the source frames (square pixels). Default: --fx/--fy, "
             "--calibration, or guessed from --hfov.")] = None,
    fx: Annotated[float | None, typer.Option(
        help="Focal length along columns, pixels of the source frames (with --fy).")] = None,
    fy: Annotated[float | None, typer.Option(
        help="Focal length along rows, pixels of the source frames (with --fx).")] = None,
    cx: Annotated[float | None, typer.Option(
        help="Principal point column of the source frames, OpenCV convention (pixel centres "
             "at integers), with --cy. Default: the image centre.")] = None,
    cy: Annotated[float | None, typer.Option(
        help="Principal point row of the source frames, OpenCV convention, with --cx.")] = None,
    calibration: Annotated[Path | None, typer.Option(
        help="OpenCV calibration file (YAML/XML from cv2.FileStorage) of the source frames: "
             "P1 (rectified left camera) or camera_matrix / K / M1 with zero distortion; "
             "image_width / image_height are checked.")] = None,
    hfov: Annotated[float, typer.Option(
        help="Horizontal field of view (degrees) assumed when --focal is not given.")
    ] = ImportConfig.assumed_hfov_deg,
    baseline: Annotated[float | None, typer.Option(
        help="Stereo baseline in --depth-unit (needed with --right unless "
             "--disparity-only).")] = None,
    depth_unit: Annotated[str, typer.Option(help="Unit of --baseline and of the depth maps.")
                          ] = ImportConfig.depth_unit,
    disparity_only: Annotated[bool, typer.Option(
        help="With --right: write disparity (px) to disparity/ instead of depth.")
    ] = ImportConfig.disparity_only,
    num_disparities: Annotated[int, typer.Option(
        help="Stereo search range in pixels (multiple of 16).")] = StereoConfig.num_disparities,
    stereo_mode: Annotated[str, typer.Option(
        help=f"SGBM mode: {', '.join(SGBM_MODES)}.")] = StereoConfig.mode,
    start: Annotated[int, typer.Option(help="First source frame (0-based).")] = ImportConfig.start,
    end: Annotated[int | None, typer.Option(help="Stop before this source frame.")
                   ] = ImportConfig.end,
    stride: Annotated[int, typer.Option(help="Keep every n-th frame.")] = ImportConfig.stride,
    resize: Annotated[str | None, typer.Option(
        help=f"Output size WIDTHxHEIGHT, same aspect ratio, e.g. 640x360; at least "
             f"{MIN_SIZE}x{MIN_SIZE}, at most {MAX_FRAME_PIXELS:,} pixels.")] = None,
    scale: Annotated[float | None, typer.Option(
        help="Output size as a factor, e.g. 0.5 (the same bounds as --resize).")] = None,
    poses: Annotated[str, typer.Option(
        help="Camera poses: static (one fixed camera) or sfm (each frame's camera from "
             "structure from motion with COLMAP on the tissue pixels: the tool masks and the "
             "outside of the field of view are excluded; needs " + INSTALL_HINT + "). SfM "
             "scale: from stereo depth with --right, else the sparse points' median depth is "
             "--sfm-median-depth. Frames that fail to register get interpolated poses, listed "
             "in scene.json and by `surgsplat info`.")] = ImportConfig.poses,
    sfm_max_image_size: Annotated[int, typer.Option(
        help="SfM: longer side (pixels) of the frames as SIFT sees them.")
    ] = SfmConfig.max_image_size,
    sfm_max_features: Annotated[int, typer.Option(
        help="SfM: most SIFT features per frame.")] = SfmConfig.max_features,
    sfm_overlap: Annotated[int, typer.Option(
        help="SfM: match each frame i with frames i + 1 .. i + this and i + 2^k for k < "
             "this.")] = SfmConfig.overlap,
    sfm_refine_focal: Annotated[bool, typer.Option(
        help="SfM: refine the focal lengths in bundle adjustment and write the refined ones "
             "(for an assumed focal; not with --right).")] = SfmConfig.refine_focal,
    sfm_median_depth: Annotated[float, typer.Option(
        help="SfM without metric depth: the sparse points' median depth, scene units (50 is "
             "also the distance training assumes without depth).")] = SfmConfig.median_depth,
) -> None:
    """Import endoscopic video or frames as an EndoNeRF-layout scene folder."""
    config = import_config(locals())
    with progress_bar() as bar:
        tasks: dict[str, int] = {}

        def report(stage: str, done: int, total: int) -> None:
            if stage not in tasks:
                tasks[stage] = bar.add_task(stage, total=total)
            bar.update(tasks[stage], completed=done)

        scene_dir = import_scene(source, out, config, progress=report)
        if derives_masks(config):
            write_mask_preview(load_scene(scene_dir),
                               progress=lambda done, total: report("masks preview", done, total))
    print_import_table(scene_dir)
    print_summary_table(scene_dir)


def derives_masks(config: ImportConfig) -> bool:
    """Whether the import derives the tool masks (automatic, prompted or a model's), so that
    a person should look at them: it then writes masks_preview.mp4."""
    return (config.auto_tool_masks or config.tool_prompts is not None
            or config.tool_segmenter is not None)


def import_config(options: dict[str, Any]) -> ImportConfig:
    """The ImportConfig of `surgsplat import`'s options (by parameter name of `import_command`,
    text as typed): the options' defaults are ImportConfig's own, read from it."""
    o = SimpleNamespace(**options)
    return ImportConfig(
        pattern=o.pattern, masks=o.masks, mask_pattern=o.mask_pattern,
        tool_labels=parse_labels(o.tool_labels), mask_match=o.mask_match,
        allow_missing_masks=o.allow_missing_masks, auto_tool_masks=o.auto_tool_masks,
        tool_prompts=o.tool_prompts, tool_segmenter=o.tool_segmenter, segmenter=ToolSegmenterConfig(
            input=model_input(o.tool_segmenter_input, o.tool_segmenter_multiple,
                              o.tool_segmenter_mean, o.tool_segmenter_std, o.model_batch,
                              "--tool-segmenter"),
            output=o.tool_segmenter_output, threshold=o.tool_segmenter_threshold),
        fov_mask=o.fov_mask, depth=o.depth,
        shading=ShadingDepthConfig(gamma=o.shading_gamma, median_depth=o.shading_median_depth),
        depth_network=DepthNetworkConfig(
            input=model_input(o.depth_model_input, o.depth_model_multiple, o.depth_model_mean,
                              o.depth_model_std, o.model_batch, "--depth-model"),
            output=o.depth_model_output, median_depth=o.depth_model_median_depth),
        right=o.right, baseline=o.baseline, disparity_only=o.disparity_only,
        depth_unit=o.depth_unit,
        stereo=StereoConfig(num_disparities=o.num_disparities, mode=o.stereo_mode),
        focal=o.focal, fx=o.fx, fy=o.fy, cx=o.cx, cy=o.cy, calibration=o.calibration,
        assumed_hfov_deg=o.hfov, start=o.start, end=o.end, stride=o.stride,
        resize=parse_size(o.resize), scale=o.scale, poses=o.poses,
        sfm=SfmConfig(max_image_size=o.sfm_max_image_size, max_features=o.sfm_max_features,
                      overlap=o.sfm_overlap, refine_focal=o.sfm_refine_focal,
                      median_depth=o.sfm_median_depth))


def print_import_table(scene_dir: Path) -> None:
    """What the import did, from the scene's scene.json."""
    extra = SceneMeta.read(scene_dir / META_FILE).extra
    table = Table(title="import", show_header=False)
    table.add_row("source", f"{extra['source_frame_count']} frames, "
                            f"{extra['source_size_wh'][0]} x {extra['source_size_wh'][1]} px")
    table.add_row("written", f"{len(extra['source_frames'])} frames "
                             f"({extra['source_frames'][0]} .. {extra['source_frames'][-1]}), "
                             f"{len(extra['dropped_without_mask'])} dropped without a mask")
    table.add_row("camera", extra["camera_source"])
    fov = extra["fov_mask"]
    table.add_row("field of view", fov if isinstance(fov, str) else
                  f"{fov['kind']}, {100 * fov['inside_share']:.1f}% of pixels inside")
    if extra.get("masks", {}).get("segmenter") == "onnx":
        table.add_row("tool masks", f"ONNX segmenter {extra['masks']['model']}")
    elif extra.get("masks", {}).get("automatic"):
        table.add_row("tool masks", "automatic (classical segmenter)")
    elif "prompts" in extra.get("masks", {}):
        prompts = extra["masks"]["prompts"]
        table.add_row("tool masks", f"from the clicks on {len(prompts)} frame"
                                    f"{'s' if len(prompts) > 1 else ''} of "
                                    f"{extra['masks']['prompts_file']}")
    elif "masks" in extra:
        table.add_row("tool labels", str(extra["masks"]["tool_labels"]))
    if (scene_dir / PREVIEW_FILE).is_file():
        table.add_row("masks preview", f"{scene_dir / PREVIEW_FILE}: check it, and add a click "
                                       "(--tool-prompts) where a frame is wrong")
    if "depth" in extra:
        table.add_row("depth", f"{extra['depth']['source']} prior: {extra['depth']['scale']}")
    if "poses" in extra:
        sfm = extra["poses"]
        table.add_row("poses", f"SfM: {sfm['registered']} of {sfm['frames']} frames registered, "
                               f"{len(sfm['interpolated'])} interpolated, scale from "
                               f"{sfm['scale_source']}, reprojection error "
                               f"{sfm['reprojection_error_px']:.2f} px, {sfm['seconds']:.1f} s")
    if "stereo" in extra:
        table.add_row("stereo", f"baseline {extra['stereo']['baseline']} "
                                f"{extra['stereo']['unit']} -> {extra['stereo']['output']}")
    Console().print(table)
