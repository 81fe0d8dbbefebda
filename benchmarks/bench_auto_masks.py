"""Automatic tool masks (`surgsplat import --auto-tool-masks`) on clips with true tool masks.

    python benchmarks/bench_auto_masks.py [--data PATH] [--out FILE] [--overlays DIR]
                                          [--phantoms DIR...] [--tool-free DIR]
                                          [--train-iters N --seeds S --train-on CLIP...
                                           --work DIR --threads T]

CholecSeg8k: the clip's frames that have labels are split in two consecutive halves: the first
half (frames 561-596 of the shared sample) is where the segmenter's parameters were chosen, the
second half (597-632) is held out and only scored. Tool = classes 31 (grasper) and 32
(L-hook). IoU, precision and recall of the tool class are pooled over the pixels of each split
inside the field of view (label 50 = border is outside); the IoU of every frame (inside the
field of view), each split's lowest, and the segmenter's per-frame confidence are reported too.
Frames are segmented as one sequence, as the importer does, so the temporal window sees each
frame's neighbours; seconds per frame are those of that whole pass at the clip's size.

Clips the segmenter was not tuned on (`unseen_clips`): surgsplat phantoms (a grey metal shaft
and jaw on textured tissue; true masks in masks/), by default the full standard phantom, the
high-variation light, and the cutting motion seen by a moving camera with another seed
(generated into --work unless given as NAME=DIR), scored the same way over every frame; and the
tool-free left frame of the SCARED sample (`tool_free`), where every marked pixel is a false
alarm: its share of the field of view.

Tool masks from clicks (`surgsplat import --tool-prompts`, section `prompted`): every clip
above with tools, and the drawn hard cases of `hard_tool_clips` (dark on dark, white on pale, a
textured metal grasper filling a third of the view), segmented with 0 clicks (the automatic
segmenter), 1 and 3 clicks per tool. A script places the clicks from the labels
(`label_clicks`): 1 click = on the frame where the tools are largest, one click on each tool
(each connected part of the labels of at least 0.2 % of the frame) at its point farthest from
its boundary; 3 clicks = the same on the frame where the tools are largest in each third of the
clip; "1 + a tissue click" adds to the 1-click prompts one tissue click where a person checking
the preview would, at the centre of the largest false alarm (`corrected`). IoU is pooled over
all frames; seconds per frame are those of the whole pass (flow,
region model, graph cuts, edge snapping) at the clip's size.

With --train-iters, each clip of --train-on (cholecseg8k, phantom) is also trained three times:
without masks, with the automatic masks and with the true masks (the reference of perfect
masks). CholecSeg8k is imported at half size, without masks, with --auto-tool-masks and with
the labels; the first phantom is trained at its full size, as its own scene without masks/,
with the segmenter's masks written into masks/, and as it is. `deform3dgs` is trained for N iterations
on each (once per training seed 0..S-1; the mean is reported), and every run is scored on the
test frames against the true masks' scene, so that all are scored over the same, truly
tool-free pixels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import write_report  # noqa: E402

from hard_tool_clips import KINDS, hard_clip  # noqa: E402

from surgsplat.data.auto_tool_masks import AutoMaskConfig, auto_tool_masks  # noqa: E402
from surgsplat.data.fov_mask import estimate_fov  # noqa: E402
from surgsplat.data.frames_source import name_numbers  # noqa: E402
from surgsplat.data.layout import IMAGES_DIR, MASKS_DIR  # noqa: E402
from surgsplat.data.prompted_masks import (  # noqa: E402
    PromptConfig, ToolPrompt, farthest_inside, prompted_tool_masks, seed_mask)
from surgsplat.data.scene import load_scene, read_image, read_tool_mask  # noqa: E402
from surgsplat.errors import DataError  # noqa: E402
from surgsplat.eval.run_metrics import EvalOptions, evaluate_run  # noqa: E402
from surgsplat.train.run import load_trained_run  # noqa: E402

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "cholecseg8k-clip"
DEFAULT_TOOL_FREE = DEFAULT_DATA.parent / "scared-stereo-sample" / "left"
TOOL_LABELS = (31, 32)
BORDER_LABEL = 50
PHANTOMS = {"phantom": ("--preset", "full"),
            "phantom-hivar": ("--preset", "full", "--lighting", "hivar"),
            "phantom-cutting-moving": ("--preset", "full", "--motion", "cutting", "--camera",
                                       "moving", "--seed", "1")}
"""`surgsplat phantom` options of the default unseen clips."""
SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]


@dataclass
class Clip:
    """Frames with their true tool masks."""

    name: str
    numbers: list[int]
    images: list[np.ndarray]
    """uint8 RGB [H, W, 3] per frame."""
    truths: list[np.ndarray]
    """bool [H, W] per frame, True = tool."""
    scored: list[np.ndarray]
    """bool [H, W] per frame: the pixels that are scored (inside the field of view)."""


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


def cholec_clip(data: Path) -> Clip:
    rows = labelled_frames(data)
    return Clip("cholecseg8k", [number for number, _, _ in rows],
                [read_image(frame) for _, frame, _ in rows],
                [read_tool_mask(labels, TOOL_LABELS) for _, _, labels in rows],
                [cv2.imread(str(labels), cv2.IMREAD_GRAYSCALE) != BORDER_LABEL
                 for _, _, labels in rows])


def phantom_clip(name: str, folder: Path) -> Clip:
    """A surgsplat phantom's frames and masks/ (255 = tool); every pixel is scored."""
    frames = sorted((folder / IMAGES_DIR).glob("*.png"))
    if not frames or not (folder / MASKS_DIR).is_dir():
        raise DataError(folder, "expected a surgsplat phantom with images/ and masks/")
    images = [read_image(frame) for frame in frames]
    return Clip(name, list(range(len(frames))), images,
                [read_tool_mask(folder / MASKS_DIR / frame.name) for frame in frames],
                [np.ones(image.shape[:2], bool) for image in images])


