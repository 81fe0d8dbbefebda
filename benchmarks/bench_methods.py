"""Method ablations on the full phantom, in suites (one per paper): each run is `surgsplat train`
then `surgsplat eval` in its own process (so train seconds, wall time including start-up, and
peak RSS are each run's own).

    python benchmarks/bench_methods.py --suite NAME [--json] [--iters N] [--work DIR]
                                       [--cases NAME ...] [--seeds S ...] [--jobs J] [--merge]

A suite lists its cases, the metrics it reports and the case each row is compared with (its
`base`, or the suite's baseline); every ratio is against a row of the same results file. With
several `--seeds`, every case runs once per seed (`train.seed` and `init.seed`) and the report
has one row per case with the mean of each metric and the values of each seed
(`<metric>_seeds`). `--jobs J` trains J cases at once, each with `--threads` = CPUs / J;
`--merge` keeps the rows of the results file that this invocation does not run again, so a
long suite can be run in parts. Besides each run's training wall time (`train_seconds`, from
its log), the CPU time of its `surgsplat train` process (`train_cpu_seconds`, start-up
included) is recorded: with one thread per job it is the measure of work that a shared, busy
machine leaves comparable, and the fidelity suite's time targets use it. Results go to
benchmarks/results/bench_methods_<suite>-<cpu>-<best ISA>.json and become the README region
`bench_methods_<suite>` (benchmarks/readme_tables.py).

Suite `fidelity` (issue 28): every paper preset beside the preset it extends, at its own full
schedule (the preset's `train.iterations`, 3000): endogsg and physiosplat beside endogaussian,
endoplanar and lumistate beside deform3dgs, drawer beside endogsg; lumistate and deform3dgs on
the hivar lighting phantom; every preset once more on the moving-camera phantom, beside
deform3dgs there; and issue 33's `surgsplat` on each of the three phantoms, whose targets are
the best of the single presets on the same phantom. The livar phantom's images are the standard
phantom's (it adds the true shading only), so issue 28's livar target is checked on the
standard rows. Its TARGETS are checked in the report (`targets`: each with the measured value,
the bound and whether it is met), on the means over the seeds.

Suite `surgsplat` (issue 33): the combined preset, its leave-one-out rows, each without one
paper's part (EndoPlanar's discs, LumiState's decomposition), and the row with the part it left
out after measuring it (Endo-GSG's SDF).

Suite `real` (issue 33): deform3dgs and surgsplat on the real samples of ../shared/data
(REAL_SCENES: the CholecSeg8k clip, the SCARED stereo pair), each imported once into the work
folder. Target: surgsplat's psnr_tissue at least deform3dgs's on each.

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
a third of the run, whatever --iters is. Targets
(hivar): lumistate psnr_tissue >= deform3dgs + 1 dB, reflectance_error and r_var <= 0.5 x
deform3dgs's (the naive baseline: its rendered colour scored as reflectance); livar: no PSNR
loss over 0.3 dB; training time <= 1.5 x deform3dgs.

Suite `drawer` (issue 16): deform3dgs, endogsg and drawer (endogsg's components with Gaussians
anchored on the SDF's mesh, plus PhysioSplat's tool field); the mesh export of every frame is
timed for drawer. Targets: drawer psnr_tissue within 1 dB of endogsg, mesh P2S median <= 0.5 mm.

Suite `speed` (issue 52): the levers of training speed, each at full length beside the preset
as it is: coarse-to-fine resolution (the first 30 % of the run at 1/4 then 1/2 of the size, or
the first 10 % at 1/2), shorter schedules (2500, 2000, 1500 iterations), fewer initial points,
and HexPlane's rates at 10x (endogaussian).

Suite `physiosplat` (issue 14): deform3dgs; endogaussian, which is PhysioSplat's Table 2 row (a)
(the monolithic HexPlane 4DGS baseline); rows (b) +tool/tissue decomposition, (c) +biomechanics
and (d) +specular (the full `physiosplat` preset); and the full preset trained with tool masks
dilated and eroded by 10 px (`train.tool_mask_offset_px`). Targets: physiosplat psnr_occluded
>= 3 dB above the better of deform3dgs and endogaussian, psnr_tissue no lower than
endogaussian, 0 collisions, training time <= 2x endogaussian, peak RSS <= 4 GB.
The tool's edge (`tool_edges` metrics) is reported beside them: the rendered tool probability
over the mask and at 3 and 10 px outside it, and the depth bias of the tissue within 10 px of
the tool and beyond. `physiosplat-edge-band-5px` is the full preset whose tissue learns less
from the 5 px beside the tool mask (`components.tool.edge_band_px`). Since issue 55 the preset's
tool field is articulated and fills the tissue no frame shows; `physiosplat-rigid` is the
paper's rigid tool field, and the articulated field's articulation (`jaw_angle_rmse_deg`,
`hinge_offset_mm`) is the model's own (the rigid one's is estimated after training). The
`grasping` phantom (the tool in every frame, its jaws opening to 60 degrees three times) runs
endogaussian and both tool fields again, with the never-seen tissue scored (`*_never_seen`,
`tool_free_transparent_fraction`).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import results_path  # noqa: E402

from surgsplat.atomic import write_text_atomic  # noqa: E402
from surgsplat.methods.endogsg.preset import ENDO_GSG_GAMMA, endogsg  # noqa: E402
from surgsplat.render.native import system_info  # noqa: E402

SURGSPLAT = [sys.executable, "-m", "surgsplat.cli.main"]
RUN_COLUMNS = ("train_seconds", "train_time_ratio", "train_cpu_seconds", "train_cpu_ratio",
               "wall_seconds", "num_gaussians", "peak_rss_mb")
"""Columns every suite reports after its own metrics."""


@dataclass(frozen=True)
class Case:
    """One row of the ablation."""

    name: str
    method: str
    phantom: str  # key of PHANTOMS, or of REAL_SCENES
    settings: tuple[str, ...] = ()  # --set assignments
    export_mesh: bool = False  # also time `surgsplat export --mesh` of every frame
    base: str | None = None  # case this row's ratios refer to (None: the suite's baseline)


PHANTOMS = {"pulling": ("--preset", "full", "--motion", "pulling"),
            "pulling-moving-camera": ("--preset", "full", "--motion", "pulling",
                                      "--camera", "moving"),
            "livar": ("--preset", "full", "--motion", "pulling", "--lighting", "livar"),
            "hivar": ("--preset", "full", "--motion", "pulling", "--lighting", "hivar"),
            "grasping": ("--preset", "full", "--motion", "grasping")}
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SCARED_FOCAL_PX, SCARED_BASELINE_MM = 517.0, 4.2
"""The SCARED pair's camera, assumed (the sample ships no calibration): half the dataset's
full-resolution focal length, and a da Vinci stereo baseline. They set the scene's scale in
millimetres, the same for every case."""
@dataclass(frozen=True)
class RealScene:
    """A real sample of ../shared/data and how a case imports and evaluates it."""

    folder: str  # under the shared data folder
    import_options: tuple[str, ...]  # of `surgsplat import`; {source} is the sample's folder
    eval_options: tuple[str, ...] = ()  # of `surgsplat eval`


REAL_SCENES = {
    "cholecseg8k": RealScene("cholecseg8k-clip", (
        "--pattern", "*_endo.png", "--masks", "{source}", "--mask-pattern",
        "*_endo_watershed_mask.png", "--tool-labels", "31,32", "--allow-missing-masks")),
    "scared": RealScene("scared-stereo-sample/left", (
        "--right", "{source}/../right", "--focal", str(SCARED_FOCAL_PX),
        "--baseline", str(SCARED_BASELINE_MM)), ("--frames", "train")),
}
"""Scenes imported from the real samples in ../shared/data (never copied into the repository):
the CholecSeg8k clip with its tool labels (static camera, no depth) and the SCARED stereo pair
(one frame, depth from stereo, no held-out frame: its metrics are of the training frame)."""
STAGE1_ONLY = ("losses.retinex.weight=0", "losses.bright_channel.weight=0",
               "losses.illumination_transfer.weight=0")
"""`lumistate` without its Stage 2: none of the terms that start there (the Retinex, bright-channel
and illumination-transfer terms; with the bright channel off, the tie alone would tie the
modulation to an illumination map that nothing anchors)."""


@dataclass(frozen=True)
class Suite:
    """The ablation of one paper: its rows, the metrics shown, and the row ratios refer to."""

    cases: tuple[Case, ...]
    metrics: tuple[str, ...]  # keys of metrics.json shown, in order
    baseline: str  # name of the case ratios are taken against
    ratio_metrics: tuple[str, ...] = ()  # metrics also reported as <key>_ratio to the baseline
    baseline_by_phantom: bool = False  # ratios against the baseline's method on each row's phantom
    targets: tuple["Target", ...] = ()  # checked on the rows in the report


PHYSIOSPLAT_WITHOUT_BIOMECHANICS = (
    "components.biomechanics=null", "losses.strain=null", "losses.collision=null",
    "components.deformation.volume_samples=0", "losses.volume=null")
PHYSIOSPLAT_WITHOUT_SPECULAR = ("components.specular=null",)
"""Row (c) keeps the preset's diffuse SH degree 0, so that rows (c) and (d) differ by the
specular lobe alone."""


ENDO_GSG_SDF_LOSSES = ("eikonal", "projection", "orientation", "sda")
SURGSPLAT_WITH_SDF = (
    'components.sdf={"kind": "sdf"}',
    f"components.photometric.occlusion_gamma={ENDO_GSG_GAMMA}",
    f"components.depth.occlusion_gamma={ENDO_GSG_GAMMA}",
    *(f"losses.{term}={json.dumps(asdict(endogsg().losses[term]))}"
      for term in ENDO_GSG_SDF_LOSSES))
"""The `surgsplat` preset with Endo-GSG's part added: its SDF, the SDF's losses and the occlusion
importance map, at the endogsg preset's values (what the preset had before issue 33's
leave-one-out measured it)."""
PHYSIOSPLAT_RIGID = ("components.tool.motion=rigid", "components.tool.fill_never_seen=false")
"""The paper's tool field: one rigid pose per frame, nothing filled where no frame sees the
tissue (the presets' tool field is articulated and fills it since issue 55)."""
SURGSPLAT_WITHOUT_PLANAR = ("components.planar=null", "losses.flatten=null", "losses.normal=null",
                            "gaussians.init_thickness=1")
SURGSPLAT_WITHOUT_LUMISTATE = ("components.lumistate=null", "losses.retinex=null",
                               "losses.bright_channel=null", "losses.illumination_transfer=null")


FIDELITY_PRESETS = {"endogsg": "endogaussian", "physiosplat": "endogaussian",
                    "endoplanar": "deform3dgs", "lumistate": "deform3dgs", "drawer": "endogsg"}
"""Each paper preset and the preset it extends (its base)."""
FIDELITY_CASES = (
    Case("deform3dgs", "deform3dgs", "pulling"),
    Case("endogaussian", "endogaussian", "pulling", base="deform3dgs"),
    *(Case(name, name, "pulling", base=base, export_mesh=name in ("endogsg", "drawer"))
      for name, base in FIDELITY_PRESETS.items()),
    Case("surgsplat", "surgsplat", "pulling"),
    Case("deform3dgs-hivar", "deform3dgs", "hivar"),
    Case("lumistate-hivar", "lumistate", "hivar", base="deform3dgs-hivar"),
    Case("surgsplat-hivar", "surgsplat", "hivar", base="deform3dgs-hivar"),
    Case("deform3dgs-moving", "deform3dgs", "pulling-moving-camera"),
    *(Case(f"{name}-moving", name, "pulling-moving-camera", base="deform3dgs-moving")
      for name in ("endogaussian", *FIDELITY_PRESETS, "surgsplat")),
)
SINGLE_PRESETS = ("deform3dgs", "endogaussian", *FIDELITY_PRESETS)
"""The presets of one paper (or baseline) each, which the combined `surgsplat` must match."""


@dataclass(frozen=True)
class Target:
    """A bound on one metric of one case: value >= bound (at_least) or <= bound, where the
    bound is `limit` alone, or `limit` added to (relative=False, e.g. dB) or multiplied by
    (relative=True) the references' value: the largest of them for at_least, else the
    smallest. The references' value is their `reference_metric` when given, else `metric`."""

    case: str
    metric: str
    at_least: bool
    limit: float
    references: tuple[str, ...] = ()
    relative: bool = False
    reference_metric: str | None = None

    def check(self, rows: dict[str, dict]) -> dict | None:
        """The target as measured on `rows` (by case), or None when a row or value is missing."""
        value = rows.get(self.case, {}).get(self.metric)
        refs = [rows.get(name, {}).get(self.reference_metric or self.metric)
                for name in self.references]
        if value is None or any(ref is None for ref in refs):
            return None
        bound = self.limit
        if refs:
            ref = max(refs) if self.at_least else min(refs)
            bound = ref * self.limit if self.relative else ref + self.limit
        met = value >= bound if self.at_least else value <= bound
        return {"case": self.case, "metric": self.metric, "value": value,
                "relation": ">=" if self.at_least else "<=", "bound": float(f"{bound:.4g}"),
                "rule": self.describe(), "met": bool(met)}

    def describe(self) -> str:
        relation = ">=" if self.at_least else "<="
        if not self.references:
            return f"{self.metric} {relation} {self.limit:g}"
        refs = " / ".join(self.references)
        if self.reference_metric:
            refs = f"{refs}'s {self.reference_metric}"
        ref = refs
        if len(self.references) > 1:
            ref = f"{'max' if self.at_least else 'min'}({refs})"
        bound = f"{self.limit:g} x {ref}" if self.relative else f"{ref} {self.limit:+g}"
        return f"{self.metric} {relation} {bound}"


def preset_targets(name: str, base: str) -> tuple[Target, ...]:
    """What every preset must deliver beside its base (issue 28): tissue PSNR within 0.3 dB of
    the better of deform3dgs and the base, and at most 1.5x the base's training time."""
    references = tuple(dict.fromkeys(("deform3dgs", base)))
    return (Target(name, "psnr_tissue", True, -0.3, references),
            Target(name, "train_cpu_seconds", False, 1.5, (base,), relative=True))


FIDELITY_TARGETS = (
    *(target for name, base in FIDELITY_PRESETS.items() for target in preset_targets(name, base)),
    Target("endogsg", "gaussians_p2s_weighted_median_mm", False, 0.5, ("endogaussian",),
           relative=True),
    Target("endogsg", "mesh_p2s_median_mm", False, 0.3),
    Target("endogsg", "psnr_occluded", True, 0.0, ("endogaussian",)),
    Target("physiosplat", "psnr_occluded", True, 1.0, ("endogaussian",)),
    Target("physiosplat", "depth_rmse_occluded_mm", False, 0.8, ("endogaussian",), relative=True),
    Target("physiosplat", "depth_rmse_mm", False, 1.2, ("endogaussian",), relative=True),
    Target("physiosplat", "psnr_specular", True, 1.0, ("endogaussian",)),
    Target("physiosplat", "collision_fraction", False, 0.0, ("physiosplat",),
           reference_metric="collision_fraction_truth"),
    Target("lumistate-hivar", "psnr_tissue", True, 0.5, ("deform3dgs-hivar",)),
    Target("lumistate", "psnr_tissue", True, -0.2, ("deform3dgs",)),  # livar = standard images
    Target("lumistate-hivar", "reflectance_error", False, 0.5, ("deform3dgs-hivar",),
           relative=True),
    Target("endoplanar", "normal_error_deg_median", False, 0.5, ("deform3dgs",), relative=True),
    Target("endoplanar", "depth_rmse_mm", False, 1.0, ("deform3dgs",), relative=True),
    Target("drawer", "mesh_p2s_median_mm", False, 0.3),
    Target("drawer", "hinge_axis_error_deg", False, 5.0),
    Target("drawer", "jaw_angle_rmse_deg", False, 3.0),
)
"""Issues 28 and 55's targets on the full phantom; reflectance_error's "naive" reference is
deform3dgs's rendered colour scored as reflectance on the same phantom."""


SURGSPLAT_BEST_OF = {"psnr_tissue": True, "psnr_occluded": True, "depth_rmse_mm": False,
                     "normal_error_deg_median": False, "gaussians_p2s_weighted_median_mm": False,
                     "mesh_p2s_median_mm": False, "reflectance_error": False}
"""Issue 33's metrics on which `surgsplat` must match the best single preset (True: higher is
better)."""


def surgsplat_targets(suffix: str, singles: tuple[str, ...]) -> tuple[Target, ...]:
    """Issue 33's targets of the case `surgsplat<suffix>` against the single presets' rows
    `singles` on the same phantom: the best of them on every metric of SURGSPLAT_BEST_OF, at
    most 2x deform3dgs's training time, at most 4 GB of peak RSS."""
    case = f"surgsplat{suffix}"
    return (*(Target(case, metric, higher, 0.0, singles)
              for metric, higher in SURGSPLAT_BEST_OF.items()),
            Target(case, "train_cpu_seconds", False, 2.0, (f"deform3dgs{suffix}",),
                   relative=True),
            Target(case, "peak_rss_mb", False, 4096.0))


SURGSPLAT_TARGETS = (
    *surgsplat_targets("", SINGLE_PRESETS),
    *surgsplat_targets("-hivar", ("deform3dgs-hivar", "lumistate-hivar")),
    *surgsplat_targets("-moving", tuple(f"{name}-moving" for name in SINGLE_PRESETS)),
)


COARSE_TO_FINE = ("train.coarse_fraction=0.3", "train.coarse_factor=4")
"""The coarse-to-fine lever: the first 30 % of the run on frames at 1/4, then 1/2 of the size."""
SPEED_CASES = (
    Case("deform3dgs", "deform3dgs", "pulling"),
    Case("deform3dgs-coarse-to-fine", "deform3dgs", "pulling", COARSE_TO_FINE),
    Case("deform3dgs-2000", "deform3dgs", "pulling", ("train.iterations=2000",)),
    Case("deform3dgs-1500", "deform3dgs", "pulling", ("train.iterations=1500",)),
)
"""Issue 52's levers, each an A/B against the preset as it is, at full length."""
HEXPLANE_FAST = ("components.deformation.grid_lr=0.016", "components.deformation.mlp_lr=0.0016")
"""HexPlane's planes and MLP at 10x the rates of 4DGS' 14000-iteration schedule."""
FEWER_POINTS_BUDGETED = ("init.max_points=30000", "densify.kind=budget",
                         "densify.budget_final=1.2")
"""30000 initial points grown by budgeted densification to 1.2 times (36000, the count the
threshold strategy reaches from 30000)."""
COARSE_START = ("train.coarse_fraction=0.1", "train.coarse_factor=2")
"""The first 10 % of the run, before densification starts, on frames at half the size."""
SPEED_CASES += (
    Case("deform3dgs-2500", "deform3dgs", "pulling", ("train.iterations=2500",)),
    Case("deform3dgs-30k-points", "deform3dgs", "pulling", ("init.max_points=30000",)),
    Case("deform3dgs-coarse-before-densify", "deform3dgs", "pulling", COARSE_START),
    Case("endogaussian", "endogaussian", "pulling", base="deform3dgs"),
    Case("endogaussian-fast-hexplane", "endogaussian", "pulling", HEXPLANE_FAST,
         base="endogaussian"),
    Case("deform3dgs-budget", "deform3dgs", "pulling", ("densify.kind=budget",)),
    Case("deform3dgs-30k-points-budget", "deform3dgs", "pulling", FEWER_POINTS_BUDGETED),
    Case("deform3dgs-fewer-points-coarse-start", "deform3dgs", "pulling",
         FEWER_POINTS_BUDGETED + COARSE_START),
    Case("surgsplat", "surgsplat", "pulling", base="deform3dgs"),
    Case("surgsplat-coarse-before-densify", "surgsplat", "pulling", COARSE_START,
         base="surgsplat"),
    Case("surgsplat-fewer-points-coarse-start", "surgsplat", "pulling",
         FEWER_POINTS_BUDGETED + COARSE_START, base="surgsplat"),
    Case("deform3dgs-cholecseg8k", "deform3dgs", "cholecseg8k", base="deform3dgs-cholecseg8k"),
    Case("deform3dgs-cholecseg8k-coarse-start", "deform3dgs", "cholecseg8k", COARSE_START,
         base="deform3dgs-cholecseg8k"),
)
FULL_SIZE_START = ("train.coarse_fraction=0", "train.coarse_factor=1")
"""Every step at full size: deform3dgs as it was before its coarse start (COARSE_START), which
the rows deform3dgs-coarse-before-densify and deform3dgs-cholecseg8k-coarse-start measured
against the preset without it; the preset has it now, and these cases measure its absence."""
SPEED_CASES += (
    Case("deform3dgs-full-size-start", "deform3dgs", "pulling", FULL_SIZE_START),
    Case("deform3dgs-cholecseg8k-full-size-start", "deform3dgs", "cholecseg8k", FULL_SIZE_START,
         base="deform3dgs-cholecseg8k"),
)
HEXPLANE_FAST_GRID = ("components.deformation.grid_lr=0.05", "components.deformation.lr_decay=0.01")
"""HexPlane's planes at about 30x their rate, decayed 100x over the run (to 3x the rate they
end at by default)."""
SPEED_CASES += (
    Case("endogaussian-1000", "endogaussian", "pulling", ("train.iterations=1000",),
         base="endogaussian"),
    Case("endogaussian-1000-fast-grid", "endogaussian", "pulling",
         ("train.iterations=1000",) + HEXPLANE_FAST_GRID, base="endogaussian-1000"),
    Case("endogaussian-fast-grid", "endogaussian", "pulling", HEXPLANE_FAST_GRID,
         base="endogaussian"),
)
HEXPLANE_FAST_TIME = ("components.deformation.time_grid_lr=0.05",
                      "components.deformation.lr_decay=0.01")
"""HexPlane's spatio-temporal planes at about 30x their rate, every rate of the field decayed
100x over the run; the spatial planes and the MLP at their rates."""
SPEED_CASES += (
    Case("endogaussian-1000-fast-time", "endogaussian", "pulling",
         ("train.iterations=1000",) + HEXPLANE_FAST_TIME, base="endogaussian-1000"),
    Case("endogaussian-fast-time", "endogaussian", "pulling", HEXPLANE_FAST_TIME,
         base="endogaussian"),
    Case("surgsplat-1000", "surgsplat", "pulling", ("train.iterations=1000",), base="surgsplat"),
    Case("surgsplat-1000-fast-time", "surgsplat", "pulling",
         ("train.iterations=1000",) + HEXPLANE_FAST_TIME, base="surgsplat-1000"),
    Case("surgsplat-fast-time", "surgsplat", "pulling", HEXPLANE_FAST_TIME, base="surgsplat"),
)
SPEED_CASES += tuple(  # the other HexPlane presets, each beside itself
    case for name in ("endogsg", "physiosplat", "drawer") for case in (
        Case(name, name, "pulling", base=name),
        Case(f"{name}-fast-time", name, "pulling", HEXPLANE_FAST_TIME, base=name)))


SUITES = {
    "fidelity": Suite(
        cases=FIDELITY_CASES,
        metrics=("psnr_tissue", "psnr_tissue_gain", "psnr_occluded", "depth_rmse_occluded_mm",
                 "psnr_specular", "psnr_outside_highlights",
                 "depth_rmse_mm", "normal_error_deg_median",
                 "gaussians_p2s_median_mm", "gaussians_p2s_weighted_median_mm",
                 "mesh_p2s_median_mm", "reflectance_error", "collisions", "collision_fraction",
                 "collision_fraction_truth",
                 "hinge_axis_error_deg", "jaw_angle_rmse_deg"),
        baseline="deform3dgs", targets=FIDELITY_TARGETS + SURGSPLAT_TARGETS),
    "surgsplat": Suite(
        cases=(
            Case("surgsplat", "surgsplat", "pulling"),
            Case("surgsplat-with-sdf", "surgsplat", "pulling", SURGSPLAT_WITH_SDF),
            Case("surgsplat-no-planar", "surgsplat", "pulling", SURGSPLAT_WITHOUT_PLANAR),
            Case("surgsplat-no-lumistate", "surgsplat", "pulling", SURGSPLAT_WITHOUT_LUMISTATE),
        ),
        metrics=("psnr_tissue", "psnr_tissue_gain", "psnr_occluded", "depth_rmse_mm",
                 "normal_error_deg_median", "gaussians_p2s_weighted_median_mm",
                 "mesh_p2s_median_mm", "reflectance_error"),
        baseline="surgsplat"),
    "real": Suite(
        cases=tuple(case for key in REAL_SCENES for case in (
            Case(f"deform3dgs-{key}", "deform3dgs", key),
            Case(f"surgsplat-{key}", "surgsplat", key, base=f"deform3dgs-{key}"))),
        metrics=("psnr_tissue", "psnr_tissue_gain", "ssim_tissue", "depth_rmse_mm"),
        baseline="deform3dgs-cholecseg8k", baseline_by_phantom=True,
        targets=tuple(Target(f"surgsplat-{key}", "psnr_tissue", True, 0.0,
                             (f"deform3dgs-{key}",)) for key in REAL_SCENES)),
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
            Case("drawer-no-anchor", "drawer", "pulling", ("components.anchor=null",),
                 export_mesh=True),
            Case("drawer-no-tool", "drawer", "pulling",
                 ("components.tool=null", "losses.mask=null"), export_mesh=True),
        ),
        metrics=("psnr_tissue", "psnr_tissue_gain", "psnr_occluded", "gaussians_p2s_mean_mm",
                 "gaussians_p2s_median_mm",
                 "gaussians_p2s_p95_mm", "mesh_p2s_median_mm", "mesh_coverage",
                 "mesh_export_seconds", "depth_rmse_mm", "jaw_angle_rmse_deg", "hinge_offset_mm"),
        baseline="endogsg"),
    "lumistate": Suite(
        cases=(
            Case("deform3dgs-livar", "deform3dgs", "livar"),
            Case("lumistate-livar", "lumistate", "livar"),
            Case("deform3dgs-hivar", "deform3dgs", "hivar"),
            Case("lumistate-hivar", "lumistate", "hivar"),
            Case("lumistate-hivar-stage1-only", "lumistate", "hivar", STAGE1_ONLY),
        ),
        metrics=("psnr_tissue", "psnr_tissue_gain", "ssim", "reflectance_error",
                 "reflectance_error_ratio", "r_var", "r_var_ratio", "shading_error"),
        baseline="deform3dgs-hivar", ratio_metrics=("reflectance_error", "r_var"),
        baseline_by_phantom=True),
    "speed": Suite(cases=SPEED_CASES,
                   metrics=("psnr_tissue", "psnr_tissue_gain", "depth_rmse_mm",
                            "normal_error_deg_median"),
                   baseline="deform3dgs", baseline_by_phantom=False),
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
            Case("physiosplat-edge-band-5px", "physiosplat", "pulling",
                 ("components.tool.edge_band_px=5",)),
            Case("physiosplat-rigid", "physiosplat", "pulling", PHYSIOSPLAT_RIGID),
            Case("physiosplat-tool-depth", "physiosplat", "pulling",
                 ("components.depth.tool_pixels=true",)),
            Case("physiosplat-tool-depth-densify", "physiosplat", "pulling",
                 ("components.depth.tool_pixels=true", "components.tool.densify_tool=true")),
            Case("physiosplat-tool-depth-densify-mask-1", "physiosplat", "pulling",
                 ("components.depth.tool_pixels=true", "components.tool.densify_tool=true",
                  "losses.mask.weight=1.0")),
            Case("physiosplat-tool-depth-densify-pose-lr-3x", "physiosplat", "pulling",
                 ("components.depth.tool_pixels=true", "components.tool.densify_tool=true",
                  "components.tool.rotation_lr=0.003", "components.tool.translation_lr=0.003")),
            Case("endogaussian-grasping", "endogaussian", "grasping"),
            Case("physiosplat-grasping", "physiosplat", "grasping",
                 base="endogaussian-grasping"),
            Case("physiosplat-rigid-grasping", "physiosplat", "grasping", PHYSIOSPLAT_RIGID,
                 base="endogaussian-grasping"),
        ),
        metrics=("psnr_tissue", "ssim", "psnr_occluded", "depth_rmse_occluded_mm", "psnr_specular",
                 "depth_rmse_mm", "chamfer_mm", "collisions", "arap_strain_mean",
                 "tool_probability_inside", "tool_probability_3px", "tool_probability_10px",
                 "depth_bias_near_tool_mm", "depth_bias_away_from_tool_mm",
                 "tissue_depth_bias_near_tool_mm", "jaw_angle_rmse_deg", "hinge_offset_mm",
                 "psnr_never_seen", "depth_rmse_never_seen_mm", "tool_free_transparent_fraction"),
        baseline="endogaussian"),
}


