"""One self-contained HTML report of one or more runs: metrics with their conventions, training
curves (matplotlib, inlined as PNG), and per test frame the ground truth, the render, an error
heat map, the depth and the normals. With several runs: a comparison table and overlaid curves.

Everything is inlined (base64 images, CSS in the page, no script), so the file opens offline and
can be mailed or attached to a paper's supplement.
"""

from __future__ import annotations

import base64
import html
import io
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from surgsplat.atomic import write_text_atomic
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.eval.normals import surface_normals
from surgsplat.eval.run_metrics import GEOMETRY_KEYS, EvalOptions, evaluate_run
from surgsplat.export.video import colorize_depth, colorize_normals, to_uint8
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.train.run import TrainedRun, load_trained_run

METRICS_FILE = "metrics.json"
LOG_FILE = "train_log.jsonl"
COMPARED = ("psnr_tissue", "psnr_zeroed", "ssim", "lpips", "depth_rmse_mm",
            "normal_error_deg_median", "chamfer_mm", "p2s_median_mm", "fscore_1mm",
            "train_seconds", "num_gaussians", "fps", "peak_rss_mb")
ERROR_RANGE = 0.1
"""Mean absolute colour error shown at full heat in the error maps."""


@dataclass
class RunSummary:
    """What the report shows of one run."""

    name: str
    method: str
    metrics: dict
    log: list[dict]  # train_log.jsonl entries
    frames: list[tuple[int, np.ndarray]]  # (frame index, uint8 RGB strip [H, 5 W, 3])


def summarise_run(run_dir: Path, max_frames: int) -> RunSummary:
    """Load a run, its metrics (evaluated now when RUN/metrics.json is missing), its training
    log and the image strips of up to `max_frames` test frames."""
    run = load_trained_run(run_dir)
    metrics_path = Path(run_dir) / METRICS_FILE
    if metrics_path.is_file():
        try:
            metrics = json.loads(metrics_path.read_text())
        except json.JSONDecodeError as err:
            raise DataError(metrics_path, f"is not valid JSON ({err})") from err
    else:
        metrics = evaluate_run(run, EvalOptions(geometry=False))
    log_path = Path(run_dir) / LOG_FILE
    log = [json.loads(line) for line in log_path.read_text().splitlines() if line.strip()] \
        if log_path.is_file() else []
    frames = [(frame.index, frame_strip(run, frame)) for frame in run.scene.test_frames[:max_frames]]
    return RunSummary(name=Path(run_dir).name, method=run.config.name, metrics=metrics, log=log,
                      frames=frames)


def frame_strip(run: TrainedRun, frame) -> np.ndarray:
    """uint8 RGB [H, 5 W, 3]: ground truth | render | error heat map | depth | normals."""
    background = torch.tensor(run.config.train.background, dtype=torch.float32)
    out = render_frame(run.model, frame.camera, FrameTime(frame.index, frame.time), background)
    rgb = out.rgb.clamp(0, 1).numpy()
    error = np.abs(rgb - frame.image.numpy()).mean(-1) / ERROR_RANGE
    heat = cv2.applyColorMap(to_uint8(np.clip(error, 0, 1)), cv2.COLORMAP_INFERNO)[..., ::-1]
    heat = np.where(frame.tissue.numpy()[..., None], heat, 0).astype(np.uint8)
    values = frame.depth[frame.depth > 0] if frame.depth is not None else out.depth[out.alpha > 0.5]
    near, far = (float(values.quantile(0.01)), float(values.quantile(0.99))) if values.numel() \
        else (0.0, 1.0)
    normals, valid, _ = surface_normals(out, frame.camera.K)
    return np.concatenate([to_uint8(frame.image.numpy()), to_uint8(rgb), heat,
                           colorize_depth(out.depth.numpy(), near, far),
                           colorize_normals(normals.numpy(), valid.numpy())], axis=1)


def png_data_uri(image: np.ndarray) -> str:
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))
    if not ok:
        raise SurgsplatError("could not encode a report image as PNG")
    return "data:image/png;base64," + base64.b64encode(encoded.tobytes()).decode("ascii")


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
        iterations = [entry["iteration"] for entry in run.log]
        seconds = [entry["seconds"] for entry in run.log]
        line = axes[0, 0].plot(iterations, [e["loss"] for e in run.log], label=f"{run.name}: loss")
        for term in sorted({t for entry in run.log for t in entry.get("terms", {})}):
            axes[0, 0].plot(iterations, [e.get("terms", {}).get(term, np.nan) for e in run.log],
                            linestyle="--", linewidth=0.8, label=f"{run.name}: {term}")
        colour = line[0].get_color()
        axes[0, 1].plot(iterations, [e["psnr"] for e in run.log], color=colour, label=run.name)
        axes[1, 0].plot(seconds, [e["psnr"] for e in run.log], color=colour, label=run.name)
        axes[1, 1].plot(iterations, [e["num_gaussians"] for e in run.log], color=colour,
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
    keys = [key for key in COMPARED if any(key in run.metrics for run in runs)]
    header = "".join(f"<th>{html.escape(key)}</th>" for key in keys)
    rows = "".join(
        f"<tr><td>{html.escape(run.name)}</td><td>{html.escape(run.method)}</td>"
        + "".join(f"<td class=num>{_cell(run.metrics.get(key))}</td>" for key in keys) + "</tr>"
        for run in runs)
    return f"<table><tr><th>run</th><th>method</th>{header}</tr>{rows}</table>"


STYLE = """body{font-family:sans-serif;margin:2em;max-width:1400px}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:3px 8px;
font-size:13px}td.num{text-align:right;font-family:monospace}img{max-width:100%}
figure img{width:100%;image-rendering:pixelated}
h2{border-bottom:1px solid #888}figcaption{font-size:13px;color:#444}"""


def write_report(run_dirs: list[Path], out: Path, max_frames: int = 4) -> Path:
    """Write the HTML report of `run_dirs` to `out` (atomically); returns `out`."""
    if not run_dirs:
        raise SurgsplatError("report: name at least one run folder")
    runs = [summarise_run(Path(run_dir), max_frames) for run_dir in run_dirs]
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>surgsplat report</title>"
             f"<style>{STYLE}</style></head><body><h1>surgsplat report</h1>"]
    if len(runs) > 1:
        parts.append("<h2>comparison</h2>" + comparison_table(runs))
    parts.append(f"<h2>training curves</h2><img alt='training curves' src='{curves_figure(runs)}'>")
    for run in runs:
        parts.append(f"<h2>{html.escape(run.name)} ({html.escape(run.method)})</h2>"
                     + metrics_table(run))
        for index, strip in run.frames:
            parts.append(f"<figure><img alt='test frame {index}' src='{png_data_uri(strip)}'>"
                         f"<figcaption>test frame {index}: ground truth | render | error "
                         f"(|render - truth|, 0 to {ERROR_RANGE}, tissue only) | depth | normals"
                         f"</figcaption></figure>")
    parts.append("</body></html>")
    write_text_atomic(Path(out), "\n".join(parts))
    return Path(out)
