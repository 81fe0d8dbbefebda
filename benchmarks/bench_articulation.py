"""Articulation and simulation-export benchmark on the full "pulling" phantom.

The full phantom is generated (once, in --work), a method with a tool field is trained on it
(`surgsplat train`, once), then, each in its own process and timed: `surgsplat articulate` (the
shaft + two revolute jaws, RUN/articulation.json) and `surgsplat export RUN --sim DIR --frame F`.
The articulation is scored against gt/tool_kinematics.json as `surgsplat eval` scores it
(eval/articulation_metrics.py: all frames whose tool mask covers >= 0.5% of the image), and the
exported scene is run: MuJoCo sweeps both jaws through their range for 1,000 steps (commanded
vs achieved angles), drops a probe sphere on the tissue (its resting distance to the tissue
mesh), and PyBullet drives the URDF's jaws to their limits.

    python benchmarks/bench_articulation.py --work /tmp/articulation [--iters 400]
                                            [--method physiosplat] [--frame 30] [--json]

Targets (issue 16): hinge_axis_error_deg <= 5, jaw_angle_rmse_deg <= 3, export of one frame
<= 30 s.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import full_pulling_phantom, write_report  # noqa: E402

from surgsplat.data.scene import load_scene  # noqa: E402
from surgsplat.eval.articulation_metrics import (MIN_TOOL_FRACTION,  # noqa: E402
                                                 articulation_metrics, read_tool_kinematics)
from surgsplat.export.articulation import read_articulation  # noqa: E402
from surgsplat.export.sim_check import jaw_sweep, probe_drop, urdf_sweep  # noqa: E402
from surgsplat.train.trainer import CHECKPOINT  # noqa: E402

SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
TARGETS = {"hinge_axis_error_deg": 5.0, "jaw_angle_rmse_deg": 3.0, "export_seconds": 30.0}


def timed(*args: str) -> float:
    """Run `surgsplat *args`; its wall seconds (exit on failure with its error)."""
    started = time.perf_counter()
    done = subprocess.run([*SURGSPLAT, *args], capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"surgsplat {' '.join(args)} failed:\n{done.stderr}")
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, required=True, help="folder for phantom and run")
    parser.add_argument("--iters", type=int, default=400)
    parser.add_argument("--method", default="physiosplat")
    parser.add_argument("--frame", type=int, default=30, help="frame exported for simulation")
    parser.add_argument("--json", action="store_true", help="write benchmarks/results/...")
    args = parser.parse_args()
    scene_dir, run = args.work / "pulling", args.work / f"run_{args.method}"
    full_pulling_phantom(scene_dir)
    train_seconds = None
    if not (run / CHECKPOINT).is_file():
        train_seconds = timed("train", "--method", args.method, "--data", str(scene_dir),
                              "--out", str(run), "--iters", str(args.iters))
    articulate_seconds = timed("articulate", str(run))
    sim = args.work / f"sim_{args.frame:03d}"
    export_seconds = timed("export", str(run), "--sim", str(sim), "--frame", str(args.frame))

    scene = load_scene(scene_dir)
    frames = [f.index for f in scene.frames if float(f.tool.float().mean()) >= MIN_TOOL_FRACTION]
    metrics = articulation_metrics(read_articulation(run), read_tool_kinematics(scene_dir),
                                   frames, [f.index for f in scene.test_frames])
    sweep = jaw_sweep(sim / "scene.xml", steps=1000)
    probe = probe_drop(sim / "scene.xml", sim / "tissue.obj")
    pybullet = urdf_sweep(sim / "tool.urdf")
    result = {"method": args.method, "iters": args.iters, "frame": args.frame,
              "train_seconds": train_seconds, "articulate_seconds": articulate_seconds,
              "export_seconds": export_seconds, **metrics, "jaw_sweep": sweep, "probe": probe,
              "pybullet": pybullet, "targets": TARGETS}
    print(json.dumps({k: v for k, v in result.items() if k != "jaw_sweep"}, indent=1))
    print(json.dumps(sweep["trace"]))
    if args.json:
        print(f"results: {write_report('bench_articulation', result, None)}")


if __name__ == "__main__":
    main()
