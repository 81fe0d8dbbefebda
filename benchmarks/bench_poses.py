"""Camera poses at import (`surgsplat import --poses sfm`): trajectory errors on the moving
phantom, registration on the CholecSeg8k clip.

    python benchmarks/bench_poses.py [--phantom DIR | --preset full] [--data PATH] [--work DIR]
                                     [--out FILE] [--plot DIR] [--train-iters N] [--seeds S]
                                     [--clip-train-iters N] [--videos DIR] [--train-only]
                                     [--merge]

Moving phantom (generated into --work unless --phantom names one): its frames and tool masks
are imported with the true focal length and --poses sfm (no depth: the scale is the
convention's), and the estimated poses are compared with the true ones after a similarity
alignment (`surgsplat.eval.trajectory`): ATE, rotation error (mean, max), RPE between
consecutive frames. Against two truths: the world poses (gt/camera_poses.npy) and the camera
relative to the tissue, which breathes rigidly by up to 1.6 mm in the world, a motion no image
can tell from the camera's own. Once more without the focal length (assumed from a 70 degree
field of view) and --sfm-refine-focal: the refined focal length and its errors. The reference, measured in the same run, is the static import
(one fixed camera, what `import` wrote before `--poses sfm`): its errors and its seconds.

CholecSeg8k clip (73 frames, 854x480, 72 with labels; tool = classes 31, 32, the border 50 is
found as the field of view): registered and interpolated frames, reprojection error, sparse
points and seconds, beside the static import's seconds.

With --train-iters N, `deform3dgs` (N iterations, seeds 0..S-1) is trained on the moving
phantom three times: with its true poses; with the poses SfM estimates from its frames, tool
masks and depth (scale from the depth, `SfmWorkspace`), written into a copy of the phantom; and
on that copy with `camera_refine` (a per-frame pose correction learnt while training, prior
weight --prior). The copy's world is SfM's (the first frame's camera), not the phantom's, so
only the metrics in the camera's frame are compared: psnr_tissue and depth_rmse_mm.

With --clip-train-iters N, `deform3dgs` (N iterations, seeds 0..S-1) is trained on the
CholecSeg8k clip, one run per case of --clip-cases (default all of CLIP_CASES): on its static
import (one fixed camera) and on its SfM import (no depth: the scale is the convention's, and
the sparse points initialise the Gaussians), each as imported, and on the SfM import with
`camera_refine`, whose test frames' poses are fitted to their own pixels at evaluation (the
pose-free protocol); and, to tell that protocol's share from the poses', each import with only
that test-time fitting (`camera_refine` at a negligible training rate). psnr_tissue is over the
test frames' tissue pixels by the clip's labels; with --videos DIR each seed-0 run's
side-by-side video (`surgsplat render`) is written to DIR/<case>/. With --merge, the clip's rows
are merged into the results file's clip_training by case.

Each import runs in its own process; seconds are its wall time and CPU seconds (user + system,
both threads) from the operating system, and the SfM stages' wall time from scene.json. The
machine is shared, so wall times vary with its load; CPU seconds much less.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_methods import surgsplat  # noqa: E402
from bench_render import results_path, write_report  # noqa: E402

from surgsplat.data.layout import (META_FILE, POSES_FILE, Intrinsics, SceneMeta,  # noqa: E402
                                   poses_bounds)
from surgsplat.data.phantom.generate import PRESETS  # noqa: E402
from surgsplat.data.scene import load_scene  # noqa: E402
from surgsplat.data.sfm_poses import SfmConfig, SfmWorkspace  # noqa: E402
from surgsplat.eval.trajectory import (TrajectoryErrors, phantom_tissue_poses,  # noqa: E402
                                       rotation_angle_deg, similarity_alignment,
                                       trajectory_errors)
from surgsplat.render.native import system_info  # noqa: E402

SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
SECTIONS = ("phantom", "cholecseg8k", "training", "clip_training")
"""The parts of a report, each made by one option of this script."""
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "cholecseg8k-clip"
CHOLEC_OPTIONS = ["--pattern", "*_endo.png", "--mask-pattern", "*_endo_watershed_mask.png",
                  "--tool-labels", "31,32", "--allow-missing-masks"]


def run_import(source: Path, out: Path, options: list[str]) -> dict:
    """Run `surgsplat import source --out out options` in its own process: wall and CPU
    seconds."""
    shutil.rmtree(out, ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    subprocess.run([*SURGSPLAT, "import", str(source), "--out", str(out), *options], check=True,
                   stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"seconds": wall, "cpu_seconds": cpu}


def poses_of(scene_dir: Path) -> np.ndarray:
    """[N, 4, 4] world-to-camera of a scene folder's frames."""
    return np.stack([frame.camera.world_to_camera.double().numpy()
                     for frame in load_scene(scene_dir).frames])


