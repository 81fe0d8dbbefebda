"""One self-contained HTML report of one or more runs: metrics with their conventions, training
curves (matplotlib, inlined as PNG), and per test frame the ground truth, the render, an error
heat map and every other channel the model declares (`SplatModel.channel_descriptors`: the
depth, the normals and those its components add), each as its descriptor says
(`export.channel_image`; the depth over the frame's measured depth range). With several runs: a comparison table (with each run's
scene) and overlaid curves; runs are named by their folders relative to the folder holding them
all (a/run and b/run for DIR/a/run and DIR/b/run, as `batch` writes them).

Everything is inlined (base64 images, CSS in the page, no script), so the file opens offline and
can be mailed or attached to a paper's supplement.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from surgsplat.atomic import write_text_atomic
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.eval.geometry_metrics import GEOMETRY_KEYS
from surgsplat.eval.run_metrics import METRICS_FILE, EvalOptions, evaluate_run, frames_scored
from surgsplat.export.channel_image import channel_image, colormap_image, percentile_range
from surgsplat.export.video import to_uint8
from surgsplat.model.channels import DEPTH, RGB, ChannelDescriptor, Colormap
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import SplatModel, render_frame
from surgsplat.train.run import TrainedRun, load_trained_run
from surgsplat.train.trainer import LOG_FILE, read_log

COMPARED = ("psnr_tissue", "psnr_zeroed", "ssim", "lpips", "depth_rmse_mm",
            "normal_error_deg_median", "chamfer_mm", "p2s_median_mm", "fscore_1mm",
            "train_seconds", "num_gaussians", "fps", "peak_rss_mb")
ERROR_RANGE = 0.1
"""Mean absolute colour error shown at full heat in the error maps."""
REPORT_HEAD = ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>surgsplat report"
               "</title>")
"""How every report begins: what tells a report surgsplat wrote from a user's file."""


@dataclass
class RunSummary:
    """What the report shows of one run."""

    name: str  # the run folder relative to the folder holding every run of the report
    method: str
    scene: Path  # the scene folder the run was trained on
    metrics: dict
    log: list[dict]  # train_log.jsonl entries (see read_log)
    panels: list[str]  # the channels shown after the render and its error (`strip_channels`)
    frames: list[tuple[int, np.ndarray]]  # (frame index, uint8 RGB strip [H, (3 + panels) W, 3])


def short_names(paths: list[Path]) -> list[str]:
    """Each path relative to the folder that holds them all: a/run and b/run for DIR/a/run and
    DIR/b/run; a single path's own name."""
    resolved = [Path(path).resolve() for path in paths]
    common = Path(os.path.commonpath([path.parent for path in resolved]))
    return [path.relative_to(common).as_posix() for path in resolved]


def read_metrics(path: Path) -> dict:
    """RUN/metrics.json as written by `surgsplat eval`; DataError naming it when it is not a
    JSON object."""
    try:
        metrics = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise DataError(path, f"is not valid JSON ({err})") from err
    if not isinstance(metrics, dict):
        raise DataError(path, "expected a JSON object of metrics, as `surgsplat eval` writes")
    return metrics


def summarise_run(run_dir: Path, name: str, max_frames: int) -> RunSummary:
    """Load a run (shown as `name`), its metrics (evaluated now when RUN/metrics.json is
    missing), its training log and the image strips of up to `max_frames` test frames."""
    run = load_trained_run(run_dir)
    metrics_path = Path(run_dir) / METRICS_FILE
    metrics = read_metrics(metrics_path) if metrics_path.is_file() \
        else evaluate_run(run, EvalOptions(geometry=False))
    log = read_log(Path(run_dir) / LOG_FILE)
    frames = [(frame.index, frame_strip(run, frame)) for frame in run.scene.test_frames[:max_frames]]
    return RunSummary(name=name, method=run.config.name, scene=run.scene.root, metrics=metrics,
                      log=log, panels=[channel.name for channel in strip_channels(run.model)],
                      frames=frames)


def strip_channels(model: SplatModel) -> list[ChannelDescriptor]:
    """The channels a frame strip shows after the render and its error: every channel the model
    declares but the colour."""
    return [channel for channel in model.channel_descriptors() if channel.name != RGB]


