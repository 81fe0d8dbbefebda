"""Long-clip benchmark: peak memory and training speed of a long clip against a short one.

A 854x480 clip of N frames is made from the full phantom (640x512, `--source-frames` frames):
each source frame is cropped to 16:9 and scaled to 854x480 (square pixels, focal scaled), and
the clip is time-stretched to N frames by blending the two nearest source frames (images and
depth linearly, tool masks by the nearer frame). Then `surgsplat train` runs as a subprocess on
a short clip (`--short` frames) and on the long one (`--frames`), each for `--iters`
iterations, and the benchmark reports each run's peak RSS (of the training process, loading
included), steps per second (from train_log.jsonl, after the first `--warmup` iterations) and
the long clip's speed as a ratio of the short one's.

    python benchmarks/bench_long_clip.py --work /tmp/longclip [--frames 7500] [--short 100]
                                         [--iters 300] [--method deform3dgs] [--json]

Targets (issue 17): 7,500 frames at 854x480 train with peak RSS <= 4 GB, at >= 90 % of the
100-frame clip's steps per second.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import surgsplat  # noqa: F401  (before torch: sets surgsplat's OpenMP wait policy)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import results_path  # noqa: E402

from surgsplat.data.layout import Intrinsics, SceneMeta, SceneWriter  # noqa: E402
from surgsplat.data.phantom import PhantomConfig, generate_phantom  # noqa: E402
from surgsplat.data.scene import load_scene  # noqa: E402
from surgsplat.render.native import system_info  # noqa: E402
from surgsplat.train.trainer import CHECKPOINT, LOG_FILE  # noqa: E402

SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
WIDTH, HEIGHT = 854, 480


def crop_and_scale(image: np.ndarray, interpolation: int) -> np.ndarray:
    """The centred 16:9 band of a 640x512 frame scaled to 854x480 ([H, W, ...] in and out)."""
    height, width = image.shape[:2]
    band = round(width * HEIGHT / WIDTH)
    top = (height - band) // 2
    return cv2.resize(image[top:top + band], (WIDTH, HEIGHT), interpolation=interpolation)


def source_frames(source: Path) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray],
                                          float]:
    """The phantom's frames cropped and scaled: uint8 RGB [H, W, 3], float depth [H, W] (mm),
    bool tool [H, W], and the scaled focal length (pixels)."""
    scene = load_scene(source)
    images, depths, tools = [], [], []
    for frame in scene.frames:
        images.append(crop_and_scale((frame.image.numpy() * 255).round().astype(np.uint8),
                                     cv2.INTER_AREA))
        depths.append(crop_and_scale(frame.depth.numpy(), cv2.INTER_NEAREST))
        tools.append(crop_and_scale(frame.tool.numpy().astype(np.uint8), cv2.INTER_NEAREST) > 0)
    return images, depths, tools, scene.camera.fx * WIDTH / scene.width


def write_clip(source: Path, out: Path, num_frames: int) -> float:
    """Write the time-stretched clip of `num_frames` frames to `out`; returns seconds taken."""
    if (out / "poses_bounds.npy").is_file():
        return 0.0
    started = time.perf_counter()
    images, depths, tools, focal = source_frames(source)
    meta = SceneMeta(depth_unit="mm", source=f"{source} time-stretched to {num_frames} frames",
                     intrinsics=Intrinsics(fx=focal, fy=focal, cx=WIDTH / 2, cy=HEIGHT / 2))
    partial = out.with_name(out.name + ".partial")
    writer = SceneWriter(partial, focal=focal, meta=meta)
    last = len(images) - 1
    for index in range(num_frames):
        position = index * last / max(num_frames - 1, 1)
        low = min(int(position), last)
        high = min(low + 1, last)
        weight = position - low
        image = (1 - weight) * images[low] + weight * images[high]
        both = (depths[low] > 0) & (depths[high] > 0)
        nearer = low if weight < 0.5 else high
        depth = np.where(both, (1 - weight) * depths[low] + weight * depths[high], depths[nearer])
        writer.add_frame(np.rint(image).astype(np.uint8), depth, tools[nearer])
    writer.finish()
    partial.rename(out)
    return time.perf_counter() - started


def train_case(scene: Path, run: Path, method: str, iters: int, warmup: int) -> dict:
    """Train `scene` in a subprocess: peak RSS of that process (loading included, as its final
    checkpoint records it), wall time and steps per second after `warmup` iterations."""
    shutil.rmtree(run, ignore_errors=True)
    started = time.perf_counter()
    subprocess.run([*SURGSPLAT, "train", "--data", str(scene), "--out", str(run), "--method",
                    method, "--iters", str(iters)], check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    state = torch.load(run / CHECKPOINT, map_location="cpu", weights_only=False)
    log = [json.loads(line) for line in (run / LOG_FILE).read_text().splitlines()]
    steady = [entry for entry in log if entry["iteration"] >= warmup]
    first, last = steady[0], steady[-1]
    return {"frames": int(state["num_frames"]), "iters": iters,
            "peak_rss_mb": round(float(state["peak_rss_mb"]), 1), "wall_seconds": round(wall, 1),
            "steps_per_s": round((last["iteration"] - first["iteration"])
                                 / (last["seconds"] - first["seconds"]), 3),
            "num_gaussians": last["num_gaussians"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=7500)
    parser.add_argument("--short", type=int, default=100)
    parser.add_argument("--source-frames", type=int, default=64)
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--warmup", type=int, default=50)
    parser.add_argument("--method", default="deform3dgs")
    parser.add_argument("--json", action="store_true", help="write benchmarks/results/...")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    source = args.work / f"phantom-{args.source_frames}"
    if not source.is_dir():
        generate_phantom(PhantomConfig(preset="full", num_frames=args.source_frames), source)
    rows = []
    for frames in (args.short, args.frames):  # short first: the long clip's RSS is the max
        clip = args.work / f"clip-{frames}"
        write_seconds = write_clip(source, clip, frames)
        run = args.work / f"run-{frames}-{args.method}-{args.iters}"
        row = train_case(clip, run, args.method, args.iters, args.warmup)
        row["write_seconds"] = round(write_seconds, 1)
        rows.append(row)
        print(json.dumps(row), flush=True)
    short, long = rows
    info = system_info()
    report = {"benchmark": "bench_long_clip", "cpu": info["cpu"], "system": info,
              "date": time.strftime("%Y-%m-%d"), "method": args.method, "width": WIDTH, "height": HEIGHT, "rows": rows,
              "steps_ratio": round(long["steps_per_s"] / short["steps_per_s"], 3),
              "targets": {"peak_rss_mb": 4096, "steps_ratio": 0.9}}
    print(json.dumps(report, indent=2))
    if args.json:
        out = results_path("bench_long_clip", info)
        out.write_text(json.dumps(report, indent=2) + "\n")
        print(f"results: {out}")


if __name__ == "__main__":
    main()