def sfm_facts(scene_dir: Path) -> dict:
    """What scene.json says of the SfM run."""
    poses = json.loads((scene_dir / META_FILE).read_text())["extra"]["poses"]
    keys = ("registered", "frames", "interpolated", "scale_source", "scale", "sparse_points",
            "reprojection_error_px", "seconds", "stage_seconds")
    return {key: poses[key] for key in keys}


def errors_row(errors: TrajectoryErrors) -> dict:
    return {"ate_mm": errors.ate, "rotation_mean_deg": errors.rotation_mean_deg,
            "rotation_max_deg": errors.rotation_max_deg, "rpe_mm": errors.rpe_translation,
            "rpe_rotation_deg": errors.rpe_rotation_deg, "alignment_scale": errors.scale}


def static_errors(true: np.ndarray) -> dict:
    """Errors of the static camera (every pose the identity): no similarity can align a single
    point's orientation and path, so the centres are compared as they are, and the rotation
    error is each true camera's angle from the first."""
    centres = np.linalg.inv(true)[:, :3, 3]
    angles = rotation_angle_deg(true[:, :3, :3])  # from the first camera (the world)
    return {"ate_mm": float(np.sqrt(((centres - centres[0]) ** 2).sum(1).mean())),
            "rotation_mean_deg": float(angles.mean()), "rotation_max_deg": float(angles.max())}


def phantom_case(phantom: Path, work: Path, plot: Path | None) -> dict:
    preset = json.loads((phantom / META_FILE).read_text())["extra"]["preset"]
    options = ["--masks", str(phantom / "masks"), "--focal", str(PRESETS[preset].focal)]
    static = run_import(phantom / "images", work / "phantom-static", options)
    sfm_dir = work / "phantom-sfm"
    timing = run_import(phantom / "images", sfm_dir, [*options, "--poses", "sfm"])
    estimated = poses_of(sfm_dir)
    world, tissue = phantom_tissue_poses(phantom)
    refined_dir = work / "phantom-sfm-focal"
    refined_timing = run_import(phantom / "images", refined_dir,
                                ["--masks", str(phantom / "masks"), "--poses", "sfm",
                                 "--sfm-refine-focal"])
    guess = json.loads((refined_dir / META_FILE).read_text())["extra"]["focal_px"]
    if plot is not None:
        plot_trajectory(estimated, world, tissue, plot / "traj.png")
    return {"phantom": str(phantom), "preset": preset, "frames": len(world),
            "size_wh": [PRESETS[preset].width, PRESETS[preset].height], **timing,
            "sfm": sfm_facts(sfm_dir),
            "against_tissue": errors_row(trajectory_errors(estimated, tissue)),
            "against_world": errors_row(trajectory_errors(estimated, world)),
            "static_reference": {**static, "against_tissue": static_errors(tissue)},
            "focal_refinement": {
                "true_px": PRESETS[preset].focal, "assumed_px": guess,
                "refined_px": load_scene(refined_dir).camera.fx, **refined_timing,
                "against_tissue": errors_row(trajectory_errors(poses_of(refined_dir), tissue))}}


def cholec_case(data: Path, work: Path) -> dict:
    options = [*CHOLEC_OPTIONS, "--masks", str(data)]
    static = run_import(data, work / "cholec-static", options)
    timing = run_import(data, work / "cholec-sfm", [*options, "--poses", "sfm"])
    return {"data": str(data), **timing, "sfm": sfm_facts(work / "cholec-sfm"),
            "static_reference": static}


def sfm_scene_with_depth(phantom: Path, out: Path) -> dict:
    """A copy of `phantom` at `out` whose poses are SfM's from its frames, tool masks and depth
    (metric scale from the depth); what the SfM run found."""
    scene = load_scene(phantom)
    intrinsics = (SceneMeta.read(phantom / META_FILE).intrinsics
                  or Intrinsics.centred(scene.camera.fx, scene.width, scene.height))
    workspace = SfmWorkspace(intrinsics, SfmConfig())
    for frame in scene.frames:
        workspace.add(np.rint(frame.image.numpy() * 255).astype(np.uint8),
                      (~frame.tissue).numpy(), frame.depth.numpy())
    poses = workspace.solve()
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(phantom, out)
    old = np.load(phantom / POSES_FILE)
    np.save(out / POSES_FILE, poses_bounds(poses.world_to_camera, scene.height, scene.width,
                                           float(old[0, 14]), float(old[:, 15].min()),
                                           float(old[:, 16].max())))
    return {"registered": int(poses.registered.sum()), "frames": len(scene.frames),
            "scale_source": poses.scale_source, "seconds": poses.seconds}