def surgsplat(*args: str) -> float:
    """Run `surgsplat *args`; the CPU seconds (user + system) the process used. On a shared
    machine a single-threaded run's CPU time measures its work where wall time also measures
    the other processes."""
    process = subprocess.Popen([*SURGSPLAT, *args], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise subprocess.CalledProcessError(process.returncode, process.args)
    return usage.ru_utime + usage.ru_stime


def phantom_dir(work: Path, key: str, shared_data: Path = SHARED_DATA) -> Path:
    """The scene of `key` under `work`: the phantom of PHANTOMS[key] generated there, or the
    real sample of REAL_SCENES[key] (under `shared_data`) imported there, unless it already
    is (see prepared_scene: runs asking for it at once, --jobs, share one)."""
    if key in REAL_SCENES:
        real = REAL_SCENES[key]
        source = shared_data / real.folder
        if not source.is_dir():
            raise SystemExit(f"{source}: no such folder; the real-data cases need the shared "
                             f"samples (--shared-data, default ../shared/data beside the "
                             f"repository)")
        options = [option.format(source=source) for option in real.import_options]
        return prepared_scene(work / f"scene-{key}", lambda scene: surgsplat(
            "import", str(source), "--out", str(scene), *options))
    return prepared_scene(work / f"phantom-{key}", lambda scene: surgsplat(
        "phantom", "--out", str(scene), *PHANTOMS[key]))


def prepared_scene(scene: Path, make: Callable[[Path], object]) -> Path:
    """`scene`, made by `make(folder)` unless it holds a scene (poses_bounds.npy). It is made
    in a temporary folder beside it and renamed into place, so that runs preparing the same
    scene at once never see one part-written: the first rename wins, the others' copies are
    removed."""
    if (scene / "poses_bounds.npy").is_file():
        return scene
    with tempfile.TemporaryDirectory(prefix=f".{scene.name}-", dir=scene.parent) as temporary:
        made = Path(temporary) / scene.name
        make(made)
        try:
            made.rename(scene)
        except OSError:  # another run renamed its copy into place first, or `scene` is in the way
            if not (scene / "poses_bounds.npy").is_file():
                raise SystemExit(f"{scene}: holds no scene (no poses_bounds.npy); remove it "
                                 "and run again") from None
    return scene


def source_commit() -> str | None:
    """The git commit of the surgsplat source this benchmark runs (None outside a checkout), so
    that rows measured at different commits and merged into one file can be told apart."""
    found = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                           text=True, cwd=Path(__file__).resolve().parent)
    return found.stdout.strip() or None if found.returncode == 0 else None


