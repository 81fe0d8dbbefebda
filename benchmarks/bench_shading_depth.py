"""The near-light shading depth prior (`surgsplat import --depth shading`) against true depth.

    python benchmarks/bench_shading_depth.py [--phantom DIR] [--scared DIR] [--work DIR]
                                             [--train-iters N [--reuse-runs]] [--out FILE]
                                             [--pictures DIR]

Phantom (generated into --work unless --phantom names one; its frames are linear, gamma 1):
the frames are imported with --depth shading and each depth map is compared with
gt/tissue_depth over the tissue pixels. SCARED (the real stereo pair beside the repository):
the left image's shading depth is compared with the structured-light ground truth, converted to
depth as 1 / disparity (focal x baseline is one constant, removed by the alignment), with the
importer's defaults (gamma 2.2, 70 degree field of view assumed).

The SCARED part also times the prior on its left image resized to 854x480 (`seconds_per_frame`
wall-clock and `cpu_seconds_per_frame`, medians of TIMING_REPEATS runs after one warm-up run).

Scores: `rel_clip` = mean |s d - d_true| / d_true with one scale s (median ratio) for the whole
clip, the quantity the prior promises; `rel_frame` with a scale per frame; Spearman rank
correlation; and, as a floor, `rel_constant`: the same error of a constant depth (the median).

With --train-iters, deform3dgs is trained on the phantom without depth (initial plane at the
true median distance) and with the shading depth (median set to that same distance, depth loss
in its scale-invariant form), and both are evaluated against the phantom's meshes.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from scipy.stats import spearmanr

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import write_report  # noqa: E402
from bench_stereo import read_ground_truth  # noqa: E402

from surgsplat.data.layout import IMAGE_SUFFIXES, Intrinsics, frame_stem, list_files  # noqa: E402
from surgsplat.data.phantom.generate import TISSUE_DEPTH_DIR  # noqa: E402
from surgsplat.data.scene import load_scene, read_image  # noqa: E402
from surgsplat.data.shading_depth import ShadingDepthConfig, shading_depth  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SCARED = ROOT.parent / "shared" / "data" / "scared-stereo-sample"
SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
SPEARMAN_SAMPLES = 200_000
"""Pixels (seeded random subset) over which the rank correlation is computed."""
TIMING_SIZE = (854, 480)
"""Frame size (width, height) at which seconds_per_frame is measured."""
TIMING_REPEATS = 3
"""Timed runs of the prior (after one warm-up run) whose median is seconds_per_frame."""
GEOMETRY = ("psnr_tissue", "chamfer_mm", "p2s_median_mm", "normal_error_deg_median")
"""Metrics of the training comparison (not depth_rmse_mm: eval takes it against the scene's
depth maps, which here are the prior itself or absent)."""


def surgsplat(*args: str) -> None:
    subprocess.run([*SURGSPLAT, *args], check=True, stdout=subprocess.DEVNULL)


def depth_scores(estimates: list[np.ndarray], truths: list[np.ndarray]) -> dict:
    """Scale-aligned errors and rank correlation of depth maps against true depth maps (float
    [H, W] each, 0 = not scored), pooled over all pixels where both are positive."""
    pairs = [(e[(e > 0) & (t > 0)], t[(e > 0) & (t > 0)]) for e, t in zip(estimates, truths)]
    estimate = np.concatenate([e for e, _ in pairs]).astype(np.float64)
    truth = np.concatenate([t for _, t in pairs]).astype(np.float64)
    per_frame = np.concatenate([e * np.median(t / e) for e, t in pairs])
    clip = estimate * np.median(truth / estimate)
    pick = np.random.default_rng(0).permutation(truth.size)[:SPEARMAN_SAMPLES]
    return {"pixels": int(truth.size),
            "rel_clip": float(np.mean(np.abs(clip - truth) / truth)),
            "rel_frame": float(np.mean(np.abs(per_frame - truth) / truth)),
            "rmse_clip": float(np.sqrt(np.mean((clip - truth) ** 2))),
            "spearman": float(spearmanr(estimate[pick], truth[pick])[0]),
            "rel_constant": float(np.mean(np.abs(np.median(truth) - truth) / truth))}


def colour_depth(depth: np.ndarray, low: float, high: float) -> np.ndarray:
    """BGR picture of a depth map (near = red, far = blue; black = no depth)."""
    scaled = np.clip((high - depth) / (high - low) * 255, 0, 255).astype(np.uint8)
    picture = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    picture[depth <= 0] = 0
    return picture


def save_pictures(path: Path, image: np.ndarray, estimate: np.ndarray, truth: np.ndarray) -> None:
    """Frame | aligned estimate | truth, side by side, in one colour scale."""
    valid = (estimate > 0) & (truth > 0)
    aligned = estimate * np.median(truth[valid] / estimate[valid])
    low, high = np.percentile(truth[truth > 0], [2, 98])
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), np.concatenate([image[..., ::-1], colour_depth(aligned, low, high),
                                           colour_depth(truth, low, high)], axis=1))


def phantom_depth(phantom: Path, work: Path, median: float, pictures: Path | None) -> dict:
    """Import the phantom's frames with --depth shading into work/ and score the depth."""
    camera = load_scene(phantom).camera
    scene = work / "phantom-shading"
    shutil.rmtree(scene, ignore_errors=True)
    surgsplat("import", str(phantom / "images"), "--masks", str(phantom / "masks"),
              "--fx", str(float(camera.K[0, 0])), "--fy", str(float(camera.K[1, 1])),
              "--depth", "shading", "--shading-gamma", "1", "--shading-median-depth",
              str(median), "--out", str(scene))
    imported = load_scene(scene)
    estimates, truths = [], []
    for frame in imported.frames:
        truth = np.load(phantom / TISSUE_DEPTH_DIR / f"{frame_stem(frame.index)}.npy")
        estimates.append(np.where(frame.tissue.numpy(), frame.depth.numpy(), 0.0))
        truths.append(truth)
        if pictures is not None and frame.index % 20 == 0:
            image = (frame.image.numpy() * 255).round().astype(np.uint8)
            save_pictures(pictures / f"phantom_{frame.index:03d}.png", image, estimates[-1],
                          truth)
    return {"frames": len(imported.frames), "scene": str(scene),
            **depth_scores(estimates, truths)}


