"""Speed of the outputs a user opens: PLY export of a 100k-Gaussian frame, viewer frames at
640x512, and the HTML report of a run.

    python benchmarks/bench_outputs.py --run RUN [--json]

RUN is a trained run, e.g. the full-phantom deform3dgs run of bench_methods.py
(/tmp/surgsplat-bench-methods/run-deform3dgs). Targets (issue 12): PLY of 100k Gaussians <= 2 s;
viewer >= 10 frames per second at 640x512 with ~50k Gaussians; report of a run <= 20 s. Results
go to benchmarks/results/bench_outputs-<cpu>-<best ISA>.json.
"""

from __future__ import annotations

import argparse
import datetime
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import cv2
import surgsplat  # noqa: F401  (before torch: sets surgsplat's OpenMP wait policy)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import results_path  # noqa: E402

from surgsplat.export.ply import write_gaussian_ply  # noqa: E402
from surgsplat.export.report import write_report  # noqa: E402
from surgsplat.export.viewer import view_image  # noqa: E402
from surgsplat.model.component import FrameTime  # noqa: E402
from surgsplat.render.native import system_info  # noqa: E402
from surgsplat.train.run import load_trained_run  # noqa: E402


def median_seconds(work, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        work()
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def ply_case(run, folder: Path) -> dict:
    """The run's Gaussians at frame 0 repeated to 100k, written as PLY."""
    with torch.no_grad():
        state = run.model.state_at(FrameTime(0, 0.0))
    repeat = -(-100_000 // state.means.shape[0])
    big = state.replace(**{name: getattr(state, name).repeat_interleave(repeat, 0)[:100_000]
                           for name in ("means", "scales", "quats", "opacities", "sh")})
    seconds = median_seconds(lambda: write_gaussian_ply(big, folder / "frame.ply"), 3)
    return {"ply_gaussians": 100_000, "ply_seconds": seconds,
            "ply_mb": (folder / "frame.ply").stat().st_size / 1e6}


def viewer_case(run) -> dict:
    """Frames as the viewer makes them (render, colour-map, JPEG) at 640x512 from the training
    camera, cycling through time."""
    camera = run.scene.frames[0].camera
    scale = 512 / camera.height
    K = camera.K.clone()
    K[:2] *= scale
    view = type(camera)(K=K, world_to_camera=camera.world_to_camera, width=640, height=512)
    count = len(run.scene.frames)
    state = {"index": 0}

    def frame():
        image = view_image(run, view, state["index"] % count, "rgb")
        cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])
        state["index"] += 1

    frame()
    seconds = median_seconds(frame, 20)
    return {"viewer_width": 640, "viewer_height": 512,
            "viewer_gaussians": run.model.gaussians.num_gaussians,
            "viewer_frame_seconds": seconds, "viewer_fps": 1.0 / seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--run", type=Path, required=True, help="a trained run folder")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args()
    run = load_trained_run(args.run)
    with tempfile.TemporaryDirectory() as folder:
        row = {**ply_case(run, Path(folder)), **viewer_case(run)}
        started = time.perf_counter()
        write_report([args.run], Path(folder) / "report.html")
        row["report_seconds"] = time.perf_counter() - started
    info = system_info()
    report = {"benchmark": "bench_outputs", "cpu": info["cpu"], "system": info,
              "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "run": str(args.run), "rows": [row]}
    out = args.out or results_path("bench_outputs", info)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2) if args.json else
          "\n".join(f"{key}: {value:.3f}" if isinstance(value, float) else f"{key}: {value}"
                    for key, value in row.items()))
    print(f"results: {out}")


if __name__ == "__main__":
    main()
