"""Write a phantom to disk: an EndoNeRF-layout scene plus its ground truth under gt/.

Besides images/, depth/ (mm, the tool where the tool is), masks/ (255 = tool),
poses_bounds.npy (each frame's endoscope pose) and scene.json, the folder holds per frame i
(stem = 6-digit index):

    gt/tissue_images/{stem}.png  the frame without the tool (same light and exposure)
    gt/tissue_depth/{stem}.npy   float32 [H, W] tissue depth in mm (frame i's camera z), also
                                 behind the tool
    gt/albedo/{stem}.png         tissue albedo
    gt/normals/{stem}.npy        float32 [H, W, 3] unit tissue normals in frame i's camera space
    gt/meshes/{stem}.ply         the tissue surface at time i / N, world frame, mm (binary PLY)
    gt/highlights/{stem}.png     255 where the tissue's specular highlight adds more than
                                 HIGHLIGHT_THRESHOLD to the image (before clipping), else 0
    gt/exposure.json             list of the per-frame exposure factors
    gt/shading/{stem}.npy        float32 [H, W] true tissue shading (with --lighting livar or
                                 hivar): tissue_images = albedo * shading + specular, clipped
    gt/light_intensity.json      list of the per-frame light intensities (same lightings)
    gt/camera_poses.npy          float64 [N, 4, 4] OpenCV world-to-camera of every frame
    gt/tool_kinematics.json      the tool's shaft pose, hinge axis and point, and jaw angles per
                                 frame, world frame, mm and degrees (see `kinematics`)

The world frame is the first frame's camera frame (see `camera_path`), so for the default
static camera every pose is the identity and world = camera space.
"""

from __future__ import annotations

import json
import errno
import os
import shutil
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from surgsplat.data.layout import SceneMeta, SceneWriter, frame_stem, write_image
from surgsplat.data.phantom.camera_path import CAMERAS
from surgsplat.data.phantom.kinematics import TOOL_KINEMATICS_FILE, tool_kinematics
from surgsplat.data.phantom.mesh import grid_mesh
from surgsplat.data.phantom.motion import MOTIONS
from surgsplat.data.phantom.scene import PhantomFrame, PhantomScene
from surgsplat.data.phantom.shading import LIGHTINGS, METAL, WET_TISSUE, shade
from surgsplat.data.ply import write_ply_mesh
from surgsplat.errors import SurgsplatError

GT_DIR = "gt"
TISSUE_IMAGES_DIR = f"{GT_DIR}/tissue_images"
TISSUE_DEPTH_DIR = f"{GT_DIR}/tissue_depth"
ALBEDO_DIR = f"{GT_DIR}/albedo"
NORMALS_DIR = f"{GT_DIR}/normals"
MESHES_DIR = f"{GT_DIR}/meshes"
HIGHLIGHTS_DIR = f"{GT_DIR}/highlights"
HIGHLIGHT_THRESHOLD = 0.1
"""Specular radiance (image units, 1 = white) above which a tissue pixel is a highlight."""
EXPOSURE_FILE = f"{GT_DIR}/exposure.json"
SHADING_DIR = f"{GT_DIR}/shading"
LIGHT_INTENSITY_FILE = f"{GT_DIR}/light_intensity.json"
CAMERA_POSES_FILE = f"{GT_DIR}/camera_poses.npy"
MAX_SEED = 2**32 - 1
"""Largest phantom seed: seeds are the unsigned 32-bit words of numpy's seed sequences."""
MAX_FRAMES = 10_000
"""Most frames of a phantom: an 11-minute clip at 15 frames/s, above any clip the benchmarks
use (a mistyped count would otherwise ray-cast for days)."""


@dataclass(frozen=True)
class PhantomPreset:
    """Camera and length of a named phantom size."""

    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    num_frames: int
    """Default number of frames."""
    focal: float
    """Focal length, pixels."""
    mesh_step: int
    """Pixels between neighbouring ground-truth mesh vertices."""


ENDONERF_FOCAL = 569.4682
"""Focal length of the real EndoNeRF camera at 640 x 512, pixels."""
PRESETS = {
    "small": PhantomPreset(width=160, height=128, num_frames=16, focal=ENDONERF_FOCAL / 4,
                           mesh_step=4),
    "full": PhantomPreset(width=640, height=512, num_frames=64, focal=ENDONERF_FOCAL, mesh_step=8),
}


@dataclass
class PhantomConfig:
    """Which phantom to generate."""

    preset: str = "small"
    """Size preset: "small" (160x128, 16 frames) or "full" (640x512, 64 frames)."""
    motion: str = "pulling"
    """Tissue motion: "pulling" (tool lifts the tissue), "cutting" (a groove opens) or
    "grasping" (the tool stays in view, its jaws open wide and close three times)."""
    camera: str = "static"
    """Endoscope: "static" or "moving" (translates a few mm, turns a few degrees)."""
    seed: int = 0
    """Seed of the texture, surface shape and tool path, in 0 .. MAX_SEED; equal seeds give
    identical files."""
    num_frames: int | None = None
    """Number of frames; None = the preset's default."""
    lighting: str = "standard"
    """Light over the clip (see shading.LIGHTINGS): "standard", "livar" (the same light, with
    gt/shading) or "hivar" (intensity and exposure vary > 2x, light off the camera centre)."""


