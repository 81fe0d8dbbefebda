"""Fault benchmark: work lost when `surgsplat train` is killed with SIGKILL (kill -9) at random
moments, and whether every kill leaves a run that resumes.

    python benchmarks/bench_faults.py [--trials 20] [--checkpoint-seconds 60] [--out FILE]

One run of deform3dgs on the small phantom is killed `--trials` times, each time at a random
moment in the two checkpoint intervals after training (re)started, and resumed with
`surgsplat train --resume` after each kill. Per kill: the wall seconds of training since the last
complete checkpoint (what the kill lost), the iterations past it that the log had reached, and
whether the checkpoint loaded. At the end the run is resumed to completion and its log must hold
strictly increasing iterations. Results go to benchmarks/results/bench_faults-<cpu>-<best ISA>.json.
"""

from __future__ import annotations

import argparse
import json
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

from bench_render import results_path

from surgsplat.render import native
from surgsplat.train.checkpoint import load_checkpoint
from surgsplat.train.trainer import CHECKPOINT, LOG_FILE

ENDLESS = 1_000_000
"""Iterations asked of the killed run: it never ends on its own."""


def surgsplat_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "surgsplat.cli.main", *args]


def logged(run: Path) -> list[int]:
    """Iterations in RUN/train_log.jsonl (a line cut by the kill is skipped)."""
    path = run / LOG_FILE
    found = []
    for line in path.read_text().splitlines() if path.is_file() else []:
        try:
            found.append(json.loads(line)["iteration"])
        except (json.JSONDecodeError, KeyError):
            pass
    return found


def one_kill(phantom: Path, run: Path, checkpoint_seconds: float, rng: random.Random) -> dict:
    """Start (or resume) training, SIGKILL it at a random moment, measure what was lost."""
    if (run / CHECKPOINT).is_file():
        command = surgsplat_command("train", "--out", str(run), "--resume")
    else:
        command = surgsplat_command("train", "--data", str(phantom), "--out", str(run), "--iters",
                                    str(ENDLESS), "--set",
                                    f"train.checkpoint_seconds={checkpoint_seconds}")
    before = logged(run)
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    while logged(run) == before or len(logged(run)) < 1:  # training has (re)started
        if process.poll() is not None:
            raise RuntimeError(f"training ended early: {process.stderr.read().decode()}")
        time.sleep(0.02)
    started = time.time()
    time.sleep(rng.uniform(0.0, 2.0 * checkpoint_seconds))
    process.send_signal(signal.SIGKILL)
    killed = time.time()
    process.wait()
    reached = max(logged(run), default=0)
    state = load_checkpoint(run / CHECKPOINT)  # raises if the kill left it damaged
    saved = (run / CHECKPOINT).stat().st_mtime
    return {"seconds_after_start": killed - started,
            "lost_wall_s": killed - max(saved, started),
            "checkpoint_iteration": int(state["iteration"]),
            "logged_iteration": reached,
            "lost_iterations_logged": max(reached - int(state["iteration"]), 0)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--checkpoint-seconds", type=float, default=60.0,
                        help="train.checkpoint_seconds of the run (the bound on lost work)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    with tempfile.TemporaryDirectory() as tmp:
        phantom, run = Path(tmp) / "phantom", Path(tmp) / "run"
        subprocess.run(surgsplat_command("phantom", "--out", str(phantom), "--preset", "small"),
                       check=True, capture_output=True)
        trials = []
        for trial in range(args.trials):
            trials.append(one_kill(phantom, run, args.checkpoint_seconds, rng))
            print(json.dumps({"trial": trial, **trials[-1]}), file=sys.stderr)
        end = load_checkpoint(run / CHECKPOINT)["iteration"] + 10
        finished = subprocess.run(surgsplat_command("train", "--out", str(run), "--resume",
                                                    "--iters", str(end)),
                                  capture_output=True, text=True)
        iterations = logged(run)
        resumed_ok = (finished.returncode == 0 and iterations[-1] == end
                      and all(a < b for a, b in zip(iterations, iterations[1:])))
    lost = [t["lost_wall_s"] for t in trials]
    info = native.system_info()
    report = {"benchmark": "bench_faults", "cpu": info["cpu"], "system": info,
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "command": "surgsplat train --method deform3dgs (small phantom), kill -9, --resume",
              "checkpoint_seconds": args.checkpoint_seconds, "trials": len(trials),
              "lost_wall_s_median": statistics.median(lost), "lost_wall_s_max": max(lost),
              "lost_iterations_logged_max": max(t["lost_iterations_logged"] for t in trials),
              "checkpoints_damaged": 0, "final_resume_ok": resumed_ok,
              "final_log_strictly_increasing": resumed_ok, "rows": trials}
    out = args.out or results_path("bench_faults", info)
    out.write_text(json.dumps(report, indent=1) + "\n")
    print(f"{len(trials)} kills, checkpoint every {args.checkpoint_seconds:g} s: work lost median "
          f"{report['lost_wall_s_median']:.1f} s, max {report['lost_wall_s_max']:.1f} s; "
          f"every checkpoint loaded; final resume {'ok' if resumed_ok else 'FAILED'}")
    print(f"written to {out}")
    if not resumed_ok:
        sys.exit(1)


if __name__ == "__main__":
    main()
