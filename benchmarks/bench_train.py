"""Training benchmark: time to quality on the full "pulling" phantom (640x512, 64 frames) and
speed on the real CholecSeg8k clip (854x480, imported, no depth), each run in its own process.

    python benchmarks/bench_train.py [--presets deform3dgs endogaussian] [--minutes 8]
                                     [--real-iters 1000] [--curve-every 50] [--phantom DIR]
                                     [--work DIR] [--skip-real] [--out FILE] [--json]

A case is one `Trainer` run of a preset at its default settings, in a child process, so that its
peak RSS is its own and its wall time includes loading the scene and building the model. The
run stops at the preset's iterations or after --minutes of wall time (the real clip after
--real-iters). Every --curve-every iterations the test frames' psnr_tissue is measured, outside
the training clock, giving seconds of training to reach 35 and 39 dB. Also reported: seconds per
iteration (the mean over the run, the median step, and the mean over the last 10% of
iterations, where the Gaussians are most numerous), rendering FPS of the trained model (median
over the test frames of the full render: deformation, projection, rasterisation), and the
in-process limit probe (bench_render's composite_probe) before and after training, so that times
compare across machines and hours. Results go to
benchmarks/results/bench_train-<cpu>-<best ISA>.json; benchmarks/readme_tables.py turns them into
the README's table.

Targets (issue 10): deform3dgs on the phantom >= 35 dB within 60 s and >= 39 dB within 240 s of
training; the CholecSeg8k clip <= 0.15 s per iteration at default settings; rendering the
trained real clip >= 30 FPS.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import surgsplat  # noqa: F401  (before torch: sets surgsplat's OpenMP wait policy)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import PROBE_GAUSSIANS, PROBE_TILES, peak_rss_mb, write_report  # noqa: E402

from surgsplat.data.importer import ImportConfig, import_scene  # noqa: E402
from surgsplat.data.phantom import PhantomConfig, generate_phantom  # noqa: E402
from surgsplat.data.scene import load_scene  # noqa: E402
from surgsplat.eval.image_metrics import psnr_tissue  # noqa: E402
from surgsplat.methods.registry import method_config  # noqa: E402
from surgsplat.model.component import FrameTime  # noqa: E402
from surgsplat.model.dynamic import render_frame  # noqa: E402
from surgsplat.render import native  # noqa: E402
from surgsplat.train.trainer import Trainer  # noqa: E402

REAL_CLIP = Path(__file__).resolve().parents[2] / "shared" / "data" / "cholecseg8k-clip"
THRESHOLDS_DB = (35.0, 39.0)
TARGETS = {"phantom_seconds_to_35db": 60.0, "phantom_seconds_to_39db": 240.0,
           "real_seconds_per_iter": 0.15, "real_render_fps": 30.0}
RENDER_REPEATS = 5


def probe_evals_per_s() -> float:
    """The limit probe's (Gaussian, pixel) evaluations per second now (median of 5)."""
    module = native.native_module()
    times = []
    for _ in range(5):
        started = time.perf_counter()
        module.composite_probe(PROBE_TILES, PROBE_GAUSSIANS, 3)
        times.append(time.perf_counter() - started)
    return PROBE_TILES * PROBE_GAUSSIANS * 256 / statistics.median(times)


def render_test_frame(trainer: Trainer, frame):
    return render_frame(trainer.model, frame.camera, FrameTime(frame.index, frame.time),
                        trainer.background)


def test_psnr(trainer: Trainer) -> float:
    """Mean psnr_tissue over the test frames, rendered now."""
    values = [psnr_tissue(render_test_frame(trainer, frame).rgb.clamp(0, 1), frame.image,
                          frame.tissue) for frame in trainer.scene.test_frames]
    return sum(values) / len(values)


def render_fps(trainer: Trainer) -> float:
    """1 / the median time of a full render of a test frame (each rendered RENDER_REPEATS times
    after one warm-up)."""
    times = []
    with torch.no_grad():
        for frame in trainer.scene.test_frames:
            render_test_frame(trainer, frame)
            for _ in range(RENDER_REPEATS):
                started = time.perf_counter()
                render_test_frame(trainer, frame)
                times.append(time.perf_counter() - started)
    return 1.0 / statistics.median(times)


def seconds_to(curve: list[list[float]], threshold: float) -> float | None:
    """Training seconds of the first curve point at or above `threshold` dB, None if none."""
    return next((seconds for _, seconds, psnr in curve if psnr >= threshold), None)