def tool_free_clip(folder: Path) -> Clip:
    """The PNG frames in `folder`, none of which shows a tool."""
    frames = sorted(folder.glob("*.png"))
    if not frames:
        raise DataError(folder, "expected PNG frames without tools")
    images = [read_image(frame) for frame in frames]
    fov = estimate_fov(images).inside
    return Clip(f"tool-free {folder.parent.name}", list(range(len(frames))), images,
                [np.zeros(image.shape[:2], bool) for image in images], [fov] * len(images))


def counts(predicted: np.ndarray, truth: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """[true positives, false positives, false negatives, pixels] of the tool over `inside`."""
    p, t = predicted & inside, truth & inside
    return np.array([(p & t).sum(), (p & ~t).sum(), (~p & t).sum(), inside.sum()],
                    dtype=np.int64)


def scores(tally: np.ndarray) -> dict:
    """IoU, precision, recall and false alarms over the scored pixels of a tally of `counts`;
    IoU is 1 where neither the truth nor the answer has a tool pixel (both empty agree)."""
    tp, fp, fn, pixels = (int(v) for v in tally)
    return {"iou": tp / (tp + fp + fn) if tp + fp + fn else 1.0, "precision": tp / max(tp + fp, 1),
            "recall": tp / max(tp + fn, 1), "tool_pixels": tp + fn,
            "false_alarm_share": fp / max(pixels, 1)}


def overlay(image: np.ndarray, predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """BGR picture: green = found, red = missed, blue = false alarm."""
    picture = image[..., ::-1].copy()
    for where, colour in ((predicted & truth, (0, 200, 0)), (~predicted & truth, (0, 0, 255)),
                          (predicted & ~truth, (255, 80, 0))):
        picture[where] = (0.45 * picture[where] + 0.55 * np.array(colour)).astype(np.uint8)
    return picture


def score_clip(clip: Clip, splits: dict[str, range], config: AutoMaskConfig,
               overlays: Path | None) -> tuple[dict, list[np.ndarray]]:
    """Segment the clip as one sequence (as the importer does) and score each split: pooled
    scores, the lowest frame IoU, every frame's IoU and confidence, and seconds per frame.
    Also returns the masks (bool [H, W] per frame)."""
    fov = estimate_fov(clip.images).inside
    started = time.perf_counter()
    results = list(auto_tool_masks(clip.images, fov, config))
    seconds = (time.perf_counter() - started) / len(clip.images)
    report: dict = {"size": [clip.images[0].shape[1], clip.images[0].shape[0]],
                    "splits": {name: [clip.numbers[positions[0]], clip.numbers[positions[-1]]]
                               for name, positions in splits.items()}}
    per_frame = []
    for split, positions in splits.items():
        tally = np.zeros(4, np.int64)
        for position in positions:
            frame_tally = counts(results[position].mask, clip.truths[position],
                                 clip.scored[position])
            tally += frame_tally
            per_frame.append({"frame": clip.numbers[position], "split": split,
                              "iou": scores(frame_tally)["iou"],
                              "confidence": results[position].confidence})
            if overlays is not None and position % 6 == 0:
                folder = overlays / clip.name.replace(" ", "-")
                folder.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(folder / f"frame_{clip.numbers[position]}_{split}.png"),
                            overlay(clip.images[position], results[position].mask,
                                    clip.truths[position]))
        report[split] = {**scores(tally), "frame_iou_min": min(
            row["iou"] for row in per_frame if row["split"] == split)}
    return report | {"per_frame": per_frame, "seconds_per_frame": seconds}, \
        [result.mask for result in results]


def label_clicks(truths: list[np.ndarray], clicks: int) -> list[ToolPrompt]:
    """The prompts a script places from the labels (bool [H, W] per frame): `clicks` (1 or 3)
    frames, each the frame where the tools are largest in its share of the clip, with one
    click per tool (connected part of at least 0.2 % of the frame) at its point farthest from
    its boundary."""
    areas = [int(truth.sum()) for truth in truths]
    bounds = np.linspace(0, len(truths), clicks + 1).round().astype(int)
    prompts = []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        frame = int(start) + int(np.argmax(areas[start:stop]))
        if areas[frame] == 0:
            continue
        count, labels, stats, _ = cv2.connectedComponentsWithStats(
            truths[frame].astype(np.uint8), connectivity=8)
        least = 0.002 * truths[frame].size
        points = tuple(farthest_inside(labels == part) for part in range(1, count)
                       if stats[part, cv2.CC_STAT_AREA] >= least)
        if points:
            prompts.append(ToolPrompt(frame, points))
    return prompts


def score_prompted(clip: Clip, prompts: list[ToolPrompt]) -> tuple[dict, list[np.ndarray]]:
    """IoU (pooled over the clip's frames) of the masks from `prompts`, the lowest frame IoU,
    the prompts, and seconds per frame of the whole pass; and the masks."""
    size = clip.images[0].shape[:2]
    radius = PromptConfig().click_radius
    seeds = [(prompt.frame, seed_mask(prompt, "tool", size, radius),
              seed_mask(prompt, "tissue", size, radius)) for prompt in prompts]
    fov = estimate_fov(clip.images).inside
    started = time.perf_counter()
    results = prompted_tool_masks(clip.images, fov, seeds)
    masks = [result.at_frame_size(image, fov, PromptConfig())
             for result, image in zip(results, clip.images)]
    seconds = (time.perf_counter() - started) / len(clip.images)
    tallies = [counts(mask, truth, scored)
               for mask, truth, scored in zip(masks, clip.truths, clip.scored)]
    return {**scores(sum(tallies)),
            "frame_iou_min": min(scores(tally)["iou"] for tally in tallies),
            "prompts": [prompt.describe() for prompt in prompts],
            "seconds_per_frame": seconds}, masks


def corrected(prompts: list[ToolPrompt], masks: list[np.ndarray], clip: Clip
              ) -> list[ToolPrompt]:
    """`prompts` with one tissue click added where a person looking at the preview would: on
    the frame with the largest false alarm, at the point of it farthest from its boundary (on
    that frame's prompt, or a new one). Unchanged when there is no false alarm."""
    false_alarms = [mask & ~truth & scored
                    for mask, truth, scored in zip(masks, clip.truths, clip.scored)]
    frame = int(np.argmax([wrong.sum() for wrong in false_alarms]))
    if not false_alarms[frame].any():
        return prompts
    point = farthest_inside(false_alarms[frame])
    others = [prompt for prompt in prompts if prompt.frame != frame]
    same = [prompt for prompt in prompts if prompt.frame == frame]
    tool = same[0].tool if same else ()
    if not tool:  # a prompt needs a tool click: the tool's own, as label_clicks places it
        count, labels = cv2.connectedComponents(clip.truths[frame].astype(np.uint8))
        if count < 2:
            return prompts
        largest = 1 + int(np.argmax(np.bincount(labels.ravel())[1:]))
        tool = (farthest_inside(labels == largest),)
    tissue = (same[0].tissue if same else ()) + (point,)
    return sorted(others + [ToolPrompt(frame, tool, tissue)], key=lambda prompt: prompt.frame)


def prompted_rows(clips: list[Clip]) -> dict:
    """Per clip: IoU with 0 clicks (the automatic segmenter), 1 and 3 clicks per tool, and 1
    click per tool plus one tissue click where the 1-click masks are most wrong."""
    rows = {}
    for clip in clips:
        fov = estimate_fov(clip.images).inside
        automatic = list(auto_tool_masks(clip.images, fov))
        tally = sum(counts(result.mask, truth, scored)
                    for result, truth, scored in zip(automatic, clip.truths, clip.scored))
        row = {"frames": len(clip.images), "size": [clip.images[0].shape[1],
                                                    clip.images[0].shape[0]],
               "clicks_0": scores(tally)}
        row["clicks_1"], masks = score_prompted(clip, label_clicks(clip.truths, 1))
        row["clicks_3"], _ = score_prompted(clip, label_clicks(clip.truths, 3))
        row["clicks_1_corrected"], _ = score_prompted(
            clip, corrected(label_clicks(clip.truths, 1), masks, clip))
        rows[clip.name] = row
        print(f"{clip.name}: IoU with 0 / 1 / 3 / 1 + a tissue click "
              + " / ".join(f"{row[key]['iou']:.3f}" for key in PROMPTED_KEYS)
              + f", {1000 * row['clicks_1']['seconds_per_frame']:.0f} ms per frame")
    return rows


PROMPTED_KEYS = ("clicks_0", "clicks_1", "clicks_3", "clicks_1_corrected")
"""The rows of a clip in the report's `prompted` section."""


def drawn_clip(kind: str) -> Clip:
    """A hard case of hard_tool_clips; every pixel is scored."""
    images, truths = hard_clip(kind)
    return Clip(kind, list(range(len(images))), images, truths,
                [np.ones(image.shape[:2], bool) for image in images])


def trained_rows(scenes: dict[str, Path], truth: Path, iterations: int, seeds: int,
                 work: Path) -> dict:
    """deform3dgs trained on each scene (seeds 0..seeds-1), scored on the test frames of the
    `truth` scene (same frames, true masks): psnr_tissue and ssim per seed and their means."""
    labelled = load_scene(truth)
    rows = {}
    for name, scene in scenes.items():
        per_seed = []
        for seed in range(seeds):
            run_dir = work / f"run-{name}-seed{seed}"
            subprocess.run(["rm", "-rf", str(run_dir)], check=True)
            subprocess.run([*SURGSPLAT, "train", "--method", "deform3dgs", "--data", str(scene),
                            "--out", str(run_dir), "--iters", str(iterations),
                            "--set", f"train.seed={seed}"],
                           check=True, stdout=subprocess.DEVNULL)
            # `surgsplat eval --data` refuses a scene of other content (the masks differ): the
            # run is scored here on the true scene's frames, which are the same images.
            run = dataclasses.replace(load_trained_run(run_dir), scene=labelled)
            metrics = evaluate_run(run, EvalOptions(geometry=False))
            per_seed.append({key: metrics[key] for key in ("psnr_tissue", "ssim")})
        rows[name] = {key: float(np.mean([row[key] for row in per_seed]))
                      for key in ("psnr_tissue", "ssim")}
        rows[name]["per_seed"] = per_seed
    return rows


CHOLEC_IMPORTS = {"unmasked": (), "auto_masks": ("--auto-tool-masks",),
                  "prompted_1_click": ("--tool-prompts", "{prompts}"),
                  "labels": ("--masks", "{data}", "--mask-pattern", "*_endo_watershed_mask.png",
                             "--tool-labels", "31,32")}
"""Import options of the CholecSeg8k scenes of the training comparison; every run is scored
against "labels", which is also trained on as the reference of perfect masks. The prompts are
label_clicks' 1 click per tool."""


def scene_mask_iou(scene: Path, truth: Path) -> float:
    """Tool IoU of `scene`'s masks against `truth`'s (same frames), pooled inside the view."""
    tally = np.zeros(4, np.int64)
    for frame, true_frame in zip(load_scene(scene).frames, load_scene(truth).frames):
        tally += counts(frame.tool.numpy(), true_frame.tool.numpy(), true_frame.fov.numpy())
    return scores(tally)["iou"]


def cholec_training(data: Path, iterations: int, seeds: int, work: Path) -> dict:
    """The training comparison on the CholecSeg8k clip, imported at half size; then the
    automatic masks refined by the first seed's run on them (`surgsplat refine-masks`) and
    trained on again. Each scene's mask IoU against the labels is reported beside its row."""
    rows_of_labels = labelled_frames(data)
    frame_count = len(rows_of_labels)
    prompts = work / "prompts-1-click.json"
    truths = [read_tool_mask(labels, TOOL_LABELS) for _, _, labels in rows_of_labels]
    prompts.write_text(json.dumps([prompt.describe() for prompt in label_clicks(truths, 1)]))
    scenes = {}
    for name, options in CHOLEC_IMPORTS.items():
        scenes[name] = work / f"scene-{name}"
        subprocess.run(["rm", "-rf", str(scenes[name])], check=True)
        subprocess.run([*SURGSPLAT, "import", str(data), "--pattern", "*_endo.png",
                        "--end", str(frame_count), "--scale", "0.5", "--out", str(scenes[name]),
                        *(option.format(data=data, prompts=prompts) for option in options)],
                       check=True, stdout=subprocess.DEVNULL)
    rows = trained_rows(scenes, scenes["labels"], iterations, seeds, work)
    scenes["auto_masks_refined"] = work / "scene-auto_masks_refined"
    subprocess.run(["rm", "-rf", str(scenes["auto_masks_refined"])], check=True)
    subprocess.run([*SURGSPLAT, "refine-masks", str(work / "run-auto_masks-seed0"), "--out",
                    str(scenes["auto_masks_refined"])], check=True, stdout=subprocess.DEVNULL)
    rows |= trained_rows({"auto_masks_refined": scenes["auto_masks_refined"]}, scenes["labels"],
                         iterations, seeds, work)
    for name, scene in scenes.items():
        if name != "unmasked":
            rows[name]["mask_iou"] = scene_mask_iou(scene, scenes["labels"])
    return {"method": "deform3dgs", "iterations": iterations, "seeds": seeds,
            "frames": frame_count, "scale": 0.5, "scored_against": "labelled masks",
            "rows": rows}


def phantom_training(phantom: Path, masks: list[np.ndarray], iterations: int, seeds: int,
                     work: Path) -> dict:
    """The training comparison on a phantom: its scene without masks/, with `masks` (the
    segmenter's, bool [H, W] per frame) as masks/, and as it is."""
    scenes = {"unmasked": work / "phantom-unmasked", "auto_masks": work / "phantom-auto_masks",
              "labels": phantom}
    frames = sorted((phantom / IMAGES_DIR).glob("*.png"))
    for name in ("unmasked", "auto_masks"):
        subprocess.run(["rm", "-rf", str(scenes[name])], check=True)
        scenes[name].mkdir(parents=True)
        for entry in phantom.iterdir():
            if entry.name != MASKS_DIR:
                (scenes[name] / entry.name).symlink_to(entry.resolve())
    (scenes["auto_masks"] / MASKS_DIR).mkdir()
    for frame, mask in zip(frames, masks):
        cv2.imwrite(str(scenes["auto_masks"] / MASKS_DIR / frame.name),
                    mask.astype(np.uint8) * 255)
    return {"method": "deform3dgs", "iterations": iterations, "seeds": seeds,
            "frames": len(frames), "scale": 1.0, "scored_against": "true masks",
            "rows": trained_rows(scenes, phantom, iterations, seeds, work / "phantom-runs")}


def phantom_folders(given: list[str], work: Path) -> dict[str, Path]:
    """NAME=DIR pairs as given, or the default phantoms generated into `work`."""
    if given:
        if not all("=" in pair for pair in given):
            raise SystemExit(f"--phantoms: expected NAME=DIR pairs, got {' '.join(given)}")
        return {name: Path(folder) for name, folder in (pair.split("=", 1) for pair in given)}
    folders = {}
    for name, options in PHANTOMS.items():
        folders[name] = work / name
        if not (folders[name] / IMAGES_DIR).is_dir():
            subprocess.run(["rm", "-rf", str(folders[name])], check=True)
            subprocess.run([*SURGSPLAT, "phantom", "--out", str(folders[name]), *options],
                           check=True, stdout=subprocess.DEVNULL)
    return folders


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    parser.add_argument("--out", type=Path, default=None, help="result file (default "
                        "benchmarks/results/bench_auto_masks-<cpu>-<best ISA>.json)")
    parser.add_argument("--overlays", type=Path, default=None,
                        help="write every 6th frame of each clip with its mask overlaid here")
    parser.add_argument("--phantoms", nargs="*", default=[], metavar="NAME=DIR",
                        help="phantom folders to score (default: generate the three of "
                             "PHANTOMS into --work)")
    parser.add_argument("--tool-free", type=Path, default=DEFAULT_TOOL_FREE,
                        help="folder of frames without tools (skipped when absent)")
    parser.add_argument("--set", nargs="*", default=[], metavar="NAME=VALUE",
                        help="override AutoMaskConfig fields (for tuning on the tuning split)")
    parser.add_argument("--train-iters", type=int, default=None,
                        help="also compare deform3dgs trained without and with auto masks")
    parser.add_argument("--train-on", nargs="*", default=["cholecseg8k"],
                        choices=["cholecseg8k", "phantom"],
                        help="clips of the training comparison")
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
    args.work.mkdir(parents=True, exist_ok=True)
    cholec = cholec_clip(args.data)
    half = len(cholec.images) // 2
    report, _ = score_clip(cholec, {"tuning": range(half),
                                    "held_out": range(half, len(cholec.images))},
                           config, args.overlays)
    result = {"data": str(args.data), **report, "config": asdict(config), "unseen_clips": {}}
    phantoms, phantom_masks = phantom_folders(args.phantoms, args.work), {}
    for name, folder in phantoms.items():
        clip = phantom_clip(name, folder)
        report, phantom_masks[name] = score_clip(clip, {"all": range(len(clip.images))},
                                                 config, args.overlays)
        result["unseen_clips"][name] = {"data": str(folder), **report}
    result["prompted"] = prompted_rows([cholec] + [phantom_clip(name, folder) for name, folder
                                                    in phantoms.items()]
                                       + [drawn_clip(kind) for kind in KINDS])
    if args.tool_free.is_dir():
        clip = tool_free_clip(args.tool_free)
        report, _ = score_clip(clip, {"all": range(len(clip.images))}, config, args.overlays)
        result["tool_free"] = {"data": str(args.tool_free), **report}
    if args.train_iters:
        result["training"] = {}
        if "cholecseg8k" in args.train_on:
            result["training"]["cholecseg8k"] = cholec_training(
                args.data, args.train_iters, args.seeds, args.work)
        if "phantom" in args.train_on:
            name = next(iter(phantoms))
            result["training"][name] = phantom_training(
                phantoms[name], phantom_masks[name], args.train_iters, args.seeds, args.work)
        for clip_name, training in result["training"].items():
            for name, row in training["rows"].items():
                print(f"{clip_name} deform3dgs {name}: psnr_tissue {row['psnr_tissue']:.2f} dB, "
                      f"ssim {row['ssim']:.4f}")
    for split in ("tuning", "held_out"):
        row = result[split]
        print(f"{split:9s} frames {result['splits'][split]}: IoU {row['iou']:.3f}  "
              f"precision {row['precision']:.3f}  recall {row['recall']:.3f}  "
              f"lowest frame IoU {row['frame_iou_min']:.3f}")
    for name, clip_report in result["unseen_clips"].items():
        row = clip_report["all"]
        print(f"{name}: IoU {row['iou']:.3f}  precision {row['precision']:.3f}  "
              f"recall {row['recall']:.3f}  lowest frame IoU {row['frame_iou_min']:.3f}")
    if "tool_free" in result:
        print(f"tool-free frames: false alarms on "
              f"{100 * result['tool_free']['all']['false_alarm_share']:.2f} % of the field of view")
    print(f"{1000 * result['seconds_per_frame']:.0f} ms per frame")
    if not args.set:
        print(f"results: {write_report('bench_auto_masks', result, args.out)}")


if __name__ == "__main__":
    main()