def run_case(case: Case, work: Path, iterations: int | None, seed: int | None,
             threads: int, shared_data: Path = SHARED_DATA) -> dict:
    """Train and evaluate `case` (with `seed` for training and initialisation when given) in
    processes of their own, with `threads` threads; its metrics.json as a row."""
    scene = phantom_dir(work, case.phantom, shared_data)
    run_dir = run_folder(work, case.name, seed)
    subprocess.run(["rm", "-rf", str(run_dir)], check=True)
    settings = case.settings + (() if seed is None else (f"train.seed={seed}", f"init.seed={seed}"))
    options = [arg for setting in settings for arg in ("--set", setting)]
    if iterations:
        options += ["--iters", str(iterations)]
    threading = ("--threads", str(threads))
    started = time.perf_counter()
    train_cpu = surgsplat(*threading, "train", "--method", case.method, "--data", str(scene),
                          "--out", str(run_dir), *options)
    wall = time.perf_counter() - started
    real = REAL_SCENES.get(case.phantom)
    surgsplat(*threading, "eval", str(run_dir), *(real.eval_options if real else ()))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    if case.export_mesh:
        started = time.perf_counter()
        surgsplat(*threading, "export", str(run_dir), "--mesh", "--frames", "all")
        metrics["mesh_export_seconds"] = time.perf_counter() - started
    row = {"case": case.name, "method": case.method, "phantom": case.phantom, "base": case.base,
           "settings": list(case.settings), "seed": seed, "iterations": metrics["iteration"],
           "wall_seconds": round(wall, 1), "train_cpu_seconds": round(train_cpu, 1),
           "threads": threads, "commit": source_commit(),
           "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")}
    row.update({key: value for key, value in metrics.items()
                if isinstance(value, (int, float)) and key not in row})
    return row


