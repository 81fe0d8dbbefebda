"""Long-clip benchmark: peak memory and training speed of a long clip against a short one, and
the time `load_scene` takes to validate the long clip.

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
                                         [--validate-only]

Validation: `load_scene` of the long clip runs in its own process (header checks, then every
frame decoded and checked on the process's torch threads, and fingerprinted), timed whole; the
same process first times a reference, one thread decoding every `--reference-every`-th frame's
files once with cv2.imread (the decoding work alone), so that the ratio of the two per frame
tells the code's speed apart from the shared machine's load; the process's CPU seconds are
recorded too (wall seconds on free cores are at least CPU seconds / threads). `--validate-only` skips training
and writes bench_long_clip_validation-<cpu>-<isa>.json. A clip shorter than 7,500 frames gives
the seconds extrapolated to 7,500 frames linearly (validation is per frame), stated as such.

Targets: 7,500 frames at 854x480 train with peak RSS <= 4 GB, at >= 90 % of the 100-frame
clip's steps per second (issue 17); load_scene validates them in <= 180 s on 2 cores (issue 30).
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
TARGET_FRAMES = 7500
"""The clip length that the validation target is stated for (issue 30)."""
TARGET_VALIDATION_SECONDS = 180.0
VALIDATION_PROBE = """
import json, sys, time
from pathlib import Path
import surgsplat
import cv2, torch
from surgsplat.data.scene import load_scene
clip, every = Path(sys.argv[1]), int(sys.argv[2])
files = sorted(p for folder in ("images", "depth", "masks") for p in (clip / folder).iterdir())
sample = [p for p in files if int(p.stem) % every == 0]
started = time.perf_counter()
for path in sample:
    cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
reference = time.perf_counter() - started
started, cpu_started = time.perf_counter(), time.process_time()
scene = load_scene(clip)
seconds, cpu_seconds = time.perf_counter() - started, time.process_time() - cpu_started
print(json.dumps({"frames": len(scene.frames), "seconds": seconds, "cpu_seconds": cpu_seconds,
                  "threads":
                  torch.get_num_threads(), "reference_frames": len({p.stem for p in sample}),
                  "reference_seconds": reference}))
"""


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


def validation_case(clip: Path, reference_every: int) -> dict:
    """Seconds of load_scene(clip) in its own process, per frame, extrapolated to TARGET_FRAMES,
    and as a ratio of the one-thread decoding reference measured in the same process."""
    probe = subprocess.run([sys.executable, "-c", VALIDATION_PROBE, str(clip),
                            str(reference_every)], check=True, capture_output=True, text=True)
    measured = json.loads(probe.stdout.splitlines()[-1])
    per_frame = measured["seconds"] / measured["frames"]
    reference_per_frame = measured["reference_seconds"] / measured["reference_frames"]
    return {"frames": measured["frames"], "threads": measured["threads"],
            "seconds": round(measured["seconds"], 1),
            "cpu_seconds": round(measured["cpu_seconds"], 1),
            "ms_per_frame": round(1000 * per_frame, 2),
            "reference_ms_per_frame": round(1000 * reference_per_frame, 2),
            "ratio_to_reference": round(per_frame / reference_per_frame, 3),
            f"seconds_at_{TARGET_FRAMES}_frames": round(per_frame * TARGET_FRAMES, 1),
            f"cpu_seconds_at_{TARGET_FRAMES}_frames": round(
                measured["cpu_seconds"] / measured["frames"] * TARGET_FRAMES, 1),
            "extrapolated": measured["frames"] != TARGET_FRAMES,
            "target_seconds": TARGET_VALIDATION_SECONDS}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--frames", type=int, default=7500)
    parser.add_argument("--short", type=int, default=100)
    parser.add_argument("--source-frames", type=int, default=64)
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--warmup", type=int, default=50)
    parser.add_argument("--method", default="deform3dgs")
    parser.add_argument("--reference-every", type=int, default=10)
    parser.add_argument("--validate-only", action="store_true",
                        help="time load_scene of the long clip only, no training")
    parser.add_argument("--json", action="store_true", help="write benchmarks/results/...")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    source = args.work / f"phantom-{args.source_frames}"
    if not source.is_dir():
        generate_phantom(PhantomConfig(preset="full", num_frames=args.source_frames), source)
    long_clip = args.work / f"clip-{args.frames}"
    write_seconds = write_clip(source, long_clip, args.frames)
    validation = validation_case(long_clip, args.reference_every)
    print(json.dumps({"validation": validation}), flush=True)
    info = system_info()
    report = {"benchmark": "bench_long_clip", "cpu": info["cpu"], "system": info,
              "date": time.strftime("%Y-%m-%d"), "width": WIDTH, "height": HEIGHT,
              "validation": validation}
    if not args.validate_only:
        report.update(training_report(args, source, write_seconds))
    print(json.dumps(report, indent=2))
    if args.json:
        name = "bench_long_clip_validation" if args.validate_only else "bench_long_clip"
        out = results_path(name, info)
        out.write_text(json.dumps(report, indent=2) + "\n")
        print(f"results: {out}")


def training_report(args: argparse.Namespace, source: Path, long_write_seconds: float) -> dict:
    """Train the short and the long clip (see the module doc); the report's training part."""
    rows = []
    for frames in (args.short, args.frames):  # short first: the long clip's RSS is the max
        clip = args.work / f"clip-{frames}"
        write_seconds = write_clip(source, clip, frames) if frames != args.frames \
            else long_write_seconds
        run = args.work / f"run-{frames}-{args.method}-{args.iters}"
        row = train_case(clip, run, args.method, args.iters, args.warmup)
        row["write_seconds"] = round(write_seconds, 1)
        rows.append(row)
        print(json.dumps(row), flush=True)
    short, long = rows
    return {"method": args.method, "rows": rows,
            "steps_ratio": round(long["steps_per_s"] / short["steps_per_s"], 3),
            "targets": {"peak_rss_mb": 4096, "steps_ratio": 0.9}}


if __name__ == "__main__":
    main()
