"""Densification ablation: how a large Gaussian is split (DensifyConfig.split), on the full
"pulling" phantom with deform3dgs.

    python benchmarks/bench_densify_split.py [--iters 1000] [--curve-every 50] [--phantom DIR]
                                             [--work DIR] [--out FILE]

For each split mode ("sample", 3DGS's children at random points of the parent with every axis
shrunk; "long_axis", the children along the parent's longest axis keeping its extent), one run
of the preset at its default settings otherwise. Reported: the test psnr_tissue across every
densifying step (at iteration k - 1 and k, where k densifies), the curve every --curve-every
iterations (points that fall on a densifying step are right after it) and the first iteration
at or above 35 dB. Quality per iteration does not depend on the machine; seconds are not
reported. Results go to benchmarks/results/bench_densify_split-<cpu>-<best ISA>.json.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import surgsplat  # noqa: F401  (before torch: sets surgsplat's OpenMP wait policy)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import full_pulling_phantom, write_report  # noqa: E402
from bench_train import test_psnr_and_visible  # noqa: E402

from surgsplat.data.scene import load_scene  # noqa: E402
from surgsplat.methods.registry import method_config  # noqa: E402
from surgsplat.train.trainer import Trainer  # noqa: E402

MODES = ("sample", "long_axis")
PRESET = "deform3dgs"
THRESHOLD_DB = 35.0


def measured_psnr(trainer: Trainer) -> float:
    with torch.no_grad():
        return round(test_psnr_and_visible(trainer)[0], 3)


def run_mode(scene_dir: Path, mode: str, run_dir: Path, iterations: int,
             curve_every: int) -> dict:
    config = method_config(PRESET)
    config.densify.split = mode
    densify = config.densify
    trainer = Trainer(config, load_scene(scene_dir), run_dir)
    first, last = densify.window(config.train.iterations)
    densifying = {k for k in range(first, min(iterations, last) + 1)
                  if k % densify.every == 0}
    steps, curve = [], []
    while trainer.iteration < iterations:
        if trainer.iteration + 1 in densifying:
            before = measured_psnr(trainer)
        trainer.step()
        k = trainer.iteration
        if k in densifying:
            after = measured_psnr(trainer)
            steps.append({"iteration": k, "psnr_before": before, "psnr_after": after,
                          "change_db": round(after - before, 3),
                          "gaussians": trainer.model.gaussians.num_gaussians})
        if k % curve_every == 0:
            curve.append([k, after if k in densifying else measured_psnr(trainer)])
    reached = next((k for k, psnr in curve if psnr >= THRESHOLD_DB), None)
    changes = [step["change_db"] for step in steps]
    return {"split": mode, "iterations": iterations, "densifying_steps": steps,
            "mean_change_db": round(sum(changes) / len(changes), 3) if changes else None,
            "curve": curve, f"iteration_to_{THRESHOLD_DB:.0f}db": reached,
            "final_test_psnr_tissue": curve[-1][1] if curve else None,
            "num_gaussians": trainer.model.gaussians.num_gaussians}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--iters", type=int, default=1000, help="iterations per run")
    parser.add_argument("--curve-every", type=int, default=50,
                        help="iterations between test-PSNR measurements")
    parser.add_argument("--phantom", type=Path, default=None,
                        help="existing full pulling phantom (default: generated under --work)")
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "surgsplat-bench-split")
    parser.add_argument("--out", type=Path, help="JSON file (default: "
                        "benchmarks/results/bench_densify_split-<cpu>-<best ISA>.json)")
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    phantom = full_pulling_phantom(args.phantom or args.work / "phantom-full-pulling")
    rows = []
    for mode in MODES:
        rows.append(run_mode(phantom, mode, args.work / f"run-{mode}", args.iters,
                             args.curve_every))
        row = rows[-1]
        print(f"{mode}: mean change across a densifying step {row['mean_change_db']} dB "
              f"({[s['change_db'] for s in row['densifying_steps']]}); "
              f"{THRESHOLD_DB:.0f} dB at iteration {row[f'iteration_to_{THRESHOLD_DB:.0f}db']}; "
              f"final {row['final_test_psnr_tissue']} dB, {row['num_gaussians']} Gaussians",
              flush=True)
    out = write_report("bench_densify_split", {"preset": PRESET, "rows": rows}, args.out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