def run_folder(work: Path, case: str, seed: int | None) -> Path:
    """The run folder of `case` trained with `seed` under `work`."""
    return work / (f"run-{case}" if seed is None else f"run-{case}-seed{seed}")


def rescore(row: dict, work: Path, threads: int) -> dict:
    """`row` with the metrics of its run folder under `work` evaluated again by the current code
    (`surgsplat eval`: a metric added since it trained); its training columns and commit stay,
    `rescored_commit` names the code that scored it."""
    run_dir = run_folder(work, row["case"], row["seed"])
    real = REAL_SCENES.get(row["phantom"])
    surgsplat("--threads", str(threads), "eval", str(run_dir),
              *(real.eval_options if real else ()))
    metrics = json.loads((run_dir / "metrics.json").read_text())
    training = {"iterations", "wall_seconds", "train_cpu_seconds", "threads", "commit", "date"}
    return {**row, **{key: value for key, value in metrics.items()
                      if isinstance(value, (int, float)) and key not in training},
            "rescored_commit": source_commit()}


def mean_over_seeds(rows: list[dict]) -> list[dict]:
    """One row per case: each number the mean over the case's seeds, with the seeds' values in
    `<key>_seeds` (in seed order) when there is more than one; so are the commits and dates
    when the seeds' differ."""
    cases: dict[str, list[dict]] = {}
    for row in rows:
        cases.setdefault(row["case"], []).append(row)
    merged = []
    for runs in cases.values():
        runs.sort(key=lambda row: -1 if row.get("seed") is None else row["seed"])
        row = dict(runs[0])
        row["seeds"] = [run.get("seed") for run in runs]
        for key, value in runs[0].items():
            values = [run.get(key) for run in runs]
            if (isinstance(value, (int, float)) and not isinstance(value, bool) and key != "seed"
                    and all(isinstance(v, (int, float)) for v in values)):
                row[key] = statistics.fmean(values)
                if len(runs) > 1:
                    row[f"{key}_seeds"] = values
            elif key in ("commit", "date") and len(set(values)) > 1:
                row[f"{key}_seeds"] = values
        row.pop("seed", None)
        merged.append(row)
    return merged


