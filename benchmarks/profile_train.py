"""Where a training run's time goes: samples `surgsplat train` with py-spy (Python and native
frames of the main thread, waiting included) and sums the samples by part of the iteration.

    pip install py-spy
    python benchmarks/profile_train.py --data PHANTOM [--method deform3dgs] [--iters 100]
                                       [--rate 25] [--threads T] [--out FILE]
                                       [--set KEY=VALUE ...]

Only the main thread's samples count (OpenMP workers and other threads only wait for it or work
for it). A sample counts for the first category (in the order of CATEGORIES) one of whose
markers is in its stack, the rest is `Python / other`; shares are given for the whole run and
for the samples inside a training step (stacks through --step-marker). The forward and backward
of the projection, the rasterisation and D-SSIM are told apart by the native kernels
(project_forward, rasterize_backward, ...) and by their autograd Functions' forward and
backward frames; the backward of plain torch ops is the autograd engine's. Results go to
benchmarks/results/profile_train-<scene folder>-<method>-<cpu>-<best ISA>.json.
bench_train.py calls `profile_training` for its per-case breakdown.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path

from bench_render import results_path

from surgsplat.render import native

CATEGORIES = {  # name: stack markers; a sample takes the first category that matches
    "data loading": ("surgsplat/data/", "Trainer._next_frame", "Trainer._at_step_size"),
    "deformation field": ("fields/deformation.py", "fields/hexplane.py",
                          "fields/gaussian_basis.py", "MeshAnchor.transform",
                          "ToolField.transform"),
    "projection backward": ("project_backward", "_NativeProject.backward"),
    "projection forward": ("project_forward", "render/project.py"),
    "rasterize backward": ("rasterize_backward", "_NativeRasterize.backward"),
    "rasterize forward": ("rasterize_forward", "render/rasterize.py"),
    "D-SSIM backward": ("ssim_backward", "_NativeSSIMScore.backward", "_NativeSSIMMap.backward"),
    "D-SSIM forward": ("ssim_forward", "image/ssim.py"),
    "other losses": ("losses/", "SplatModel.losses", "normal_consistency.py"),
    "Adam (optimiser)": ("optim/adam.py", "_fused_adam", "optim/optimizer.py"),
    "densify / prune": ("train/strategy.py", "SplatModel.densify_weights"),
    "rest of render": ("render/", "SplatModel.render"),
    "autograd engine (other ops' backward)": ("run_backward", "autograd/__init__.py"),
}
OTHER = "Python / other"
MAIN_THREAD = "main (surgsplat/cli/main.py"
STEP_MARKER = "Trainer.step"


def categorise(stacks: Counter) -> dict[str, float]:
    """Share of the samples per category, largest first."""
    totals: Counter = Counter()
    for stack, count in stacks.items():
        name = next((name for name, markers in CATEGORIES.items()
                     if any(m in stack for m in markers)), OTHER)
        totals[name] += count
    total = sum(totals.values())
    return {name: count / total for name, count in totals.most_common()}


def py_spy() -> str | None:
    """The py-spy executable on PATH or beside this Python, None when neither has one."""
    beside = Path(sys.executable).with_name("py-spy")
    return shutil.which("py-spy") or (str(beside) if beside.is_file() else None)


def main_thread_stacks(data: Path, method: str, iters: int, rate: int,
                       settings: Sequence[str] = (), threads: int | None = None) -> Counter:
    """Samples per stack of the main thread of `surgsplat train` on `data` for `iters`
    iterations, recorded by py-spy with native frames at `rate` per second."""
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "samples.txt"
        command = [sys.executable, "-m", "surgsplat.cli.main",
                   *(["--threads", str(threads)] if threads else []),
                   "train", "--method", method, "--data", str(data),
                   "--out", str(Path(tmp) / "run"), "--iters", str(iters),
                   *(arg for setting in settings for arg in ("--set", setting))]
        subprocess.run([py_spy(), "record", "--native", "--idle", "--format", "raw", "--rate",
                        str(rate), "--output", str(raw), "--", *command], check=True,
                       capture_output=True)
        stacks: Counter = Counter()
        for line in raw.read_text().splitlines():
            stack, _, count = line.rpartition(" ")
            if MAIN_THREAD in stack:
                stacks[stack] += int(count)
    return stacks


def profile_training(data: Path, method: str, iters: int, rate: int = 25,
                     settings: Sequence[str] = (), threads: int | None = None,
                     step_marker: str = STEP_MARKER) -> dict:
    """Shares of the main thread's samples per category over a `surgsplat train` run, for the
    whole run and inside the training steps (stacks through `step_marker`), with the sample
    counts. Needs py-spy (`py_spy()`)."""
    stacks = main_thread_stacks(data, method, iters, rate, settings, threads)
    in_steps = Counter({s: n for s, n in stacks.items() if step_marker in s})
    return {"samples": sum(stacks.values()), "step_samples": sum(in_steps.values()),
            "shares_whole_run": categorise(stacks), "shares_in_steps": categorise(in_steps)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True,
                        help="scene folder (a phantom or an imported clip)")
    parser.add_argument("--method", default="deform3dgs")
    parser.add_argument("--iters", type=int, default=100)
    parser.add_argument("--rate", type=int, default=25,
                        help="samples per second; each native sample stops the run while py-spy "
                             "unwinds it (at 200 on 2 cores the run got 7 %% of a core)")
    parser.add_argument("--threads", type=int, help="`surgsplat --threads` of the run")
    parser.add_argument("--step-marker", default=STEP_MARKER,
                        help="a frame every stack inside a training step has")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting of the method, as `surgsplat train --set`")
    args = parser.parse_args()
    if py_spy() is None:
        sys.exit("py-spy is not installed: pip install py-spy")
    profile = profile_training(args.data, args.method, args.iters, args.rate, args.set,
                               args.threads, args.step_marker)
    info = native.system_info()
    report = {"benchmark": "profile_train", "cpu": info["cpu"], "system": info,
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "command": f"surgsplat train --method {args.method} --iters {args.iters}"
                         + "".join(f" --set {setting}" for setting in args.set),
              "data": args.data.name, **profile}
    out = args.out or results_path(f"profile_train-{args.data.name}-{args.method}", info)
    out.write_text(json.dumps(report, indent=1) + "\n")
    for scope in ("shares_whole_run", "shares_in_steps"):
        print(scope.replace("_", " ") + ":")
        for name, share in report[scope].items():
            print(f"  {share:7.1%}  {name}")
    print(f"{report['samples']} main-thread samples ({report['step_samples']} in steps); "
          f"written to {out}")


if __name__ == "__main__":
    main()
