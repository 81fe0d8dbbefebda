"""Operator census of a training step: how many PyTorch operators a step of each preset runs, and
how its time divides between surgsplat's native kernels, torch's fused Adam, the other ATen
operators and the framework around them.

    python benchmarks/op_census.py [--presets deform3dgs surgsplat ...] [--warmup 400]
                                   [--steps 20] [--threads 2] [--phantom DIR] [--work DIR]
                                   [--out FILE]

Each preset trains at its default schedule on the full "pulling" phantom (generated under --work
when --phantom is not given) in this process: --warmup steps, then --steps more that
torch.profiler records (operators only, no stacks or shapes, so that recording costs little;
with the default --warmup, the steps are early in the fine stage of every preset). Per preset:
seconds per profiled step (the wall time of the steps), the operators' self CPU time per step,
its shares by kind (OPERATOR_KINDS), the ATen operator calls per step, and the operators with
the most self time. Where the py-spy phase tables of bench_train say "the autograd engine" and
"the rest of the render", this says how many operators those are and whether one of them is
worth a native kernel. Results go to benchmarks/results/op_census-<cpu>-<best ISA>.json.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import surgsplat  # noqa: F401  (before torch: sets surgsplat's OpenMP wait policy)
import torch
from torch.profiler import ProfilerActivity, profile

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import full_pulling_phantom, write_report  # noqa: E402

from surgsplat.data.scene import load_scene  # noqa: E402
from surgsplat.methods.overrides import build_method_config  # noqa: E402
from surgsplat.methods.registry import PRESETS  # noqa: E402
from surgsplat.render import native  # noqa: E402
from surgsplat.train.trainer import Trainer  # noqa: E402

TOP_OPERATORS = 12

OPERATOR_KINDS = ("native kernels", "fused Adam", "ATen operators", "framework")
"""native kernels: surgsplat's autograd Functions around csrc/ (their forward and backward);
fused Adam: torch's fused optimiser step; ATen operators: every other aten:: operator (the
elementwise arithmetic, copies, reductions, matrix products of the components and losses, and
their backward); framework: the rest (autograd's engine, the optimiser's Python, profiler
labels)."""


def operator_kind(name: str) -> str:
    """The OPERATOR_KINDS entry of a profiler event name."""
    if name.startswith("_Native"):
        return "native kernels"
    if name == "aten::_fused_adam_":
        return "fused Adam"
    if name.startswith("aten::"):
        return "ATen operators"
    return "framework"


def census(events, steps: int, step_seconds: float) -> dict:
    """The census of `steps` profiled steps from the profiler's key averages `events` (objects
    with key, count and self_cpu_time_total in microseconds)."""
    self_ms = {event.key: event.self_cpu_time_total / 1e3 / steps for event in events}
    calls = {event.key: event.count / steps for event in events}
    total = sum(self_ms.values())
    by_kind: dict[str, float] = defaultdict(float)
    for name, ms in self_ms.items():
        by_kind[operator_kind(name)] += ms
    top = sorted(self_ms, key=self_ms.get, reverse=True)[:TOP_OPERATORS]
    return {
        "steps": steps, "seconds_per_step": step_seconds, "self_ms_per_step": total,
        "aten_calls_per_step": sum(n for name, n in calls.items()
                                   if operator_kind(name) == "ATen operators"),
        "shares": {kind: by_kind[kind] / total for kind in OPERATOR_KINDS},
        "top": [{"operator": name, "kind": operator_kind(name), "ms_per_step": self_ms[name],
                 "share": self_ms[name] / total, "calls_per_step": calls[name]}
                for name in top],
    }


def run_preset(scene_dir: Path, preset: str, warmup: int, steps: int, work: Path) -> dict:
    """Train `preset` at its default schedule for warmup steps, then profile `steps` more; its
    census."""
    trainer = Trainer(build_method_config(preset, None, []), load_scene(scene_dir), work / preset)
    for _ in range(warmup):
        trainer.step()
    with profile(activities=[ProfilerActivity.CPU]) as profiler:
        started = time.perf_counter()
        for _ in range(steps):
            trainer.step()
        seconds = time.perf_counter() - started
    row = census(profiler.key_averages(), steps, seconds / steps)
    return {"preset": preset, "warmup": warmup, "num_gaussians":
            trainer.model.gaussians.num_gaussians, **row}


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--presets", nargs="+", choices=list(PRESETS),
                        default=["deform3dgs", "surgsplat"])
    parser.add_argument("--warmup", type=int, default=400,
                        help="iterations before the profiled ones")
    parser.add_argument("--steps", type=int, default=20, help="iterations profiled")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--phantom", type=Path, default=None,
                        help="existing full pulling phantom (default: generated under --work)")
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "surgsplat-op-census")
    parser.add_argument("--out", type=Path, help="JSON file (default: "
                        "benchmarks/results/op_census-<cpu>-<best ISA>.json)")
    args = parser.parse_args()
    if args.warmup < 0 or args.steps < 1:
        parser.error("--warmup must be at least 0 and --steps at least 1")
    return args


def main() -> None:
    args = parse_args()
    if native.native_module() is None:
        sys.exit("the native module is not built: run `make install` first")
    native.set_threads(args.threads)
    phantom = full_pulling_phantom(args.phantom or args.work / "phantom-full-pulling")
    rows = []
    for preset in args.presets:
        rows.append(run_preset(phantom, preset, args.warmup, args.steps, args.work))
        row = rows[-1]
        print(f"{preset}: {row['seconds_per_step'] * 1e3:.0f} ms/step, "
              f"{row['aten_calls_per_step']:.0f} ATen calls/step, "
              + ", ".join(f"{kind} {share:.0%}" for kind, share in row["shares"].items()),
              flush=True)
    out = write_report("op_census", {"threads": args.threads, "steps": args.steps,
                                     "warmup": args.warmup, "rows": rows}, args.out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