def baseline_row(rows: list[dict], row: dict, suite: Suite) -> dict | None:
    """The row `row` is compared with: its case's base, else the suite's baseline case, or with
    baseline_by_phantom the baseline's method on `row`'s phantom."""
    if row.get("base"):
        return next((r for r in rows if r["case"] == row["base"]), None)
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
        if row.get("train_cpu_seconds") and base.get("train_cpu_seconds"):
            row["train_cpu_ratio"] = round(row["train_cpu_seconds"] / base["train_cpu_seconds"],
                                           3)
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


def run_all(cases: list[Case], seeds: list[int | None], args: argparse.Namespace) -> list[dict]:
    """Every (case, seed) run, `args.jobs` at a time; each row printed as it finishes."""
    threads = args.threads or max((os.cpu_count() or 1) // args.jobs, 1)
    runs = [(case, seed) for seed in seeds for case in cases]
    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(run_case, case, args.work, args.iters, seed, threads,
                               args.shared_data)
                   for case, seed in runs]
        rows = []
        for future in futures:
            rows.append(future.result())
            print(json.dumps(rows[-1]) if args.json else
                  f"done: {rows[-1]['case']} seed {rows[-1]['seed']}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0].replace("\n", " "))
    parser.add_argument("--suite", required=True, choices=sorted(SUITES))
    parser.add_argument("--json", action="store_true", help="print the rows as JSON lines")
    parser.add_argument("--iters", type=int, default=None, help="override preset iterations")
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "surgsplat-bench-methods")
    parser.add_argument("--shared-data", type=Path, default=SHARED_DATA,
                        help="folder of the real samples the real-data cases import (default "
                             "../shared/data beside the repository)")
    parser.add_argument("--cases", nargs="+", default=None,
                        help="run only these cases of the suite (default: all)")
    parser.add_argument("--seeds", nargs="+", type=int, default=None,
                        help="run every case once per seed (default: the presets' seed, once)")
    parser.add_argument("--jobs", type=int, default=1, help="cases trained at once")
    parser.add_argument("--threads", type=int, default=None,
                        help="threads of every run (default: the logical CPUs over --jobs; "
                             "give 1 to match rows measured with one thread while two "
                             "benchmarks share the machine)")
    parser.add_argument("--merge", action="store_true",
                        help="keep the result file's rows of the cases and seeds not run now")
    parser.add_argument("--out", type=Path, default=None, help="result file (default "
                        "benchmarks/results/bench_methods_<suite>-<cpu>-<best ISA>.json)")
    parser.add_argument("--collect", type=Path, default=None, metavar="LOG",
                        help="run nothing: write the report from the rows an interrupted "
                             "`--json` run printed to LOG (its cases that finished)")
    parser.add_argument("--rescore", action="store_true",
                        help="with --collect: evaluate the collected rows' run folders under "
                             "--work again with the current code (a metric added since they "
                             "trained); their training columns stay")
    args = parser.parse_args()
    if args.rescore and not args.collect:
        parser.error("--rescore needs --collect")
    if args.jobs < 1:
        parser.error("--jobs must be at least 1")
    if args.threads is not None and args.threads < 1:
        parser.error("--threads must be at least 1")
    suite = SUITES[args.suite]
    names = [case.name for case in suite.cases]
    unknown = set(args.cases or ()) - set(names)
    if unknown:
        parser.error(f"suite {args.suite} has no case {sorted(unknown)}; it has {names}")
    info = system_info()
    out = args.out or results_path(f"bench_methods_{args.suite}", info)
    if args.collect:
        runs = [json.loads(line) for line in args.collect.read_text().splitlines()
                if line.startswith('{"case"')]
        if args.rescore:
            runs = [rescore(run, args.work, args.threads or 1) for run in runs]
    else:
        args.work.mkdir(parents=True, exist_ok=True)
        chosen = [case for case in suite.cases if args.cases is None or case.name in args.cases]
        runs = run_all(chosen, args.seeds or [None], args)
    commands = [" ".join(["python", "benchmarks/bench_methods.py", *sys.argv[1:]])]
    if args.merge and out.is_file():
        previous = json.loads(out.read_text())
        done = {(run["case"], run.get("seed")) for run in runs}
        runs = [run for run in previous.get("runs", previous["rows"])
                if (run["case"], run.get("seed")) not in done] + runs
        commands = previous.get("commands", [previous["command"]]) + commands
    order = {name: i for i, name in enumerate(names)}
    runs.sort(key=lambda run: (order.get(run["case"], len(order)), run.get("seed") or 0))
    rows = mean_over_seeds(runs)
    add_ratios(rows, suite)
    by_case = {row["case"]: row for row in rows}
    checked = [result for target in suite.targets
               if (result := target.check(by_case)) is not None]
    columns = suite.metrics + RUN_COLUMNS
    report = {"benchmark": "bench_methods", "suite": args.suite, "columns": list(columns),
              "cpu": info["cpu"], "system": info,
              "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "command": commands[-1], "commands": commands, "rows": rows, "runs": runs}
    if checked:
        report["targets"] = checked
    missing = [case.name for case in suite.cases if case.name not in by_case]
    if args.collect or missing:
        report["note"] = ("cases not measured: " + ", ".join(missing)) if missing else \
            "rows collected from the output a run printed (--collect)"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(report, indent=2) + "\n")
    if not args.json:
        print_table(rows, columns)
    print(f"results: {out}")


if __name__ == "__main__":
    main()
