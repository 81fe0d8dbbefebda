"""Method ablations on the full phantom, in suites (one per paper): each run is `surgsplat train`
then `surgsplat eval` in its own process (so train seconds, wall time including start-up, and
peak RSS are each run's own).

    python benchmarks/bench_methods.py --suite NAME [--json] [--iters N] [--work DIR]
                                       [--cases NAME ...]

A suite lists its cases, the metrics it reports and its baseline case; every ratio is against
that baseline in the same run. Results go to
benchmarks/results/bench_methods_<suite>-<cpu>-<best ISA>.json and become the README region
`bench_methods_<suite>` (benchmarks/readme_tables.py).

Suite `endogsg` (issue 13): deform3dgs, endogaussian and endoplanar beside endogsg and its
ablations of Endo-GSG Table 4 (without the depth loss, without projection and orientation,
without SDA); the mesh export of every frame is timed for deform3dgs and endogsg. Targets:
endogsg gaussians_p2s_mean_mm <= 0.5 x deform3dgs, psnr_tissue within 0.5 dB of deform3dgs,
training time <= 2 x, peak RSS <= 4 GB, meshes of all frames in <= 60 s, mesh P2S median
<= 0.5 mm.

Suite `endoplanar` (issue 9): deform3dgs; endoplanar without its normal loss; endoplanar; and
deform3dgs on the moving-camera phantom with known poses. Targets: endoplanar psnr_tissue >= 38
dB, median normal error <= 5 deg, depth_rmse_mm no worse than deform3dgs, training time within
15% of deform3dgs; the moving-camera run psnr_tissue >= 35 dB.

Suite `lumistate` (issue 15): deform3dgs (whose exposure curve is the exposure-only model) and
lumistate on the livar and hivar phantoms, and lumistate on hivar with Stage 1 only (Retinex and
bright-channel losses off); ratios against deform3dgs on the same phantom. Stage 2 starts at
iteration LUMISTATE_STAGE2_ITER, a third of the --iters 400 the suite is run with. Targets
(hivar): lumistate psnr_tissue >= deform3dgs + 1 dB, reflectance_error and r_var <= 0.5 x
deform3dgs's (the naive baseline: its rendered colour scored as reflectance); livar: no PSNR
loss over 0.3 dB; training time <= 1.5 x deform3dgs.

Suite `drawer` (issue 16): deform3dgs, endogsg and drawer (endogsg's components with Gaussians
anchored on the SDF's mesh, plus PhysioSplat's tool field); the mesh export of every frame is
timed for drawer. Targets: drawer psnr_tissue within 1 dB of endogsg, mesh P2S median <= 0.5 mm.

Suite `physiosplat` (issue 14): deform3dgs; endogaussian, which is PhysioSplat's Table 2 row (a)
(the monolithic HexPlane 4DGS baseline); rows (b) +tool/tissue decomposition, (c) +biomechanics
and (d) +specular (the full `physiosplat` preset); and the full preset trained with tool masks
dilated and eroded by 10 px (`train.tool_mask_offset_px`). Targets: physiosplat psnr_occluded
>= 3 dB above the better of deform3dgs and endogaussian, psnr_tissue no lower than
endogaussian, 0 collisions, training time <= 2x endogaussian, peak RSS <= 4 GB.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import results_path  # noqa: E402

from surgsplat.render.native import system_info  # noqa: E402

SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
RUN_COLUMNS = ("train_seconds", "train_time_ratio", "wall_seconds", "num_gaussians",
               "peak_rss_mb")
"""Columns every suite reports after its own metrics."""


@dataclass(frozen=True)
class Case:
    """One row of the ablation."""

    name: str
    method: str
    phantom: str  # key of PHANTOMS
    settings: tuple[str, ...] = ()  # --set assignments
    export_mesh: bool = False  # also time `surgsplat export --mesh` of every frame


PHANTOMS = {"pulling": ("--preset", "full", "--motion", "pulling"),
            "pulling-moving-camera": ("--preset", "full", "--motion", "pulling",
                                      "--camera", "moving"),
            "livar": ("--preset", "full", "--motion", "pulling", "--lighting", "livar"),
            "hivar": ("--preset", "full", "--motion", "pulling", "--lighting", "hivar")}
LUMISTATE_STAGE2_ITER = 133
"""Stage 2 start of the lumistate suite's runs (a third of its --iters 400)."""
LUMISTATE_STAGES = tuple(f"losses.{term}.start_iter={LUMISTATE_STAGE2_ITER}"
                         for term in ("retinex", "bright_channel"))
STAGE1_ONLY = ("losses.retinex.weight=0", "losses.bright_channel.weight=0")


@dataclass(frozen=True)
class Suite:
    """The ablation of one paper: its rows, the metrics shown, and the row ratios refer to."""

    cases: tuple[Case, ...]
    metrics: tuple[str, ...]  # keys of metrics.json shown, in order
    baseline: str  # name of the case ratios are taken against
    ratio_metrics: tuple[str, ...] = ()  # metrics also reported as <key>_ratio to the baseline
    baseline_by_phantom: bool = False  # ratios against the baseline's method on each row's phantom


