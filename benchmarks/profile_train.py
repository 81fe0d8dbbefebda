"""Where a training run's time goes: samples `surgsplat train` with py-spy (Python and native
frames of the main thread, waiting included) and sums the samples by part of the iteration.

    pip install py-spy
    python benchmarks/profile_train.py --data PHANTOM [--method deform3dgs] [--iters 100]
                                       [--rate 25] [--out FILE] [--set KEY=VALUE ...]

Only the main thread's samples count (OpenMP workers and other threads only wait for it or work
for it). A sample counts for the first category (in the order of CATEGORIES) one of whose
markers is in its stack, the rest is `other`; shares are given for the whole run and for the
samples inside a training step (stacks through --step-marker). Results go to
benchmarks/results/profile_train-<scene folder>-<method>-<cpu>-<best ISA>.json.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from datetime import datetime, timezone
from pathlib import Path

from bench_render import results_path

from surgsplat.render import native

CATEGORIES = {  # name: stack markers, most specific first
    "rasterize (native fwd+bwd)": ("rasterize_forward", "rasterize_backward", "_NativeRasterize"),
    "projection": ("project_forward", "project_backward", "render/project.py"),
    "D-SSIM": ("ssim_forward", "ssim_backward", "eval/ssim.py", "image/ssim.py"),
    "illumination UNet (LumiState)": ("fields/illumination.py", "convolution_backward",
                                       "max_pool2d_with_indices_backward"),
    "SH modulation MLP (LumiState)": ("model/lumistate.py",),
    "deformation field": ("hexplane", "gaussian_basis.py", "fields/"),
    "Adam": ("optim/adam.py", "_fused_adam", "optim/optimizer.py"),
    "densify / prune": ("strategy.py",),
    "data loading": ("data/",),
    "other losses": ("losses/",),
    "rest of render (SH, colours, tensors)": ("render/",),
    "autograd engine (other ops' backward)": ("run_backward", "autograd/__init__.py"),
    "imports": ("_find_and_load",),
}
MAIN_THREAD = "main (surgsplat/cli/main.py"


def categorise(stacks: Counter) -> dict[str, float]:
    """Share of the samples per category, largest first."""
    totals: Counter = Counter()
    for stack, count in stacks.items():
        name = next((name for name, markers in CATEGORIES.items()
                     if any(m in stack for m in markers)), "other (Python, torch ops)")
        totals[name] += count
    total = sum(totals.values())
    return {name: count / total for name, count in totals.most_common()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, required=True,
                        help="scene folder (a phantom or an imported clip)")
    parser.add_argument("--method", default="deform3dgs")
    parser.add_argument("--iters", type=int, default=100)
    parser.add_argument("--rate", type=int, default=25,
                        help="samples per second; each native sample stops the run while py-spy "
                             "unwinds it (at 200 on 2 cores the run got 7 %% of a core)")
    parser.add_argument("--step-marker", default="Trainer.step",
                        help="a frame every stack inside a training step has")
    parser.add_argument("--out", type=Path)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a setting of the method, as `surgsplat train --set`")
    args = parser.parse_args()
    py_spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "samples.txt"
        command = [sys.executable, "-m", "surgsplat.cli.main", "train", "--method", args.method,
                   "--data", str(args.data), "--out", str(Path(tmp) / "run"),
                   "--iters", str(args.iters),
                   *(arg for setting in args.set for arg in ("--set", setting))]
        subprocess.run([py_spy, "record", "--native", "--idle", "--format", "raw", "--rate",
                        str(args.rate), "--output", str(raw), "--", *command], check=True,
                       capture_output=True)
        stacks: Counter = Counter()
        for line in raw.read_text().splitlines():
            stack, _, count = line.rpartition(" ")
            if MAIN_THREAD in stack:
                stacks[stack] += int(count)
    in_steps = Counter({s: n for s, n in stacks.items() if args.step_marker in s})
    info = native.system_info()
    report = {"benchmark": "profile_train", "cpu": info["cpu"], "system": info,
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "command": f"surgsplat train --method {args.method} --iters {args.iters}"
                         + "".join(f" --set {setting}" for setting in args.set),
              "data": args.data.name, "samples": sum(stacks.values()),
              "step_samples": sum(in_steps.values()),
              "shares_whole_run": categorise(stacks), "shares_in_steps": categorise(in_steps)}
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
