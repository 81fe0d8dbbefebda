"""Automatic tool masks (`surgsplat import --auto-tool-masks`) against CholecSeg8k labels.

    python benchmarks/bench_auto_masks.py [--data PATH] [--out FILE] [--overlays DIR]
                                          [--train-iters N --seeds S --work DIR]

The clip's frames that have labels are split in two consecutive halves: the first half
(frames 561-596 of the shared sample) is where the segmenter's parameters were chosen, the
second half (597-632) is held out and only scored. Tool = classes 31 (grasper) and 32
(L-hook). IoU, precision and recall of the tool class are pooled over the pixels of each split
inside the field of view (label 50 = border is outside); the IoU of every frame (inside the
field of view), each split's lowest, and the segmenter's per-frame confidence are reported too.
Frames are segmented as one sequence, as the importer does, so the temporal window sees each
frame's neighbours; seconds per frame are those of that whole pass at the clip's size.

With --train-iters, the labelled frames are also imported three times at half size (no masks,
--auto-tool-masks, and the labels as masks), `deform3dgs` is trained for N iterations on each
(once per training seed 0..S-1; the mean is reported; the labels' row is the reference of
perfect masks), and every run is scored on the test frames against the labelled scene, so that
all are scored over the same, truly tool-free pixels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import time
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import write_report  # noqa: E402

from surgsplat.data.auto_tool_masks import AutoMaskConfig, auto_tool_masks  # noqa: E402
from surgsplat.data.fov_mask import estimate_fov  # noqa: E402
from surgsplat.data.frames_source import name_numbers  # noqa: E402
from surgsplat.data.scene import load_scene, read_image  # noqa: E402
from surgsplat.data.tool_masks import read_tool_labels  # noqa: E402
from surgsplat.errors import DataError  # noqa: E402
from surgsplat.eval.run_metrics import EvalOptions, evaluate_run  # noqa: E402
from surgsplat.train.run import load_trained_run  # noqa: E402

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "cholecseg8k-clip"
TOOL_LABELS = (31, 32)
BORDER_LABEL = 50


def labelled_frames(data: Path) -> list[tuple[int, Path, Path]]:
    """(frame number, frame file, label file) of the frames that have a watershed mask."""
    rows = []
    for frame in sorted(data.glob("frame_*_endo.png"), key=name_numbers):
        labels = frame.with_name(frame.stem + "_watershed_mask.png")
        if labels.is_file():
            rows.append((name_numbers(frame)[0], frame, labels))
    if len(rows) < 4:
        raise DataError(data, "expected CholecSeg8k frames frame_N_endo.png with "
                              "frame_N_endo_watershed_mask.png")
    return rows


def counts(predicted: np.ndarray, truth: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """[true positives, false positives, false negatives] of the tool over `inside` pixels."""
    p, t = predicted & inside, truth & inside
    return np.array([(p & t).sum(), (p & ~t).sum(), (~p & t).sum()], dtype=np.int64)


def scores(tally: np.ndarray) -> dict:
    tp, fp, fn = (int(v) for v in tally)
    return {"iou": tp / max(tp + fp + fn, 1), "precision": tp / max(tp + fp, 1),
            "recall": tp / max(tp + fn, 1), "tool_pixels": tp + fn}


def overlay(image: np.ndarray, predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """BGR picture: green = found, red = missed, blue = false alarm."""
    picture = image[..., ::-1].copy()
    for where, colour in ((predicted & truth, (0, 200, 0)), (~predicted & truth, (0, 0, 255)),
                          (predicted & ~truth, (255, 80, 0))):
        picture[where] = (0.45 * picture[where] + 0.55 * np.array(colour)).astype(np.uint8)
    return picture


def run(data: Path, config: AutoMaskConfig, overlays: Path | None) -> dict:
    rows = labelled_frames(data)
    half = len(rows) // 2
    images = [read_image(frame) for _, frame, _ in rows]
    truths = [read_tool_labels(labels, TOOL_LABELS) for _, _, labels in rows]
    borders = [cv2.imread(str(labels), cv2.IMREAD_GRAYSCALE) == BORDER_LABEL
               for _, _, labels in rows]
    fov = estimate_fov(images).inside
    started = time.perf_counter()
    results = list(auto_tool_masks(images, fov, config))
    seconds = (time.perf_counter() - started) / len(images)
    tallies = {"tuning": np.zeros(3, np.int64), "held_out": np.zeros(3, np.int64)}
    per_frame = []
    for position, (result, truth, border) in enumerate(zip(results, truths, borders)):
        split = "tuning" if position < half else "held_out"
        tally = counts(result.mask, truth, ~border)
        tallies[split] += tally
        per_frame.append({"frame": rows[position][0], "split": split,
                          "iou": scores(tally)["iou"], "confidence": result.confidence})
        if overlays is not None and position % 6 == 0:
            overlays.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(overlays / f"frame_{rows[position][0]}_{split}.png"),
                        overlay(images[position], result.mask, truth))
    numbers = [number for number, _, _ in rows]
    return {
        "data": str(data), "size": [images[0].shape[1], images[0].shape[0]],
        "splits": {"tuning": [numbers[0], numbers[half - 1]],
                   "held_out": [numbers[half], numbers[-1]]},
        "config": asdict(config),
        **{split: {**scores(tally), "frame_iou_min": min(
            row["iou"] for row in per_frame if row["split"] == split)}
           for split, tally in tallies.items()},
        "per_frame": per_frame,
        "seconds_per_frame": seconds,
    }


SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
TRAINING_SCENES = {"unmasked": (), "auto_masks": ("--auto-tool-masks",),
                   "labels": ("--masks", "{data}", "--mask-pattern", "*_endo_watershed_mask.png",
                              "--tool-labels", "31,32")}
"""Import options of the scenes of the training comparison; every run is scored against
"labels", which is also trained on as the reference of perfect masks."""


def train_comparison(data: Path, frame_count: int, iterations: int, seeds: int,
                     work: Path) -> dict:
    """Test-frame metrics of deform3dgs trained without masks, with automatic masks and with the
    labels as masks (each with training seeds 0..seeds-1), all scored against the labelled
    scene."""
    scenes = {}
    for name, options in TRAINING_SCENES.items():
        scenes[name] = work / f"scene-{name}"
        subprocess.run(["rm", "-rf", str(scenes[name])], check=True)
        subprocess.run([*SURGSPLAT, "import", str(data), "--pattern", "*_endo.png",
                        "--end", str(frame_count), "--scale", "0.5", "--out", str(scenes[name]),
                        *(option.format(data=data) for option in options)],
                       check=True, stdout=subprocess.DEVNULL)
    labelled = load_scene(scenes["labels"])
    rows = {}
    for name in TRAINING_SCENES:
        per_seed = []
        for seed in range(seeds):
            run_dir = work / f"run-{name}-seed{seed}"
            subprocess.run(["rm", "-rf", str(run_dir)], check=True)
            subprocess.run([*SURGSPLAT, "train", "--method", "deform3dgs", "--data",
                            str(scenes[name]), "--out", str(run_dir), "--iters", str(iterations),
                            "--set", f"train.seed={seed}"],
                           check=True, stdout=subprocess.DEVNULL)
            # `surgsplat eval --data` refuses a scene of other content (the masks differ): the
            # run is scored here on the labelled scene's frames, which are the same images.
            run = dataclasses.replace(load_trained_run(run_dir), scene=labelled)
            metrics = evaluate_run(run, EvalOptions(geometry=False))
            per_seed.append({key: metrics[key] for key in ("psnr_tissue", "ssim")})
        rows[name] = {key: float(np.mean([row[key] for row in per_seed]))
                      for key in ("psnr_tissue", "ssim")}
        rows[name]["per_seed"] = per_seed
    return {"method": "deform3dgs", "iterations": iterations, "seeds": seeds,
            "frames": frame_count, "scale": 0.5, "scored_against": "labelled masks",
            "rows": rows}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=None, help="result file (default "
                        "benchmarks/results/bench_auto_masks-<cpu>-<best ISA>.json)")
    parser.add_argument("--overlays", type=Path, default=None,
                        help="write every 6th frame with its mask overlaid here")
    parser.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE",
                        help="override AutoMaskConfig fields (for tuning on the tuning split)")
    parser.add_argument("--train-iters", type=int, default=None,
                        help="also compare deform3dgs trained without and with auto masks")
    parser.add_argument("--seeds", type=int, default=1,
                        help="training seeds per case; the table shows their mean")
    parser.add_argument("--threads", type=int, default=None,
                        help="threads of every surgsplat process (default: one per core)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/surgsplat-bench-auto-masks"))
    args = parser.parse_args()
    if args.threads is not None:
        SURGSPLAT.extend(["--threads", str(args.threads)])
    config = AutoMaskConfig()
    for assignment in args.set:
        name, value = assignment.split("=")
        *path, leaf = name.split(".")  # e.g. motion.preset
        target = config
        for part in path:
            target = getattr(target, part)
        setattr(target, leaf, type(getattr(target, leaf))(value))
    result = run(args.data, config, args.overlays)
    if args.train_iters:
        args.work.mkdir(parents=True, exist_ok=True)
        frame_count = len(labelled_frames(args.data))
        result["training"] = train_comparison(args.data, frame_count, args.train_iters,
                                              args.seeds, args.work)
        for name, row in result["training"]["rows"].items():
            print(f"deform3dgs {name}: psnr_tissue {row['psnr_tissue']:.2f} dB, "
                  f"ssim {row['ssim']:.4f}")
    for split in ("tuning", "held_out"):
        row = result[split]
        print(f"{split:9s} frames {result['splits'][split]}: IoU {row['iou']:.3f}  "
              f"precision {row['precision']:.3f}  recall {row['recall']:.3f}  "
              f"lowest frame IoU {row['frame_iou_min']:.3f}")
    print(f"{1000 * result['seconds_per_frame']:.0f} ms per frame")
    if not args.set:
        print(f"results: {write_report('bench_auto_masks', result, args.out)}")

if __name__ == "__main__":
    main()