REFINE = ("--set", "components.camera_refine.kind=camera_refine")
TEST_TIME_ONLY = (*REFINE, "--set", "components.camera_refine.lr=1e-12",
                  "--set", "components.camera_refine.lr_final=1e-12")
CLIP_CASES = {"static": ("static", ()), "sfm": ("sfm", ()),
              "sfm_refined": ("sfm", REFINE),
              "static_test_time_poses": ("static", TEST_TIME_ONLY),
              "sfm_test_time_poses": ("sfm", TEST_TIME_ONLY)}
"""Clip training cases: (import, extra train options); the camera_refine cases also take the
pose prior's weight."""


def training_case(phantom: Path, work: Path, iterations: int, seeds: int, prior: float
                  ) -> dict:
    """deform3dgs on the phantom's true poses, on SfM's, and on SfM's with camera_refine:
    psnr_tissue and depth_rmse_mm per seed and their means."""
    sfm_dir = work / "phantom-sfm-depth"
    sfm = sfm_scene_with_depth(phantom, sfm_dir)
    refine = [*REFINE, "--set", f"losses.pose_prior.weight={prior}"]
    cases = {"true_poses": (phantom, []), "sfm_poses": (sfm_dir, []),
             "sfm_poses_refined": (sfm_dir, refine)}
    rows = trained_rows(cases, work, "", iterations, seeds, ("psnr_tissue", "depth_rmse_mm"))
    return {"method": "deform3dgs", "iterations": iterations, "seeds": seeds,
            "pose_prior_weight": prior, "sfm": sfm, "rows": rows}


def trained_rows(cases: dict[str, tuple[Path, list[str]]], work: Path, prefix: str,
                 iterations: int, seeds: int, keys: tuple[str, ...],
                 videos: Path | None = None) -> dict:
    """deform3dgs trained on each case's (scene, extra options) for `iterations`, seeds
    0..S-1, in work/run-<prefix><case>-seed<S>, and evaluated: the metrics `keys` and the train
    CPU seconds per seed and their means, per case; each seed-0 run's videos into
    videos/<case> when given."""
    rows = {}
    for name, (scene, options) in cases.items():
        per_seed = []
        for seed in range(seeds):
            run = work / f"run-{prefix}{name}-seed{seed}"
            shutil.rmtree(run, ignore_errors=True)
            cpu = surgsplat("train", "--method", "deform3dgs", "--data", str(scene), "--out",
                            str(run), "--iters", str(iterations), "--set", f"train.seed={seed}",
                            "--set", f"init.seed={seed}", *options)
            surgsplat("eval", str(run))
            metrics = json.loads((run / "metrics.json").read_text())
            per_seed.append({key: metrics[key] for key in keys}
                            | {"train_cpu_seconds": round(cpu, 1)})
            if videos is not None and seed == 0:
                surgsplat("render", str(run), "--out", str(videos / name))
        rows[name] = {key: float(np.mean([row[key] for row in per_seed]))
                      for key in per_seed[0]} | {"per_seed": per_seed}
    return rows


def clip_training_case(work: Path, iterations: int, seeds: int, videos: Path | None,
                       names: list[str], prior: float) -> dict:
    """deform3dgs on the clip's imports (made by `cholec_case` in `work`) in the CLIP_CASES
    `names`: psnr_tissue and ssim per seed and their means; the seed-0 runs' side-by-side
    videos into `videos`."""
    cases = {}
    for name in names:
        scene, options = CLIP_CASES[name]
        if not (work / f"cholec-{scene}" / POSES_FILE).is_file():
            raise SystemExit(f"{work / f'cholec-{scene}'}: no import there; run without "
                             "--train-only first")
        prior_option = ("--set", f"losses.pose_prior.weight={prior}") if options else ()
        cases[name] = (work / f"cholec-{scene}", [*options, *prior_option])
    rows = trained_rows(cases, work, "cholec-", iterations, seeds, ("psnr_tissue", "ssim"),
                        videos)
    return {"method": "deform3dgs", "iterations": iterations, "seeds": seeds,
            "pose_prior_weight": prior, "rows": rows}