def check_phantom_request(config: PhantomConfig, out_dir: Path) -> tuple[PhantomPreset, int]:
    """(preset, number of frames) of `config`; SurgsplatError if `config` is invalid or
    `out_dir` exists and is not an empty folder."""
    if config.preset not in PRESETS:
        raise SurgsplatError(f"unknown phantom preset {config.preset!r}; valid presets: "
                             f"{', '.join(PRESETS)}")
    if config.motion not in MOTIONS:
        raise SurgsplatError(f"unknown phantom motion {config.motion!r}; valid motions: "
                             f"{', '.join(MOTIONS)}")
    if config.camera not in CAMERAS:
        raise SurgsplatError(f"unknown phantom camera {config.camera!r}; valid cameras: "
                             f"{', '.join(CAMERAS)}")
    if config.lighting not in LIGHTINGS:
        raise SurgsplatError(f"unknown phantom lighting {config.lighting!r}; valid lightings: "
                             f"{', '.join(LIGHTINGS)}")
    if not 0 <= config.seed <= MAX_SEED:
        raise SurgsplatError(f"--seed: the phantom seed must be an integer in 0..{MAX_SEED}, "
                             f"got {config.seed}")
    preset = PRESETS[config.preset]
    num_frames = preset.num_frames if config.num_frames is None else config.num_frames
    if not 1 <= num_frames <= MAX_FRAMES:
        raise SurgsplatError(f"--frames: the number of frames must be in 1..{MAX_FRAMES}, got "
                             f"{num_frames}")
    out_dir = Path(out_dir)
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise SurgsplatError(f"{out_dir} already exists and is not an empty folder; choose "
                             "another output folder or remove it")
    return preset, num_frames


def generate_phantom(config: PhantomConfig, out_dir: Path,
                     progress: Callable[[int, int], None] | None = None) -> Path:
    """Render the phantom `config` into the new or empty folder `out_dir` and return it;
    `progress(done, total)` is called after each frame. The files are written into a hidden
    sibling folder that is renamed to `out_dir` only when complete, so a stopped generation
    never leaves a half-written phantom behind. An OSError (a full disk, say) names the file of
    `out_dir` that could not be written, or `out_dir` itself."""
    preset, num_frames = check_phantom_request(config, out_dir)
    final = Path(out_dir)
    partial = final.with_name(f".{final.name}.partial-{os.getpid()}")
    shutil.rmtree(partial, ignore_errors=True)
    try:
        _write_phantom(config, preset, num_frames, partial, progress)
        if final.exists() and not any(final.iterdir()):
            final.rmdir()  # an empty folder (check_phantom_request refused any other)
        os.replace(partial, final)
    except OSError as err:
        if err.errno in (errno.ENOTEMPTY, errno.EEXIST) and final.is_dir():
            raise SurgsplatError(f"{final}: another process wrote into it while this phantom "
                                 "was generated; choose another output folder") from None
        raise _naming_the_output(err, partial, final) from err
    finally:
        shutil.rmtree(partial, ignore_errors=True)
    return final


def _naming_the_output(err: OSError, partial: Path, final: Path) -> OSError:
    """`err` with the path the user asked for: a file of the hidden folder `partial` (removed
    on failure) becomes the same file of `final`, and an error naming no file names `final`."""
    if err.filename is not None and not Path(err.filename).is_relative_to(partial):
        return err
    named = final if err.filename is None else final / Path(err.filename).relative_to(partial)
    return OSError(err.errno, err.strerror or str(err), str(named))