def assumed_intrinsics(width: int, height: int) -> Intrinsics:
    """The importer's default camera: a 70 degree horizontal field of view, centred."""
    return Intrinsics.centred(width / 2 / np.tan(np.radians(70.0) / 2), width, height)


def seconds_per_frame(image: np.ndarray, config: ShadingDepthConfig) -> dict:
    """Median wall-clock and CPU seconds (all threads of this process) of the prior on `image`
    resized to TIMING_SIZE; CPU seconds tell the cost apart from other load on the machine."""
    frame = cv2.resize(image, TIMING_SIZE, interpolation=cv2.INTER_AREA)
    intrinsics = assumed_intrinsics(*TIMING_SIZE)
    wall, cpu = [], []
    for _ in range(TIMING_REPEATS + 1):
        start, start_cpu = time.perf_counter(), time.process_time()
        shading_depth(frame, intrinsics, None, config)
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    return {"seconds_per_frame": float(np.median(wall[1:])),
            "cpu_seconds_per_frame": float(np.median(cpu[1:])), "timing_size": list(TIMING_SIZE)}


def scared_depth(data: Path, pictures: Path | None) -> dict:
    """Shading depth of each left image against 1 / ground-truth disparity, and the prior's
    seconds per frame at TIMING_SIZE."""
    lefts = list_files(data / "left", IMAGE_SUFFIXES)
    truths = list_files(data / "disparity", (".tif", ".tiff"))
    occlusions = list_files(data / "occlusion", (".png",))
    config = ShadingDepthConfig()
    estimates, depths = [], []
    for left_path, truth_path, occlusion_path in zip(lefts, truths, occlusions):
        image = read_image(left_path)
        height, width = image.shape[:2]
        estimates.append(shading_depth(image, assumed_intrinsics(width, height), None, config))
        disparity = read_ground_truth(truth_path, occlusion_path)
        depths.append(np.where(disparity > 0, 1.0 / np.maximum(disparity, 1e-6), 0.0))
        if pictures is not None:
            save_pictures(pictures / f"scared_{left_path.stem}.png", image, estimates[-1],
                          depths[-1])
    return {"pairs": len(lefts), "config": config.describe(),
            **seconds_per_frame(image, config), **depth_scores(estimates, depths)}


def without_depth(phantom: Path, folder: Path) -> Path:
    """A view of the phantom without depth/ (links to its frames, masks and gt/)."""
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    for name in ("images", "masks", "gt", "poses_bounds.npy"):
        (folder / name).symlink_to((phantom / name).resolve())
    meta = json.loads((phantom / "scene.json").read_text())
    meta["depth_unit"] = "unknown"
    (folder / "scene.json").write_text(json.dumps(meta))
    return folder


def with_shading_depth(phantom: Path, shading_scene: Path, folder: Path) -> Path:
    """The phantom with its depth/ replaced by the imported shading depth."""
    without_depth(phantom, folder)
    (folder / "depth").symlink_to((shading_scene / "depth").resolve())
    shading_meta = json.loads((shading_scene / "scene.json").read_text())
    meta = json.loads((folder / "scene.json").read_text())
    meta.update(depth_unit=shading_meta["depth_unit"], depth_scale=shading_meta["depth_scale"])
    (folder / "scene.json").write_text(json.dumps(meta))
    return folder