def plot_trajectory(estimated: np.ndarray, world: np.ndarray, tissue: np.ndarray,
                    path: Path) -> None:
    """Camera centres over the frames (x, y, z in mm): the estimate aligned to the tissue
    truth, the tissue truth and the world truth."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    estimated_c2w, tissue_c2w = np.linalg.inv(estimated), np.linalg.inv(tissue)
    aligned = similarity_alignment(estimated_c2w, tissue_c2w).apply(estimated_c2w[:, :3, 3])
    curves = {"true, relative to the tissue": tissue_c2w[:, :3, 3],
              "true, world (tissue breathes)": np.linalg.inv(world)[:, :3, 3],
              "SfM, aligned": aligned}
    figure, axes = plt.subplots(1, 4, figsize=(17, 4))
    for axis, name in enumerate("xyz"):
        for (label, centres), style in zip(curves.items(), ("-", ":", "--")):
            axes[axis].plot(centres[:, axis], style, label=label)
        axes[axis].set(title=f"camera centre {name}", xlabel="frame", ylabel="mm")
    for (label, centres), style in zip(curves.items(), ("-", ":", "--")):
        axes[3].plot(centres[:, 0], centres[:, 1], style, label=label)
    axes[3].set(title="from the front (x, y)", xlabel="x mm", ylabel="y mm", aspect="equal")
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=90)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--phantom", type=Path, help="moving-camera phantom folder (default: "
                        "generate one of --preset into --work)")
    parser.add_argument("--preset", default="full", help="phantom size to generate")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="CholecSeg8k clip")
    parser.add_argument("--threads", type=int, default=None,
                        help="threads of every surgsplat process (default: one per core)")
    parser.add_argument("--work", type=Path, default=Path("/tmp/surgsplat-bench-poses"))
    parser.add_argument("--out", type=Path, help="JSON file (default: "
                        "benchmarks/results/bench_poses-<cpu>-<best ISA>.json)")
    parser.add_argument("--plot", type=Path, help="folder for traj.png")
    parser.add_argument("--train-iters", type=int, help="also train deform3dgs on true, SfM "
                        "and refined SfM poses for this many iterations")
    parser.add_argument("--seeds", type=int, default=1, help="training seeds 0..S-1")
    parser.add_argument("--prior", type=float, default=0.1, help="pose_prior weight")
    parser.add_argument("--clip-train-iters", type=int, help="also train deform3dgs on the "
                        "clip's static and SfM imports for this many iterations")
    parser.add_argument("--clip-cases", nargs="*", choices=list(CLIP_CASES),
                        default=list(CLIP_CASES), help="clip training cases")
    parser.add_argument("--videos", type=Path, help="folder for the clip runs' videos")
    parser.add_argument("--train-only", action="store_true",
                        help="only the training comparisons (no imports: those in --work)")
    parser.add_argument("--merge", action="store_true",
                        help="keep the sections of the results file that this run does not make")
    args = parser.parse_args()
    if args.threads is not None:
        SURGSPLAT.extend(["--threads", str(args.threads)])
    args.work.mkdir(parents=True, exist_ok=True)
    phantom = args.phantom
    if phantom is None and (args.train_iters or not args.train_only):
        phantom = args.work / f"phantom-{args.preset}-moving"
        shutil.rmtree(phantom, ignore_errors=True)
        subprocess.run([*SURGSPLAT, "phantom", "--out", str(phantom), "--preset", args.preset,
                        "--camera", "moving"], check=True, stdout=subprocess.DEVNULL)
    result = {}
    if not args.train_only:
        result["phantom"] = phantom_case(phantom, args.work, args.plot)
        if args.data.is_dir():
            result["cholecseg8k"] = cholec_case(args.data, args.work)
    if args.train_iters:
        result["training"] = training_case(phantom, args.work, args.train_iters, args.seeds,
                                           args.prior)
    if args.clip_train_iters:
        result["clip_training"] = clip_training_case(args.work, args.clip_train_iters,
                                                     args.seeds, args.videos, args.clip_cases,
                                                     args.prior)
    print(json.dumps(result, indent=2))
    out = args.out or results_path("bench_poses", system_info())
    if args.merge and out.is_file():
        previous = json.loads(out.read_text())
        commands = previous.get("commands", [previous["command"]])
        clip = previous.get("clip_training")
        if clip is not None and "clip_training" in result:
            same = all(clip[key] == result["clip_training"][key]
                       for key in ("method", "iterations", "seeds"))
            if same:  # the rows measured before, with this run's rows put in
                result["clip_training"]["rows"] = (clip["rows"]
                                                   | result["clip_training"]["rows"])
        result = {key: value for key, value in previous.items()
                  if key in SECTIONS and key not in result} | result
        result["commands"] = commands + [" ".join(["python", "benchmarks/bench_poses.py",
                                                   *sys.argv[1:]])]
    print(f"written to {write_report('bench_poses', result, out)}")


if __name__ == "__main__":
    main()