def run_case(scene_dir: Path, preset: str, run_dir: Path, budget_s: float,
             iterations: int | None, curve_every: int) -> dict:
    """One training run in this process: its figures as one row."""
    probe_before = probe_evals_per_s()
    started = time.perf_counter()
    config = method_config(preset)
    if iterations:
        config.train.iterations = iterations
    shutil.rmtree(run_dir, ignore_errors=True)
    trainer = Trainer(config, load_scene(scene_dir), run_dir)
    trainer.write_run_files()
    initialisation = time.perf_counter() - started
    curve, steps = [], []
    with torch.no_grad():
        curve.append([0, 0.0, round(test_psnr(trainer), 2)])
    while trainer.iteration < config.train.iterations:
        before = trainer.elapsed
        trainer.step()
        steps.append(trainer.elapsed - before)
        if trainer.iteration % curve_every == 0:
            with torch.no_grad():
                curve.append([trainer.iteration, round(trainer.elapsed, 1),
                              round(test_psnr(trainer), 2)])
        if time.perf_counter() - started > budget_s:
            break
    trainer.save()
    wall = time.perf_counter() - started
    with torch.no_grad():
        final_psnr = test_psnr(trainer)
    last = steps[-max(len(steps) // 10, 1):]
    row = {"method": preset, "iterations": trainer.iteration,
           "train_seconds": trainer.elapsed, "wall_seconds": wall,
           "initialisation_seconds": initialisation,
           "seconds_per_iter": trainer.elapsed / max(trainer.iteration, 1),
           "median_step_seconds": statistics.median(steps),
           "last_tenth_seconds_per_iter": sum(last) / len(last),
           "test_psnr_tissue": final_psnr,
           "render_fps": render_fps(trainer),
           "num_gaussians": trainer.model.gaussians.num_gaussians,
           "width": trainer.scene.frames[0].image.shape[1],
           "height": trainer.scene.frames[0].image.shape[0],
           "peak_rss_mb": peak_rss_mb(), "curve": curve,
           "probe_evals_per_s_before": probe_before, "probe_evals_per_s_after": probe_evals_per_s()}
    for threshold in THRESHOLDS_DB:
        row[f"seconds_to_{threshold:.0f}db"] = seconds_to(curve, threshold)
    return row


def real_clip_scene(work: Path) -> Path:
    """The CholecSeg8k clip imported (once) under `work`: tool masks from the watershed labels
    31 and 32, frames without a mask dropped."""
    scene_dir = work / "cholecseg8k-clip"
    if not (scene_dir / "poses_bounds.npy").is_file():
        shutil.rmtree(scene_dir, ignore_errors=True)
        import_scene(REAL_CLIP, scene_dir, ImportConfig(
            pattern="*_endo.png", masks=REAL_CLIP, mask_pattern="*_endo_watershed_mask.png",
            tool_labels=(31, 32), allow_missing_masks=True))
    return scene_dir


def case_in_subprocess(scene: str, scene_dir: Path, preset: str, args) -> dict:
    iterations = args.real_iters if scene == "cholecseg8k-clip" else None
    command = [sys.executable, __file__, "--case", f"{scene}:{preset}:{scene_dir}",
               "--work", str(args.work), "--minutes", str(args.minutes),
               "--curve-every", str(args.curve_every)]
    if iterations:
        command += ["--real-iters", str(iterations)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return {"scene": scene, **json.loads(done.stdout.strip().splitlines()[-1])}


def print_row(row: dict) -> None:
    reached = ", ".join(f"{t:.0f} dB at {row[f'seconds_to_{t:.0f}db']} s" for t in THRESHOLDS_DB)
    print(f"{row['scene']} / {row['method']}: {row['iterations']} iterations, "
          f"{row['train_seconds']:.0f} s training ({row['seconds_per_iter']:.3f} s/iter, last "
          f"tenth {row['last_tenth_seconds_per_iter']:.3f}), {row['wall_seconds']:.0f} s wall; "
          f"test psnr_tissue {row['test_psnr_tissue']:.2f} ({reached}); "
          f"render {row['render_fps']:.1f} FPS; {row['num_gaussians']} Gaussians; "
          f"peak RSS {row['peak_rss_mb']:.0f} MB; probe {row['probe_evals_per_s_before']:.2e}"
          f"/s", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--presets", nargs="+", default=["deform3dgs", "endogaussian"],
                        help="presets trained on the phantom; the first also on the real clip")
    parser.add_argument("--minutes", type=float, default=8.0, help="wall budget per run")
    parser.add_argument("--real-iters", type=int, default=1000,
                        help="iterations on the real clip (its seconds per iteration are "
                             "measured at default settings otherwise)")
    parser.add_argument("--curve-every", type=int, default=50,
                        help="iterations between test-PSNR measurements")
    parser.add_argument("--phantom", type=Path, default=None,
                        help="existing full pulling phantom (default: generated under --work)")
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "surgsplat-bench-train")
    parser.add_argument("--skip-real", action="store_true", help="skip the CholecSeg8k clip")
    parser.add_argument("--out", type=Path, help="JSON file (default: "
                        "benchmarks/results/bench_train-<cpu>-<best ISA>.json)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--case", help=argparse.SUPPRESS)  # SCENE:PRESET:DIR, in a child process
    args = parser.parse_args()
    if native.native_module() is None:
        sys.exit("the native module is not built: run `make install` first")
    if args.case:
        scene, preset, scene_dir = args.case.split(":", 2)
        iterations = args.real_iters if scene == "cholecseg8k-clip" else None
        row = run_case(Path(scene_dir), preset, args.work / f"{scene}-{preset}",
                       args.minutes * 60, iterations, args.curve_every)
        print(json.dumps(row))
        return
    args.work.mkdir(parents=True, exist_ok=True)
    phantom = args.phantom or args.work / "phantom-full-pulling"
    if not (phantom / "poses_bounds.npy").is_file():
        generate_phantom(PhantomConfig(preset="full", motion="pulling"), phantom)
    cases = [("phantom-full-pulling", phantom, preset) for preset in args.presets]
    if not args.skip_real and REAL_CLIP.is_dir():
        cases.append(("cholecseg8k-clip", real_clip_scene(args.work), args.presets[0]))
    rows = []
    for scene, scene_dir, preset in cases:
        rows.append(case_in_subprocess(scene, scene_dir, preset, args))
        print_row(rows[-1])
    phantom_main = next(r for r in rows if r["scene"] == "phantom-full-pulling")
    real = next((r for r in rows if r["scene"] == "cholecseg8k-clip"), None)
    measured = {"phantom_seconds_to_35db": phantom_main["seconds_to_35db"],
                "phantom_seconds_to_39db": phantom_main["seconds_to_39db"],
                "real_seconds_per_iter": real and real["seconds_per_iter"],
                "real_render_fps": real and real["render_fps"]}
    out = write_report("bench_train", {"targets": TARGETS, "measured": measured,
                                       "minutes": args.minutes, "rows": rows}, args.out)
    if args.json:
        print(json.dumps(rows, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