PHYSIOSPLAT_WITHOUT_BIOMECHANICS = (
    "components.biomechanics=null", "losses.strain=null", "losses.collision=null",
    "components.deformation.volume_samples=0", "losses.volume=null")
PHYSIOSPLAT_WITHOUT_SPECULAR = ("components.specular=null", "gaussians.sh_degree=1")

SUITES = {
    "endoplanar": Suite(
        cases=(
            Case("deform3dgs", "deform3dgs", "pulling"),
            Case("endoplanar-no-normal-loss", "endoplanar", "pulling",
                 ("losses.normal.weight=0",)),
            Case("endoplanar", "endoplanar", "pulling"),
            Case("deform3dgs-moving-camera", "deform3dgs", "pulling-moving-camera"),
        ),
        metrics=("psnr_tissue", "ssim", "depth_rmse_mm", "depth_rmse_ratio",
                 "normal_error_deg_median", "normal_error_deg_mean", "chamfer_mm",
                 "p2s_median_mm"),
        baseline="deform3dgs", ratio_metrics=("depth_rmse_mm",)),
    "endogsg": Suite(
        cases=(
            Case("deform3dgs", "deform3dgs", "pulling", export_mesh=True),
            Case("endogsg", "endogsg", "pulling", export_mesh=True),
            Case("endogaussian", "endogaussian", "pulling"),
            Case("endogsg-no-depth", "endogsg", "pulling", ("losses.depth.weight=0",)),
            Case("endogsg-no-proj-ori", "endogsg", "pulling",
                 ("losses.projection.weight=0", "losses.orientation.weight=0")),
            Case("endogsg-no-sda", "endogsg", "pulling", ("losses.sda.weight=0",)),
            Case("endoplanar", "endoplanar", "pulling"),
        ),
        metrics=("gaussians_p2s_mean_mm", "gaussians_p2s_mean_ratio", "gaussians_p2s_p95_mm",
                 "fscore_1mm", "chamfer_mm", "mesh_p2s_median_mm", "mesh_coverage",
                 "mesh_largest_hole_cells", "mesh_export_seconds", "psnr_tissue",
                 "psnr_occluded", "depth_rmse_mm"),
        baseline="deform3dgs", ratio_metrics=("gaussians_p2s_mean_mm",)),
    "drawer": Suite(
        cases=(
            Case("deform3dgs", "deform3dgs", "pulling"),
            Case("endogsg", "endogsg", "pulling"),
            Case("drawer", "drawer", "pulling", export_mesh=True),
        ),
        metrics=("psnr_tissue", "psnr_tissue_gain", "psnr_occluded", "gaussians_p2s_mean_mm",
                 "gaussians_p2s_median_mm",
                 "gaussians_p2s_p95_mm", "mesh_p2s_median_mm", "mesh_coverage",
                 "mesh_export_seconds", "depth_rmse_mm"),
        baseline="endogsg"),
    "lumistate": Suite(
        cases=(
            Case("deform3dgs-livar", "deform3dgs", "livar"),
            Case("lumistate-livar", "lumistate", "livar", LUMISTATE_STAGES),
            Case("deform3dgs-hivar", "deform3dgs", "hivar"),
            Case("lumistate-hivar", "lumistate", "hivar", LUMISTATE_STAGES),
            Case("lumistate-hivar-stage1-only", "lumistate", "hivar", STAGE1_ONLY),
        ),
        metrics=("psnr_tissue", "psnr_tissue_gain", "ssim", "reflectance_error",
                 "reflectance_error_ratio", "r_var", "r_var_ratio", "shading_error"),
        baseline="deform3dgs-hivar", ratio_metrics=("reflectance_error", "r_var"),
        baseline_by_phantom=True),
    "physiosplat": Suite(
        cases=(
            Case("deform3dgs", "deform3dgs", "pulling"),
            Case("endogaussian", "endogaussian", "pulling"),
            Case("physiosplat-b-decomposition", "physiosplat", "pulling",
                 PHYSIOSPLAT_WITHOUT_BIOMECHANICS + PHYSIOSPLAT_WITHOUT_SPECULAR),
            Case("physiosplat-c-biomechanics", "physiosplat", "pulling",
                 PHYSIOSPLAT_WITHOUT_SPECULAR),
            Case("physiosplat", "physiosplat", "pulling"),
            Case("physiosplat-masks-dilated-10px", "physiosplat", "pulling",
                 ("train.tool_mask_offset_px=10",)),
            Case("physiosplat-masks-eroded-10px", "physiosplat", "pulling",
                 ("train.tool_mask_offset_px=-10",)),
        ),
        metrics=("psnr_tissue", "ssim", "psnr_occluded", "depth_rmse_occluded_mm", "psnr_specular",
                 "depth_rmse_mm", "chamfer_mm", "collisions", "arap_strain_mean"),
        baseline="endogaussian"),
}


def surgsplat(*args: str) -> None:
    subprocess.run([*SURGSPLAT, *args], check=True, stdout=subprocess.DEVNULL)