def _write_phantom(config: PhantomConfig, preset: PhantomPreset, num_frames: int, out_dir: Path,
                   progress: Callable[[int, int], None] | None) -> None:
    """Render every frame and its ground truth into `out_dir`."""

    scene = PhantomScene(preset.width, preset.height, preset.focal, num_frames, config.motion,
                         config.seed, config.camera, config.lighting)
    meta = SceneMeta(depth_unit="mm", source=f"phantom {config.preset} {config.motion} "
                                             f"seed {config.seed}",
                     extra=_extra(config, preset, num_frames, scene))
    writer = SceneWriter(out_dir, focal=preset.focal, meta=meta)
    for sub in (TISSUE_IMAGES_DIR, TISSUE_DEPTH_DIR, ALBEDO_DIR, NORMALS_DIR, MESHES_DIR,
                HIGHLIGHTS_DIR):
        (out_dir / sub).mkdir(parents=True, exist_ok=True)
    writes_shading = scene.lighting.writes_shading
    if writes_shading:
        (out_dir / SHADING_DIR).mkdir(parents=True, exist_ok=True)
    exposures, intensities, poses = [], [], []
    for index in range(num_frames):
        frame = scene.render(index)
        writer.add_frame(frame.image, frame.depth, frame.tool_mask, frame.world_to_camera)
        stem = frame_stem(index)
        _write_rgb(out_dir / TISSUE_IMAGES_DIR / f"{stem}.png", frame.tissue_image)
        _write_rgb(out_dir / ALBEDO_DIR / f"{stem}.png", frame.albedo)
        np.save(out_dir / TISSUE_DEPTH_DIR / f"{stem}.npy", frame.tissue_depth)
        np.save(out_dir / NORMALS_DIR / f"{stem}.npy", frame.normals)
        if writes_shading:
            np.save(out_dir / SHADING_DIR / f"{stem}.npy", frame.shading)
        write_image(out_dir / HIGHLIGHTS_DIR / f"{stem}.png", _highlights(scene, frame))
        vertices, faces, colors = grid_mesh(frame.tissue_depth, scene.xn, scene.yn,
                                            preset.mesh_step, frame.albedo)  # camera space
        camera_to_world = scene.camera_path.camera_to_world(scene.time(index))
        vertices = vertices @ camera_to_world[:3, :3].T + camera_to_world[:3, 3]
        write_ply_mesh(out_dir / MESHES_DIR / f"{stem}.ply", vertices, faces, colors)
        exposures.append(frame.exposure)
        intensities.append(frame.light_intensity)
        poses.append(frame.world_to_camera)
        if progress is not None:
            progress(index + 1, num_frames)
    (out_dir / EXPOSURE_FILE).write_text(json.dumps(exposures) + "\n")
    if writes_shading:
        (out_dir / LIGHT_INTENSITY_FILE).write_text(json.dumps(intensities) + "\n")
    np.save(out_dir / CAMERA_POSES_FILE, np.stack(poses))
    tool_poses = [scene.tool_pose(scene.time(index)) for index in range(num_frames)]
    (out_dir / TOOL_KINEMATICS_FILE).write_text(
        json.dumps(tool_kinematics(tool_poses, scene.geometry), indent=1) + "\n")
    writer.finish()


def _highlights(scene: PhantomScene, frame: PhantomFrame) -> np.ndarray:
    """uint8 [H, W]: 255 where the tissue's specular term alone (zero albedo) exceeds
    HIGHLIGHT_THRESHOLD."""
    depth = frame.tissue_depth.astype(np.float64)
    points = np.stack([depth * scene.xn, depth * scene.yn, depth], axis=-1)
    specular = shade(points, frame.normals.astype(np.float64), np.zeros_like(points), WET_TISSUE,
                     scene.light, frame.exposure)[..., 0]
    return np.where(specular > HIGHLIGHT_THRESHOLD, 255, 0).astype(np.uint8)


def _write_rgb(path: Path, image: np.ndarray) -> None:
    """Write float RGB [H, W, 3] in [0, 1] as an 8-bit PNG."""
    pixels = np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)
    write_image(path, pixels[..., ::-1])


def _extra(config: PhantomConfig, preset: PhantomPreset, num_frames: int,
           scene: PhantomScene) -> dict:
    """Facts about the phantom for scene.json."""
    extra = {
        "preset": config.preset, "motion": config.motion, "camera": config.camera,
        "camera_path": asdict(scene.camera_path), "seed": config.seed,
        "num_frames": num_frames, "width": preset.width, "height": preset.height,
        "focal": preset.focal, "mesh_step_px": preset.mesh_step,
        "light": asdict(scene.light), "tissue_material": asdict(WET_TISSUE),
        "tool_material": asdict(METAL), "exposure": asdict(scene.exposure),
        "tool": asdict(scene.geometry), "trocar_mm": scene.trocar.tolist(),
        "gt": {"tissue_images": TISSUE_IMAGES_DIR, "tissue_depth": TISSUE_DEPTH_DIR,
               "albedo": ALBEDO_DIR, "normals": NORMALS_DIR, "meshes": MESHES_DIR,
               "highlights": HIGHLIGHTS_DIR,
               "exposure": EXPOSURE_FILE, "camera_poses": CAMERA_POSES_FILE,
               "tool_kinematics": TOOL_KINEMATICS_FILE,
               "depth_unit": "mm", "frames": "depth and normals: per-frame camera space; "
                                             "meshes: world frame (= frame 0's camera)"},
    }
    if scene.lighting.writes_shading:  # the standard phantom's scene.json stays as it was
        extra["lighting"] = asdict(scene.lighting)
        extra["gt"].update(shading=SHADING_DIR, light_intensity=LIGHT_INTENSITY_FILE)
    return extra
