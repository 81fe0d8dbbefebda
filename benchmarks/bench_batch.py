"""Batch benchmark: the overhead of `surgsplat batch` on Ray over the same clips run one after
another in one process.

Both sides get the same CPUs (`--cpus`): Ray a local instance of that many CPUs with one clip's
tasks declaring them all, so clips run one at a time as in the sequential run, which runs every
stage of every clip (`run_clip_here`) in one Python process with that many threads; both write
the summary and the HTML report. Each side is a fresh subprocess, timed from start to exit (Python and torch start-up, Ray's start and
stop included); the clips are copies of the small phantom. Overhead share = (Ray wall -
sequential wall) / Ray wall.

    python benchmarks/bench_batch.py [--clips 3] [--iters 300] [--cpus 1] [--work DIR]

Target (issue 17): overhead share <= 10 % of the wall time.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import results_path  # noqa: E402

from surgsplat.data.phantom import PhantomConfig, generate_phantom  # noqa: E402
from surgsplat.render.native import system_info  # noqa: E402

SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
SEQUENTIAL = """
import sys
from pathlib import Path
from surgsplat.pipeline.batch import clip_jobs, write_summary
from surgsplat.pipeline.batch_stages import run_clip_here
out, iters, threads, *clips = sys.argv[1:]
jobs = clip_jobs([Path(c) for c in clips], Path(out), "deform3dgs", int(iters), int(threads), 15.0)
for job in jobs:
    status = run_clip_here(job)
    assert status["state"] == "done", status
write_summary(jobs, Path(out))
"""


def timed(command: list[str]) -> float:
    started = time.perf_counter()
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clips", type=int, default=3)
    parser.add_argument("--iters", type=int, default=300)
    parser.add_argument("--cpus", type=int, default=1)
    parser.add_argument("--work", type=Path)
    parser.add_argument("--out", type=Path, help="JSON file (default: "
                        "benchmarks/results/bench_batch-<cpu>-<best ISA>.json)")
    args = parser.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bench_batch-"))
    phantom = work / "phantom"
    if not phantom.is_dir():
        generate_phantom(PhantomConfig(preset="small"), phantom)
    clips = []
    for index in range(args.clips):
        clip = work / "clips" / f"clip{index}"
        if not clip.is_dir():
            shutil.copytree(phantom, clip)
        clips.append(str(clip))
    for side in ("sequential", "ray"):
        shutil.rmtree(work / side, ignore_errors=True)
    sequential = timed([sys.executable, "-c", SEQUENTIAL, str(work / "sequential"),
                        str(args.iters), str(args.cpus), *clips])
    ray = timed([*SURGSPLAT, "batch", *clips, "--out", str(work / "ray"), "--iters",
                 str(args.iters), "--cpus-per-clip", str(args.cpus), "--num-cpus",
                 str(args.cpus), "--memory-gb", "2"])
    summary = (work / "ray" / "summary.csv").read_text()
    assert summary.count(",done,") == args.clips, summary
    info = system_info()
    command = (f"python benchmarks/bench_batch.py --clips {args.clips} --iters {args.iters} "
               f"--cpus {args.cpus}")
    rows = [{"case": "one after another", "iterations": args.iters, "clips": args.clips,
             "wall_seconds": round(sequential, 1)},
            {"case": "surgsplat batch (Ray)", "iterations": args.iters, "clips": args.clips,
             "wall_seconds": round(ray, 1),
             "overhead_share": round((ray - sequential) / ray, 3)}]
    report = {"benchmark": "bench_batch", "cpu": info["cpu"], "system": info,
              "date": time.strftime("%Y-%m-%d"), "command": command,
              "columns": ["clips", "wall_seconds", "overhead_share"], "rows": rows,
              "target": {"overhead_share": 0.10}}
    print(json.dumps(report, indent=2))
    out = args.out or results_path("bench_batch", info)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(f"results: {out}")


if __name__ == "__main__":
    main()