def frame_strip(run: TrainedRun, frame) -> np.ndarray:
    """uint8 RGB [H, (3 + C) W, 3]: ground truth | render | error heat map | the C
    `strip_channels` (depth over the frame's measured depth range when it has depth)."""
    background = torch.tensor(run.config.train.background, dtype=torch.float32)
    out = render_frame(run.model, frame.camera, FrameTime(frame.index, frame.time), background)
    rgb = out.rgb.clamp(0, 1).numpy()
    error = np.abs(rgb - frame.image.numpy()).mean(-1)
    heat = colormap_image(error, Colormap.INFERNO, 0.0, ERROR_RANGE)
    heat = np.where(frame.tissue.numpy()[..., None], heat, 0).astype(np.uint8)
    ranges = {} if frame.depth is None else {DEPTH: percentile_range(frame.depth[frame.depth > 0])}
    return np.concatenate([to_uint8(frame.image.numpy()), to_uint8(rgb), heat,
                           *(channel_image(out, channel, frame.camera.K, ranges.get(channel.name))
                             for channel in strip_channels(run.model))], axis=1)


def png_data_uri(image: np.ndarray) -> str:
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise SurgsplatError("could not encode a report image as PNG")
    return "data:image/png;base64," + base64.b64encode(encoded.tobytes()).decode("ascii")


def logged(log: list[dict], key: str, term: bool = False) -> list[float]:
    """The value of `key` (of a loss term under "terms" when `term`) in each log entry; NaN
    where an entry has no number there (a damaged line), so every curve has one point per
    entry."""
    values = []
    for entry in log:
        holder = entry.get("terms") if term else entry
        value = holder.get(key) if isinstance(holder, dict) else None
        numeric = isinstance(value, (int, float)) and not isinstance(value, bool)
        values.append(float(value) if numeric else float("nan"))
    return values


def term_names(log: list[dict]) -> list[str]:
    """The loss terms logged in any entry, sorted."""
    return sorted({name for entry in log if isinstance(entry.get("terms"), dict)
                   for name in entry["terms"]})


def curves_figure(runs: list[RunSummary]) -> str:
    """Training curves of every run, overlaid: loss and its terms, PSNR against iterations and
    seconds, Gaussian count. Returns a PNG data URI."""
    try:
        import matplotlib
    except ImportError as err:
        raise SurgsplatError("the report's plots need matplotlib: pip install "
                             "'surgsplat[report]'") from err
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    figure, axes = plt.subplots(2, 2, figsize=(11, 7), dpi=80)
    for run in runs:
        if not run.log:
            continue
        iterations = logged(run.log, "iteration")
        psnr = logged(run.log, "psnr")
        line = axes[0, 0].plot(iterations, logged(run.log, "loss"), label=f"{run.name}: loss")
        for term in term_names(run.log):
            axes[0, 0].plot(iterations, logged(run.log, term, term=True), linestyle="--",
                            linewidth=0.8, label=f"{run.name}: {term}")
        colour = line[0].get_color()
        axes[0, 1].plot(iterations, psnr, color=colour, label=run.name)
        axes[1, 0].plot(logged(run.log, "seconds"), psnr, color=colour, label=run.name)
        axes[1, 1].plot(iterations, logged(run.log, "num_gaussians"), color=colour,
                        label=run.name)
    titles = (("loss and its terms (unweighted)", "iteration", "value"),
              ("training-frame PSNR over tissue", "iteration", "dB"),
              ("training-frame PSNR against time", "training seconds", "dB"),
              ("Gaussians", "iteration", "count"))
    for axis, (title, xlabel, ylabel) in zip(axes.flat, titles):
        axis.set_title(title)
        axis.set_xlabel(xlabel)
        axis.set_ylabel(ylabel)
        axis.grid(alpha=0.3)
        if axis.lines:
            axis.legend(fontsize=7)
    axes[0, 0].set_yscale("log")
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    plt.close(figure)
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode("ascii")


def _cell(value) -> str:
    if isinstance(value, float):
        return f"{value:.4f}" if abs(value) < 10 else f"{value:.2f}"
    return "–" if value is None else html.escape(str(value))


def convention_of(key: str, conventions: dict[str, str]) -> str:
    """The convention that defines metric `key` (e.g. psnr_tissue, depth_rmse_mm, chamfer_mm)."""
    if key in GEOMETRY_KEYS:
        return conventions.get("geometry", "")
    if key.endswith("_note"):
        return ""
    return next((text for name, text in conventions.items()
                 if key == name or key.startswith(name + "_")), "")