def evaluated_at(run_dir: Path) -> int | None:
    """The iteration of the run's metrics.json, None when it has none."""
    path = run_dir / "metrics.json"
    return json.loads(path.read_text())["iteration"] if path.is_file() else None


def train_comparison(phantom: Path, shading_scene: Path, work: Path, median: float,
                     iterations: int, reuse: bool) -> dict:
    """deform3dgs without depth vs with the shading depth (scale-invariant loss); with `reuse`,
    a run folder already evaluated at `iterations` is kept instead of trained again."""
    cases = {
        "no_depth": (without_depth(phantom, work / "phantom-no-depth"),
                     ("--set", f"init.monocular_depth={median}")),
        "shading_depth": (with_shading_depth(phantom, shading_scene, work / "phantom-shading-gt"),
                          ("--set", "components.depth.form=scale_invariant",
                           "--set", "losses.depth.weight=1.0")),
    }
    rows = {}
    for name, (scene, options) in cases.items():
        run_dir = work / f"run-{name}"
        if not (reuse and evaluated_at(run_dir) == iterations):
            shutil.rmtree(run_dir, ignore_errors=True)
            surgsplat("train", "--method", "deform3dgs", "--data", str(scene), "--out",
                      str(run_dir), "--iters", str(iterations), *options)
            surgsplat("eval", str(run_dir))
        metrics = json.loads((run_dir / "metrics.json").read_text())
        rows[name] = {"settings": list(options[1::2]), "iterations": metrics["iteration"],
                      **{key: metrics.get(key) for key in GEOMETRY}}
    rows["shading_depth"]["chamfer_ratio_to_no_depth"] = (
        rows["no_depth"]["chamfer_mm"] / rows["shading_depth"]["chamfer_mm"])
    return {"method": "deform3dgs", "iterations": iterations, "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--phantom", type=Path, default=None,
                        help="phantom folder (default: generate the full pulling phantom)")
    parser.add_argument("--scared", type=Path, default=DEFAULT_SCARED)
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "surgsplat-bench-shading")
    parser.add_argument("--train-iters", type=int, default=None,
                        help="also train deform3dgs on the phantom without and with the prior")
    parser.add_argument("--reuse-runs", action="store_true",
                        help="keep training runs in --work already evaluated at --train-iters")
    parser.add_argument("--pictures", type=Path, default=None,
                        help="write frames next to their aligned shading depth and true depth")
    parser.add_argument("--out", type=Path, default=None, help="result file (default "
                        "benchmarks/results/bench_shading_depth-<cpu>-<best ISA>.json)")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    phantom = args.phantom
    if phantom is None:
        phantom = args.work / "phantom-pulling"
        if not (phantom / "poses_bounds.npy").is_file():
            surgsplat("phantom", "--out", str(phantom), "--preset", "full", "--motion", "pulling")
    truths = [np.load(path) for path in sorted((phantom / TISSUE_DEPTH_DIR).glob("*.npy"))]
    median = float(np.median(np.concatenate([t[t > 0] for t in truths])))
    result = {"scared": scared_depth(args.scared, args.pictures)}
    print(f"SCARED: rel_clip {result['scared']['rel_clip']:.3f} (constant depth "
          f"{result['scared']['rel_constant']:.3f}), Spearman {result['scared']['spearman']:.3f}, "
          f"{result['scared']['seconds_per_frame']:.2f} s "
          f"({result['scared']['cpu_seconds_per_frame']:.2f} s CPU) per 854x480 frame", flush=True)
    result["phantom"] = phantom_depth(phantom, args.work, median, args.pictures)
    result["phantom"]["median_depth_mm"] = median
    print(f"phantom: rel_clip {result['phantom']['rel_clip']:.3f} (constant depth "
          f"{result['phantom']['rel_constant']:.3f}), Spearman "
          f"{result['phantom']['spearman']:.3f}", flush=True)
    if args.train_iters:
        result["training"] = train_comparison(phantom, Path(result["phantom"]["scene"]),
                                              args.work, median, args.train_iters,
                                              args.reuse_runs)
        for name, row in result["training"]["rows"].items():
            print(f"deform3dgs {name}: chamfer {row['chamfer_mm']:.3f} mm, "
                  f"psnr_tissue {row['psnr_tissue']:.2f} dB")
    print(f"results: {write_report('bench_shading_depth', result, args.out)}")

if __name__ == "__main__":
    main()
