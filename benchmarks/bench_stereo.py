"""Accuracy and speed of surgsplat's SGBM stereo step against structured-light ground truth.

    python benchmarks/bench_stereo.py [--json] [--data PATH] [--repeat N]

The data folder holds rectified `left/` and `right/` images, ground-truth disparity of the left
image in `disparity/*.tiff` (float32 px, 0 = no ground truth) and optionally `occlusion/*.png`
(255 = valid), paired by sorted name (the SCARED sample beside the repository by default).

Errors are pooled over the pixels of all pairs:
- sparse: over pixels valid in the ground truth AND estimated by SGBM; density is the share of
  ground-truth-valid pixels that SGBM estimated;
- filled: invalid SGBM pixels take the value of the nearest estimated pixel, so the error is
  over all ground-truth-valid pixels (density 100 %).
`bad3` is the share of those pixels with an absolute error above 3 px.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import tifffile
from rich.console import Console
from rich.table import Table

from surgsplat.data.layout import IMAGE_SUFFIXES, list_files
from surgsplat.data.scene import read_image
from surgsplat.data.stereo import StereoConfig, fill_invalid, stereo_disparity
from surgsplat.errors import DataError

DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "scared-stereo-sample"
BAD_PX = 3.0
"""Error threshold in pixels of the bad-pixel share."""


def read_ground_truth(disparity_path: Path, occlusion_path: Path | None) -> np.ndarray:
    """Ground-truth disparity float32 [H, W] in px with 0 where it is missing or occluded."""
    disparity = np.squeeze(tifffile.imread(disparity_path)).astype(np.float32)
    if disparity.ndim != 2:
        raise DataError(disparity_path, f"expected a [1, H, W] or [H, W] disparity, got "
                                        f"{disparity.shape}")
    disparity[~np.isfinite(disparity)] = 0.0
    if occlusion_path is not None:
        occlusion = cv2.imread(str(occlusion_path), cv2.IMREAD_GRAYSCALE)
        if occlusion is None or occlusion.shape != disparity.shape:
            raise DataError(occlusion_path, f"expected an 8-bit mask of shape {disparity.shape}")
        disparity[occlusion != 255] = 0.0
    return disparity


def error_stats(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float, int]:
    """(sum of |error|, count of |error| > BAD_PX, pixel count) over pixels where both are > 0."""
    both = (estimate > 0) & (truth > 0)
    error = np.abs(estimate[both] - truth[both])
    return float(error.sum()), int((error > BAD_PX).sum()), int(both.sum())


def run(data: Path, repeat: int) -> dict:
    folders = {name: data / name for name in ("left", "right", "disparity", "occlusion")}
    for name in ("left", "right", "disparity"):
        if not folders[name].is_dir():
            raise DataError(folders[name], "missing: expected left/, right/ and disparity/ folders")
    lefts = list_files(folders["left"], IMAGE_SUFFIXES)
    rights = list_files(folders["right"], IMAGE_SUFFIXES)
    truths = list_files(folders["disparity"], (".tif", ".tiff"))
    occlusions = (list_files(folders["occlusion"], (".png",)) if folders["occlusion"].is_dir()
                  else [None] * len(lefts))
    if not lefts or not len(lefts) == len(rights) == len(truths) == len(occlusions):
        raise DataError(data, f"needs equal, non-zero file counts: {len(lefts)} left, "
                              f"{len(rights)} right, {len(truths)} disparity, "
                              f"{len(occlusions)} occlusion")
    config = StereoConfig()
    sparse = np.zeros(3)  # [sum |error|, bad count, pixels]
    filled = np.zeros(3)
    truth_pixels = 0
    seconds = []
    for left_path, right_path, truth_path, occlusion_path in zip(lefts, rights, truths, occlusions):
        left, right = read_image(left_path), read_image(right_path)
        truth = read_ground_truth(truth_path, occlusion_path)
        for _ in range(repeat):
            start = time.perf_counter()
            estimate = stereo_disparity(left, right, config)
            seconds.append(time.perf_counter() - start)
        sparse += error_stats(estimate, truth)
        filled += error_stats(fill_invalid(estimate), truth)
        truth_pixels += int((truth > 0).sum())
    height, width = left.shape[:2]
    return {
        "data": str(data), "pairs": len(lefts), "size": [width, height],
        "config": asdict(config),
        "gt_valid_pixels": truth_pixels,
        "density": sparse[2] / truth_pixels,
        "mae_px": sparse[0] / sparse[2], "bad3_share": sparse[1] / sparse[2],
        "filled_mae_px": filled[0] / filled[2], "filled_bad3_share": filled[1] / filled[2],
        "seconds_per_pair": float(np.median(seconds)),
    }


def print_table(result: dict) -> None:
    table = Table(title=f"SGBM stereo on {result['pairs']} pair(s), "
                        f"{result['size'][0]} x {result['size'][1]} px")
    for column in ("pixels", "density", "MAE (px)", f"> {BAD_PX:g} px"):
        table.add_column(column, justify="right")
    table.add_row("valid in GT and SGBM", f"{100 * result['density']:.1f} %",
                  f"{result['mae_px']:.3f}", f"{100 * result['bad3_share']:.2f} %")
    table.add_row("all GT-valid, holes filled", "100.0 %", f"{result['filled_mae_px']:.3f}",
                  f"{100 * result['filled_bad3_share']:.2f} %")
    console = Console()
    console.print(table)
    console.print(f"{result['seconds_per_pair'] * 1000:.1f} ms per pair (median), mode "
                  f"{result['config']['mode']}, {result['config']['num_disparities']} disparities, "
                  f"block {result['config']['block_size']}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA,
                        help="folder with left/, right/, disparity/ (and occlusion/)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs per pair")
    args = parser.parse_args()
    result = run(args.data, max(args.repeat, 1))
    if args.json:
        print(json.dumps(result))
    else:
        print_table(result)


if __name__ == "__main__":
    main()