def metrics_table(run: RunSummary) -> str:
    conventions = run.metrics.get("conventions", {})
    rows = []
    for key, value in run.metrics.items():
        if key == "conventions" or isinstance(value, dict):
            continue
        convention = convention_of(key, conventions)
        rows.append(f"<tr><td>{html.escape(key)}</td><td class=num>{_cell(value)}</td>"
                    f"<td>{html.escape(convention)}</td></tr>")
    return ("<table><tr><th>metric</th><th>value</th><th>convention</th></tr>"
            + "".join(rows) + "</table>")


def comparison_table(runs: list[RunSummary]) -> str:
    """One row per run, with its scene (named like the runs, relative to the folder holding
    every scene), its method, the frames its metrics are over (test or train, and how many:
    `frames_scored`) and the COMPARED metrics; runs of one scene are adjacent."""
    keys = [key for key in COMPARED if any(key in run.metrics for run in runs)]
    header = "".join(f"<th>{html.escape(key)}</th>" for key in keys)
    scenes = short_names([run.scene for run in runs])
    rows = "".join(
        f"<tr><td>{html.escape(run.name)}</td><td>{html.escape(scene)}</td>"
        f"<td>{html.escape(run.method)}</td><td>{html.escape(frames_scored(run.metrics))}</td>"
        + "".join(f"<td class=num>{_cell(run.metrics.get(key))}</td>" for key in keys) + "</tr>"
        for scene, run in sorted(zip(scenes, runs), key=lambda pair: pair[0]))
    return (f"<table><tr><th>run</th><th>scene</th><th>method</th><th>frames scored</th>"
            f"{header}</tr>{rows}</table>")


STYLE = """body{font-family:sans-serif;margin:2em;max-width:1400px}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;
font-size:13px}td.num{text-align:right;font-family:monospace}img{max-width:100%}
figure img{width:100%;image-rendering:pixelated}
h2{border-bottom:1px solid #888}figcaption{font-size:13px;color:#444}"""


def check_report_target(out: Path) -> None:
    """DataError naming `out` unless a report may be written there: a new file, or a report
    surgsplat wrote (it begins with REPORT_HEAD); a folder or any other file is refused, never
    replaced."""
    out = Path(out)
    if out.is_dir():
        raise DataError(out, f"is a folder; expected the HTML file to write, e.g. "
                             f"{out / 'report.html'}")
    if out.exists():
        with open(out, "rb") as handle:
            head = handle.read(len(REPORT_HEAD))
        if head != REPORT_HEAD.encode("ascii"):
            raise DataError(out, "exists and is not a report surgsplat wrote; choose a new file "
                                 "(a report replaces only an earlier report)")


def write_report(run_dirs: list[Path], out: Path, max_frames: int = 4) -> Path:
    """Write the HTML report of `run_dirs` to `out` (atomically; see check_report_target);
    returns `out`."""
    if not run_dirs:
        raise SurgsplatError("report: name at least one run folder")
    check_report_target(out)
    runs = [summarise_run(Path(run_dir), name, max_frames)
            for run_dir, name in zip(run_dirs, short_names(run_dirs))]
    parts = [f"{REPORT_HEAD}<style>{STYLE}</style></head><body><h1>surgsplat report</h1>"]
    if len(runs) > 1:
        parts.append("<h2>comparison</h2>" + comparison_table(runs))
    parts.append(f"<h2>training curves</h2><img alt='training curves' src='{curves_figure(runs)}'>")
    for run in runs:
        parts.append(f"<h2>{html.escape(run.name)} ({html.escape(run.method)}; metrics over "
                     f"{html.escape(frames_scored(run.metrics))} frames)</h2>"
                     + metrics_table(run))
        for index, strip in run.frames:
            parts.append(f"<figure><img alt='test frame {index}' src='{png_data_uri(strip)}'>"
                         f"<figcaption>test frame {index}: ground truth | render | error "
                         f"(|render - truth|, 0 to {ERROR_RANGE}, tissue only) | "
                         f"{html.escape(' | '.join(run.panels))}</figcaption></figure>")
    parts.append("</body></html>")
    write_text_atomic(Path(out), "\n".join(parts))
    return Path(out)
