"""The tool-free view of a real clip, to be looked at: the CholecSeg8k sample of ../shared/data
(a grasper in view) imported with its tool labels, trained with a preset that separates the tool
(`physiosplat` by default, its full schedule), and rendered without the tool.

Writes, under --work: the scene, the run, the run's tool-free videos (`surgsplat render
--tool-free`), PNGs of a few frames side by side (the frame, its tool mask outlined, the tool-free
render, and the `observed` channel: white, tissue some frame showed; black, filled or empty) and
`tool-free-cholecseg8k-<method>.mp4`, every frame so, each panel 320 px wide. With --images, the
PNGs and the video are also copied there (the README shows them).

    python benchmarks/real_tool_free.py --work /tmp/real-tool-free --images docs/images

The sample is never copied into the repository; only the PNGs are.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import surgsplat  # noqa: E402,F401  (first: it sets OpenMP's wait policy before torch loads)
from bench_methods import REAL_SCENES, SHARED_DATA, SURGSPLAT  # noqa: E402
from surgsplat.export.video import VideoWriter  # noqa: E402
from surgsplat.model.channels import OBSERVED  # noqa: E402
from surgsplat.model.component import FrameTime  # noqa: E402
from surgsplat.model.dynamic import render_frame  # noqa: E402
from surgsplat.train.run import load_trained_run  # noqa: E402

PANEL_WIDTH = 427
"""Each panel of a PNG is scaled to this width (half the clip's 854 px)."""
VIDEO_PANEL_WIDTH = 320
"""Each panel of the video is scaled to this width."""


def run(*args: str) -> None:
    """Run `surgsplat *args`, failing on a non-zero exit."""
    subprocess.run([*SURGSPLAT, *args], check=True)


def panels(trained, index: int, width: int) -> np.ndarray:
    """[H, 4 width, 3] uint8 RGB of frame `index` of the trained run: the frame, the frame with
    its tool mask outlined, the tool-free render, and the observed channel (grey)."""
    frame = trained.scene.frames[index]
    output = render_frame(trained.model, frame.camera,
                          FrameTime(frame.index, frame.time, tissue_only=True))
    image = (frame.image.numpy() * 255).round().astype(np.uint8)
    outlined = image.copy()
    contours, _ = cv2.findContours(frame.tool.numpy().astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    cv2.drawContours(outlined, contours, -1, (255, 255, 0), 2)
    tool_free = (output.rgb.clamp(0, 1).numpy() * 255).round().astype(np.uint8)
    observed = output.extras.get(OBSERVED)
    if observed is None:
        observed = output.alpha[..., None]
    grey = np.repeat((observed.clamp(0, 1).numpy() * 255).round().astype(np.uint8), 3, axis=2)
    height = 2 * round(image.shape[0] * width / image.shape[1] / 2)  # even, for the video
    return np.concatenate([cv2.resize(panel, (width, height), interpolation=cv2.INTER_AREA)
                           for panel in (image, outlined, tool_free, grey)], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--work", type=Path, required=True)
    parser.add_argument("--method", default="physiosplat")
    parser.add_argument("--shared-data", type=Path, default=SHARED_DATA)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--frames", type=int, nargs="+", default=None,
                        help="frame indices of the PNGs (default: three spread over the clip)")
    parser.add_argument("--images", type=Path, default=None,
                        help="also copy the PNGs into this folder")
    args = parser.parse_args()
    real = REAL_SCENES["cholecseg8k"]
    source = args.shared_data / real.folder
    scene, run_dir = args.work / "scene", args.work / f"run-{args.method}"
    if not (scene / "scene.json").is_file():
        run("import", str(source), "--out", str(scene),
            *(option.format(source=source) for option in real.import_options))
    threads = ("--threads", str(args.threads))
    if not (run_dir / "metrics.json").is_file():  # trained and evaluated before: kept
        run(*threads, "train", "--method", args.method, "--data", str(scene), "--out",
            str(run_dir))
        run(*threads, "eval", str(run_dir))
    shutil.rmtree(args.work / "videos", ignore_errors=True)
    run(*threads, "render", str(run_dir), "--tool-free", "--out", str(args.work / "videos"))
    trained = load_trained_run(run_dir)
    count = len(trained.scene.frames)
    written = [args.work / f"tool-free-cholecseg8k-{args.method}.mp4"]
    with VideoWriter(written[0], fps=10.0) as video:
        for index in range(count):
            video.add(panels(trained, index, VIDEO_PANEL_WIDTH))
    for index in args.frames or [count // 6, count // 2, 5 * count // 6]:
        written.append(args.work / f"tool-free-cholecseg8k-{args.method}-frame{index}.png")
        cv2.imwrite(str(written[-1]), cv2.cvtColor(panels(trained, index, PANEL_WIDTH),
                                                   cv2.COLOR_RGB2BGR))
    for path in written:
        if args.images is not None:
            shutil.copy(path, args.images / path.name)
        print(path)


if __name__ == "__main__":
    main()
