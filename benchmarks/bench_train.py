"""Training benchmark: both presets on the full "pulling" phantom (640x512, 64 frames) within a
wall-time budget, with PSNR against training time; and the real CholecSeg8k clip (imported,
no depth) with PSNR on its held-out frames.

    python benchmarks/bench_train.py [--json] [--minutes 10] [--presets deform3dgs endogaussian]
                                     [--phantom DIR] [--work DIR] [--skip-real]

Targets (issue 4): psnr_tissue >= 35 dB and depth_rmse_mm <= 1.0 on the phantom, trained in at
most 10 minutes wall, peak RSS <= 4 GB.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import shutil
import tempfile
import time
from pathlib import Path

import torch

from surgsplat.data.importer import ImportConfig, import_scene
from surgsplat.data.phantom import PhantomConfig, generate_phantom
from surgsplat.data.scene import Scene, load_scene
from surgsplat.eval.image_metrics import psnr_tissue
from surgsplat.eval.run_metrics import EvalOptions, evaluate_run
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.registry import method_config
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train.run import load_trained_run
from surgsplat.train.trainer import Trainer

REAL_CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "cholecseg8k-clip"
REPORTED = ("psnr_tissue", "psnr_zeroed", "ssim", "lpips", "depth_rmse_mm", "chamfer_mm",
            "p2s_median_mm", "fscore_1mm", "fps", "num_gaussians", "peak_rss_mb")


def test_psnr(trainer: Trainer) -> float:
    """Mean psnr_tissue over the test frames, rendered now."""
    values = []
    for frame in trainer.scene.test_frames:
        out = render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time),
                           trainer.background)
        values.append(psnr_tissue(out.rgb.clamp(0, 1), frame.image, frame.tissue))
    return sum(values) / len(values)


def train_within(config: MethodConfig, scene: Scene, run_dir: Path, budget_s: float,
                 curve_every: int) -> tuple[list[list[float]], float]:
    """Train until config.train.iterations or the wall-time budget; returns the PSNR curve
    [[iteration, train seconds, test psnr_tissue], ...] and the wall time."""
    started = time.perf_counter()
    trainer = Trainer(config, scene, run_dir)
    trainer.write_run_files()
    curve = []
    while trainer.iteration < config.train.iterations:
        trainer.step()
        if trainer.iteration % curve_every == 0:
            curve.append([trainer.iteration, round(trainer.elapsed, 1), round(test_psnr(trainer), 2)])
        if time.perf_counter() - started > budget_s:
            break
    trainer.save()
    return curve, time.perf_counter() - started


def run_case(scene_name: str, scene_dir: Path, preset: str, work: Path, minutes: float,
             iterations: int | None) -> dict:
    config = method_config(preset)
    if iterations:
        config.train.iterations = iterations
    run_dir = work / f"{scene_name}-{preset}"
    shutil.rmtree(run_dir, ignore_errors=True)
    started = time.perf_counter()  # wall time includes loading the scene and building the model
    scene = load_scene(scene_dir)
    curve, _ = train_within(config, scene, run_dir, minutes * 60,
                            curve_every=max(config.train.iterations // 10, 1))
    wall = time.perf_counter() - started
    metrics = evaluate_run(load_trained_run(run_dir), EvalOptions())
    row = {"scene": scene_name, "method": preset, "iterations": metrics["iteration"],
           "train_seconds": round(metrics["train_seconds"], 1), "wall_seconds": round(wall, 1)}
    row.update({key: metrics[key] for key in REPORTED if key in metrics})
    # measured here, on this process (which trained): the peak so far, cases run in sequence
    row["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    row["curve"] = curve
    return row


def real_clip_scene(work: Path) -> Path:
    scene_dir = work / "cholecseg8k-clip"
    if not (scene_dir / "poses_bounds.npy").is_file():
        shutil.rmtree(scene_dir, ignore_errors=True)
        import_scene(REAL_CLIP, scene_dir, ImportConfig(
            pattern="*_endo.png", masks=REAL_CLIP, mask_pattern="*_endo_watershed_mask.png",
            tool_labels=(31, 32), allow_missing_masks=True))
    return scene_dir


def print_row(row: dict) -> None:
    def show(value):
        if value is None:
            return "null"
        return f"{value:.3f}" if isinstance(value, float) and not math.isinf(value) else str(value)

    print(f"\n{row['scene']} / {row['method']}: {row['iterations']} iterations, "
          f"{row['train_seconds']} s training, {row['wall_seconds']} s wall")
    print("  " + ", ".join(f"{k} {show(row[k])}" for k in REPORTED if k in row))
    print("  test psnr_tissue vs training seconds: "
          + ", ".join(f"{s:.0f}s {p:.2f}" for _, s, p in row["curve"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--json", action="store_true", help="one JSON object per run")
    parser.add_argument("--minutes", type=float, default=10.0, help="wall budget per run")
    parser.add_argument("--presets", nargs="+", default=["deform3dgs", "endogaussian"])
    parser.add_argument("--iters", type=int, default=None, help="override preset iterations")
    parser.add_argument("--phantom", type=Path, default=None,
                        help="existing full phantom (default: generate one under --work)")
    parser.add_argument("--work", type=Path, default=Path(tempfile.gettempdir()) / "surgsplat-bench")
    parser.add_argument("--skip-real", action="store_true", help="skip the CholecSeg8k clip")
    args = parser.parse_args()
    torch.set_num_threads(2)
    args.work.mkdir(parents=True, exist_ok=True)
    phantom = args.phantom or args.work / "phantom-full-pulling"
    if not (phantom / "poses_bounds.npy").is_file():
        generate_phantom(PhantomConfig(preset="full", motion="pulling"), phantom)
    cases = [("phantom-full-pulling", phantom, preset) for preset in args.presets]
    if not args.skip_real and REAL_CLIP.is_dir():
        cases.append(("cholecseg8k-clip", real_clip_scene(args.work), args.presets[0]))
    for scene_name, scene_dir, preset in cases:
        row = run_case(scene_name, scene_dir, preset, args.work, args.minutes, args.iters)
        print(json.dumps(row)) if args.json else print_row(row)


if __name__ == "__main__":
    main()