def phantom_dir(work: Path, key: str) -> Path:
    folder = work / f"phantom-{key}"
    if not (folder / "poses_bounds.npy").is_file():
        surgsplat("phantom", "--out", str(folder), *PHANTOMS[key])
    return folder


def run_case(case: Case, work: Path, iterations: int | None) -> dict:
    scene = phantom_dir(work, case.phantom)
    run_dir = work / f"run-{case.name}"
    subprocess.run(["rm", "-rf", str(run_dir)], check=True)
    options = [arg for setting in case.settings for arg in ("--set", setting)]
    if iterations:
        options += ["--iters", str(iterations)]
    started = time.perf_counter()
    surgsplat("train", "--method", case.method, "--data", str(scene), "--out", str(run_dir),
              *options)
    wall = time.perf_counter() - started
    surgsplat("eval", str(run_dir))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    if case.export_mesh:
        started = time.perf_counter()
        surgsplat("export", str(run_dir), "--mesh", "--frames", "all")
        metrics["mesh_export_seconds"] = time.perf_counter() - started
    row = {"case": case.name, "method": case.method, "phantom": case.phantom,
           "settings": list(case.settings), "iterations": metrics["iteration"],
           "wall_seconds": round(wall, 1)}
    row.update({key: value for key, value in metrics.items()
                if isinstance(value, (int, float)) and key not in row})
    return row


def baseline_row(rows: list[dict], row: dict, suite: Suite) -> dict | None:
    """The row `row` is compared with: the suite's baseline case, or with baseline_by_phantom
    the baseline's method on `row`'s phantom."""
    base = next((r for r in rows if r["case"] == suite.baseline), None)
    if base is not None and suite.baseline_by_phantom:
        base = next((r for r in rows if r["method"] == base["method"]
                     and r["phantom"] == row["phantom"] and not r["settings"]), None)
    return base


def add_ratios(rows: list[dict], suite: Suite) -> None:
    """Train time and the suite's ratio metrics of each row, as ratios to its baseline row, and
    the PSNR gain over it (dB)."""
    for row in rows:
        base = baseline_row(rows, row, suite)
        if base is None:
            continue
        row["train_time_ratio"] = round(row["train_seconds"] / base["train_seconds"], 3)
        row["psnr_tissue_gain"] = round(row["psnr_tissue"] - base["psnr_tissue"], 3)
        for key in suite.ratio_metrics:
            if row.get(key) is not None and base.get(key):
                row[f"{key.removesuffix('_mm')}_ratio"] = round(row[key] / base[key], 3)


def print_table(rows: list[dict], columns: tuple[str, ...]) -> None:
    keys = ("case", "iterations") + columns
    print(" | ".join(keys))
    for row in rows:
        print(" | ".join(f"{row[k]:.3f}" if isinstance(row.get(k), float) else str(row.get(k, ""))
                         for k in keys))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--suite", required=True, choices=sorted(SUITES))
    parser.add_argument("--json", action="store_true", help="print the rows as JSON lines")
    parser.add_argument("--iters", type=int, default=None, help="override preset iterations")
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "surgsplat-bench-methods")
    parser.add_argument("--cases", nargs="+", default=None,
                        help="run only these cases of the suite (default: all)")
    parser.add_argument("--out", type=Path, default=None, help="result file (default "
                        "benchmarks/results/bench_methods_<suite>-<cpu>-<best ISA>.json)")
    parser.add_argument("--collect", type=Path, default=None, metavar="LOG",
                        help="run nothing: write the report from the rows an interrupted "
                             "`--json` run printed to LOG (its cases that finished)")
    args = parser.parse_args()
    suite = SUITES[args.suite]
    names = [case.name for case in suite.cases]
    unknown = set(args.cases or ()) - set(names)
    if unknown:
        parser.error(f"suite {args.suite} has no case {sorted(unknown)}; it has {names}")
    if args.collect:
        rows = [json.loads(line) for line in args.collect.read_text().splitlines()
                if line.startswith('{"case"')]
    else:
        args.work.mkdir(parents=True, exist_ok=True)
        rows = []
        for case in suite.cases:
            if args.cases is None or case.name in args.cases:
                rows.append(run_case(case, args.work, args.iters))
                print(json.dumps(rows[-1]) if args.json else f"done: {rows[-1]['case']}",
                      flush=True)
    add_ratios(rows, suite)
    columns = suite.metrics + RUN_COLUMNS
    info = system_info()
    report = {"benchmark": "bench_methods", "suite": args.suite, "columns": list(columns),
              "cpu": info["cpu"], "system": info,
              "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "command": " ".join(["python", "benchmarks/bench_methods.py", *sys.argv[1:]]),
              "rows": rows}
    if args.collect:
        done = {row["case"] for row in rows}
        report["note"] = ("collected from the rows printed by an interrupted run; cases not "
                          "finished: " + (", ".join(case.name for case in suite.cases
                                                    if case.name not in done) or "none"))
    out = args.out or results_path(f"bench_methods_{args.suite}", info)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    if not args.json:
        print_table(rows, columns)
    print(f"results: {out}")


if __name__ == "__main__":
    main()
