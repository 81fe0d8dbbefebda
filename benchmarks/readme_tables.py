"""Writes the benchmark tables of the documentation from the benchmark results: every
benchmarks/results/<benchmark>-*.json becomes one table, placed between the
`<!-- <benchmark>:begin -->` and `<!-- <benchmark>:end -->` markers of the one page under docs/
that holds them, for the benchmarks bench_render, bench_train, bench_densify_split,
bench_threads, bench_outputs, bench_auto_masks, bench_shading_depth, bench_batch,
bench_long_clip, bench_articulation, bench_faults, bench_onnx_models, bench_poses, op_census,
bench_camera_grads and bench_stream (each must have its region in some page), for every suite
of bench_methods whose region `bench_methods_<suite>` a page has, and for every region
`preset_<suite>_<preset>` (a method page: that preset's rows and targets of one bench_methods
suite, e.g. preset_fidelity_endogsg or preset_speed_deform3dgs). No figure in those regions is
typed by hand. The name is historical: the tables were the README's before they moved to docs/.

    python benchmarks/readme_tables.py [--check]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def cell(row: dict, key: str, spec: str) -> str:
    """row[key] formatted with `spec`, or empty when the row lacks it."""
    value = row.get(key)
    if value is None:
        return ""
    return format(round(value) if spec == "d" else value, spec)


def backward_efficiency(row: dict) -> float | None:
    """A bench_render raster row's efficiency of the backward pass alone: its evaluations per
    second of backward time (fwd+bwd ms - forward ms) over the probe's; None for a step row."""
    if "efficiency_fwdbwd" not in row:
        return None
    return row["efficiency_fwdbwd"] * row["fwdbwd_ms"] / (row["fwdbwd_ms"] - row["fwd_ms"])


def render_table(report: dict) -> str:
    """Markdown for one bench_render report: a line naming the machine, then one row per ISA
    variant and case, with the efficiency of forward, of backward alone and of both."""
    system = report["system"]
    lines = [
        f"{report['cpu']} ({system['logical_cpus']} logical CPUs, {system['torch_threads']} "
        f"threads; ISA variants {', '.join(system['available_isas'])}), "
        f"{report['width']}x{report['height']}, median of {report['repeats']}, "
        f"{report['date'][:10]}:",
        "",
        "| ISA | Gaussians | C | forward ms | FPS | fwd+bwd ms | train step ms | evals/s "
        "| probe evals/s | efficiency fwd | efficiency bwd | efficiency fwd+bwd |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["rows"]:
        lines.append(
            f"| {row['isa']} | {row['gaussians'] // 1000}k | {row['channels']} "
            f"| {cell(row, 'fwd_ms', '.1f')} | {cell(row, 'fps', '.1f')} "
            f"| {cell(row, 'fwdbwd_ms', '.1f')} "
            f"| {cell(row, 'step_ms', '.0f')} | {cell(row, 'evals_per_s', '.2e')} "
            f"| {cell(row, 'probe_evals_per_s', '.2e')} | {cell(row, 'efficiency_fwd', '.2f')} "
            f"| {cell({'bwd': backward_efficiency(row)}, 'bwd', '.2f')} "
            f"| {cell(row, 'efficiency_fwdbwd', '.2f')} |")
    return "\n".join(lines)


def render_threads_table(report: dict) -> str:
    """Markdown for one bench_threads report: training time per OpenMP wait policy."""
    lines = [
        f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs), "
        f"`{report['command']}`, {report['iters']} iterations, median of {report['repeats']}, "
        f"{report['date'][:10]}:",
        "",
        "| wait policy | competing process | training s | vs surgsplat default |",
        "|---|---|---|---|",
    ]
    for row in report["rows"]:
        lines.append(f"| {row['policy']} | {'yes' if row['competing_process'] else 'no'} "
                     f"| {row['train_s']:.1f} | {row['ratio_to_surgsplat_default']:.2f} |")
    if "load_average_1min" in report:
        load = report["load_average_1min"]
        lines += ["", f"Load average of the machine (1 min): {load['start']:.1f} at the start, "
                      f"{load['end']:.1f} at the end (2 would be both cores busy)."]
    if "note" in report:
        lines += ["", report["note"]]
    return "\n".join(lines)


def metric_format(key: str) -> str:
    """How a bench_methods column is printed, from its name."""
    if key in ("iterations", "num_gaussians", "collisions", "clips", "frames"):
        return "d"
    if key.startswith("ssim"):
        return ".4f"
    if key.endswith(("_mm", "_mm_mean", "_mm_median", "_mm_p95")) or key.startswith("fscore"):
        return ".3f"
    if key.endswith(("seconds", "rss_mb")):
        return ".0f"
    if key in ("r_var", "reflectance_error", "shading_error"):
        return ".4f"
    if key.startswith("collision_fraction"):
        return ".1e"
    return ".2f"


def methods_table(report: dict) -> str:
    """Markdown for one bench_methods suite report: the machine and command, then one row per
    case with the columns the suite chose (report["columns"])."""
    system = report["system"]
    columns = ["iterations", *report["columns"]]
    lines = [
        f"{report['cpu']} ({system['logical_cpus']} logical CPUs, ISA {system['isa']}), "
        f"{report['date'][:10]}, `{report['command']}`:",
        "",
        "| case | " + " | ".join(columns) + " |",
        "|---|" + "---|" * len(columns),
    ]
    for row in report["rows"]:
        cells = [cell(row, key, metric_format(key)) for key in columns]
        lines.append(f"| {row['case']} | " + " | ".join(cells) + " |")
    seeds = {tuple(row.get("seeds") or ()) for row in report["rows"]}
    if any(len(case_seeds) > 1 for case_seeds in seeds):
        lines += ["", "Each figure is the mean over the seeds "
                  + ", ".join(str(list(case_seeds)) for case_seeds in sorted(seeds))
                  + "; each seed's value is in the JSON (`<metric>_seeds`)."]
    if report.get("targets"):
        lines += ["", "| case | target | measured | bound | met |", "|---|---|---|---|---|"]
        for target in report["targets"]:
            spec = metric_format(target["metric"])
            lines.append(f"| {target['case']} | {target['rule']} "
                         f"| {cell(target, 'value', spec)} | {cell(target, 'bound', spec)} "
                         f"| {'yes' if target['met'] else '**no**'} |")
    if "note" in report:
        lines += ["", report["note"]]
    return "\n".join(lines)


def outputs_table(report: dict) -> str:
    """Markdown for one bench_outputs report: PLY export, viewer frames, report generation."""
    row = report["rows"][0]
    return "\n".join([
        f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs, ISA "
        f"{report['system']['isa']}), {report['date'][:10]}:",
        "",
        "| PLY export, 100k Gaussians | viewer frame 640x512 | report of one run |",
        "|---|---|---|",
        f"| {row['ply_seconds']:.2f} s ({row['ply_mb']:.0f} MB) "
        f"| {row['viewer_frame_seconds'] * 1e3:.0f} ms = {row['viewer_fps']:.1f} FPS "
        f"({row['viewer_gaussians'] // 1000}k Gaussians) | {row['report_seconds']:.1f} s |"])


def auto_masks_table(report: dict) -> str:
    """Markdown for one bench_auto_masks report: tool IoU, precision and recall per split of
    the CholecSeg8k clip and per unseen clip, false alarms on tool-free frames, then the
    training comparison per clip when the report has one."""
    lines = [f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs), "
             f"{report['date'][:10]}, `{report['command']}`:", "",
             "| clip | frames | IoU | lowest frame IoU | precision | recall "
             "| false alarms (share of view) | ms per frame |",
             "|---|---|---|---|---|---|---|---|"]
    clips = [("cholecseg8k", split, report) for split in ("tuning", "held_out")]
    clips += [(name, "all", clip) for name, clip in report.get("unseen_clips", {}).items()]
    if "tool_free" in report:
        clips.append(("SCARED frame, no tool", "all", report["tool_free"]))
    for name, split, clip in clips:
        first, last = clip["splits"][split]
        row = clip[split]
        frames = f"{split.replace('_', '-')} {first}-{last}" if split != "all" else \
            f"{first}-{last}"
        scored = "| {iou:.3f} | {frame_iou_min:.3f} | {precision:.3f} | {recall:.3f} " \
            if row["tool_pixels"] else "| | | | "  # no tool: only false alarms mean anything
        lines.append(f"| {name} | {frames} " + scored.format(**row)
                     + f"| {100 * row['false_alarm_share']:.2f} % "
                     f"| {1000 * clip['seconds_per_frame']:.0f} |")
    if "prompted" in report:
        lines += ["", "| clip (tool masks from clicks) | frames | IoU, 0 clicks | 1 click "
                      "per tool | 3 clicks per tool | 1 click + 1 tissue click "
                      "| lowest frame IoU, 1 click | ms per frame |",
                  "|---|---|---|---|---|---|---|---|"]
        for name, row in report["prompted"].items():
            ious = " | ".join(f"{row[key]['iou']:.3f}" for key in
                              ("clicks_0", "clicks_1", "clicks_3", "clicks_1_corrected"))
            lines.append(f"| {name} | {row['frames']} | {ious} "
                         f"| {row['clicks_1']['frame_iou_min']:.3f} "
                         f"| {1000 * row['clicks_1']['seconds_per_frame']:.0f} |")
    for clip_name, training in report.get("training", {}).items():
        seeds = training["seeds"]
        lines += ["", f"| {clip_name}: {training['method']}, {training['iterations']} "
                      f"iterations, scale {training['scale']}, mean of {seeds} "
                      f"seed{'s' if seeds > 1 else ''} | psnr_tissue | seeds | ssim "
                      "| mask IoU |",
                  "|---|---|---|---|---|"]
        for name, row in training["rows"].items():
            per_seed = " / ".join(f"{seed['psnr_tissue']:.2f}" for seed in row["per_seed"])
            lines.append(f"| {name} | {cell(row, 'psnr_tissue', '.2f')} | {per_seed} "
                         f"| {cell(row, 'ssim', '.4f')} | {cell(row, 'mask_iou', '.3f')} |")
    return "\n".join(lines)


def shading_depth_table(report: dict) -> str:
    """Markdown for one bench_shading_depth report: depth accuracy on the phantom and SCARED,
    then the training comparison when the report has one."""
    lines = [f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs), "
             f"{report['date'][:10]}, `{report['command']}`:", "",
             "| data | rel_clip | rel_frame | Spearman | rel_constant (floor) |",
             "|---|---|---|---|---|"]
    for name in ("phantom", "scared"):
        row = report[name]
        lines.append(f"| {name} | {row['rel_clip']:.3f} | {row['rel_frame']:.3f} "
                     f"| {row['spearman']:.3f} | {row['rel_constant']:.3f} |")
    if "training" in report:
        training = report["training"]
        columns = ("psnr_tissue", "chamfer_mm", "p2s_median_mm", "normal_error_deg_median",
                   "chamfer_ratio_to_no_depth")
        lines += ["", f"| {training['method']}, {training['iterations']} iterations | "
                      + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
        for name, row in training["rows"].items():
            lines.append(f"| {name} | " + " | ".join(cell(row, key, metric_format(key))
                                                      for key in columns) + " |")
    return "\n".join(lines)


def poses_table(report: dict) -> str:
    """Markdown for one bench_poses report: trajectory errors of SfM on the moving phantom
    against both truths beside the static camera's, then registration on CholecSeg8k."""
    phantom = report["phantom"]
    width, height = phantom["size_wh"]
    lines = [f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs), "
             f"{report['date'][:10]}, `{report['command']}`:", "",
             f"| moving phantom ({phantom['preset']}, {phantom['frames']} frames, {width}x"
             f"{height}) | ATE mm | rotation mean / max deg | RPE mm | RPE deg |",
             "|---|---|---|---|---|"]
    for name, label in (("against_tissue", "SfM vs camera relative to the tissue"),
                        ("against_world", "SfM vs world poses (tissue breathes)")):
        row = phantom[name]
        lines.append(f"| {label} | {row['ate_mm']:.3f} | {row['rotation_mean_deg']:.3f} / "
                     f"{row['rotation_max_deg']:.3f} | {row['rpe_mm']:.3f} "
                     f"| {row['rpe_rotation_deg']:.3f} |")
    static = phantom["static_reference"]["against_tissue"]
    lines.append(f"| static camera (reference) vs tissue | {static['ate_mm']:.3f} "
                 f"| {static['rotation_mean_deg']:.3f} / {static['rotation_max_deg']:.3f} | | |")
    focal = phantom.get("focal_refinement")
    if focal is not None:
        row = focal["against_tissue"]
        lines.append(f"| SfM, focal assumed ({focal['assumed_px']:.1f} px) and refined to "
                     f"{focal['refined_px']:.1f} (true {focal['true_px']:.1f}), vs tissue "
                     f"| {row['ate_mm']:.3f} | {row['rotation_mean_deg']:.3f} / "
                     f"{row['rotation_max_deg']:.3f} | {row['rpe_mm']:.3f} "
                     f"| {row['rpe_rotation_deg']:.3f} |")
    lines += ["", "| data | registered | interpolated | reprojection px | sparse points "
                  "| import s (CPU s) | SfM s: features / matching / mapping | static import s |",
              "|---|---|---|---|---|---|---|---|"]
    for name, case in (("phantom", phantom), ("CholecSeg8k clip", report.get("cholecseg8k"))):
        if case is None:
            continue
        facts, stages = case["sfm"], case["sfm"]["stage_seconds"]
        lines.append(f"| {name} | {facts['registered']} of {facts['frames']} "
                     f"| {len(facts['interpolated'])} | {facts['reprojection_error_px']:.2f} "
                     f"| {facts['sparse_points']} | {case['seconds']:.1f} "
                     f"({case['cpu_seconds']:.1f}) | {stages['features']:.1f} / "
                     f"{stages['matching']:.1f} / {stages['mapping']:.1f} "
                     f"| {case['static_reference']['seconds']:.1f} |")
    training = report.get("training")
    if training is not None:
        lines += ["", f"| {training['method']}, {training['iterations']} iterations, "
                      f"{training['seeds']} seed(s), moving phantom | psnr_tissue "
                      "| depth_rmse_mm | train CPU s |", "|---|---|---|---|"]
        labels = {"true_poses": "true poses", "sfm_poses": "SfM poses (scale from depth)",
                  "sfm_poses_refined": "SfM poses + camera_refine (prior "
                                       f"{training['pose_prior_weight']:g})"}
        for name, row in training["rows"].items():
            lines.append(f"| {labels[name]} | {row['psnr_tissue']:.2f} "
                         f"| {row['depth_rmse_mm']:.3f} | {row['train_cpu_seconds']:.0f} |")
    clip = report.get("clip_training")
    if clip is not None:
        lines += ["", f"| {clip['method']}, {clip['iterations']} iterations, {clip['seeds']} "
                      "seed(s), CholecSeg8k clip | psnr_tissue | ssim | train CPU s |",
                  "|---|---|---|---|"]
        prior = clip.get("pose_prior_weight")
        labels = {"static": "static camera (every pose the first)", "sfm": "SfM poses",
                  "sfm_refined": f"SfM poses + camera_refine (prior {prior}), test poses "
                                 "fitted at evaluation",
                  "static_test_time_poses": "static camera, test poses fitted at evaluation",
                  "sfm_test_time_poses": "SfM poses, test poses fitted at evaluation"}
        for name, row in clip["rows"].items():
            lines.append(f"| {labels[name]} | {row['psnr_tissue']:.2f} | {row['ssim']:.3f} "
                         f"| {row['train_cpu_seconds']:.0f} |")
    return "\n".join(lines)


def long_clip_table(report: dict) -> str:
    """Markdown for one bench_long_clip report: one row per clip length, steps per second also
    as a ratio to the shortest clip's."""
    rows = sorted(report["rows"], key=lambda row: row["frames"])
    lines = [
        f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs, ISA "
        f"{report['system']['isa']}), {report['date'][:10]}, {report['method']} at "
        f"{report['width']}x{report['height']}, {rows[0]['iters']} iterations:",
        "",
        "| frames | peak RSS MB | steps/s | steps/s vs shortest | Gaussians | wall s |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        lines.append(f"| {row['frames']} | {row['peak_rss_mb']:.0f} | {row['steps_per_s']:.2f} "
                     f"| {row['steps_per_s'] / rows[0]['steps_per_s']:.2f} "
                     f"| {row['num_gaussians']} | {row['wall_seconds']:.0f} |")
    return "\n".join(lines)


def long_clip_validation_table(report: dict) -> str:
    """Markdown for one bench_long_clip validation report: `load_scene` of the long clip,
    wall and CPU seconds beside the target, and the ratio to the decoding reference."""
    row = report["validation"]
    extrapolated = " (extrapolated from fewer frames)" if row["extrapolated"] else ""
    return "\n".join([
        f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs, ISA "
        f"{report['system']['isa']}), {report['date'][:10]}, {report['width']}x"
        f"{report['height']}, {row['threads']} threads:",
        "",
        "| frames | seconds at 7500 frames | CPU seconds | target seconds | ms per frame "
        "| ratio to one-thread decoding |",
        "|---|---|---|---|---|---|",
        f"| {row['frames']} | {row['seconds_at_7500_frames']:.0f}{extrapolated} "
        f"| {row['cpu_seconds_at_7500_frames']:.0f} | {row['target_seconds']:.0f} "
        f"| {row['ms_per_frame']:.1f} | {row['ratio_to_reference']:.2f} |"])


def faults_table(report: dict) -> str:
    """Markdown for one bench_faults report: the work kill -9 lost, and where the report has
    them, the fault cases of issues 30 and 53 handled per class with the totals of bad
    outcomes, at the commit the cases ran."""
    machine = (f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs), "
               f"{report['date'][:10]}")
    code = f", code at {report['commit']}" if "commit" in report else ""
    paragraphs = []
    if "trials" in report:
        paragraphs.append(
            f"{machine}: training killed with kill -9 {report['trials']} times (checkpoint "
            f"every {report['checkpoint_seconds']:g} s) lost a median "
            f"{report['lost_wall_s_median']:.1f} s of work, at most "
            f"{report['lost_wall_s_max']:.1f} s; damaged checkpoints "
            f"{report['checkpoints_damaged']}, final resume "
            f"{'ok' if report['final_resume_ok'] else 'FAILED'}.")
    for group in ("issue_30", "issue_53"):
        cases = report.get(group)
        if not cases:
            continue
        rows = [f"| {name} | {row['cases']} | {row['handled']} |"
                for name, row in cases["by_class"].items()]
        paragraphs.append("\n".join([
            f"Issue {group.split('_')[1]}'s classes against the CLI ({machine}{code}): "
            f"{cases['handled']} of {cases['cases']} cases handled; silent wrong results "
            f"{cases['silent_wrong']}, overwritten user files {cases['overwrote']}, tracebacks "
            f"{cases['traceback']}, hangs {cases['hang']}.", "",
            "| class | cases | handled |", "|---|---|---|", *rows]))
    return "\n\n".join(paragraphs)


def articulation_table(report: dict) -> str:
    """Markdown for one bench_articulation report: the articulation's errors, the export's
    time and what the simulated scene did, each with its target where the issue sets one."""
    sweep, probe, targets = report["jaw_sweep"], report["probe"], report["targets"]
    lines = [
        f"{report['cpu']} ({report['system']['logical_cpus']} logical CPUs), "
        f"{report['date'][:10]}, `{report['method']}` at {report['iters']} iterations on the "
        f"full pulling phantom, {report['articulation_frames']} frames with the tool "
        f"({report['articulation_frames_estimated']} estimated from their own observation), "
        f"simulation export of frame {report['frame']}:",
        "",
        "| measure | value | target |",
        "|---|---|---|",
    ]
    rows = [("hinge axis error, deg", report["hinge_axis_error_deg"], ".1f",
             targets["hinge_axis_error_deg"]),
            ("hinge axis error, frames estimated from their own observation, deg",
             report["hinge_axis_error_deg_estimated"], ".1f", None),
            ("hinge offset, mm", report["hinge_offset_mm"], ".1f", None),
            ("hinge offset, frames estimated from their own observation, mm",
             report["hinge_offset_mm_estimated"], ".1f", None),
            ("jaw angle RMSE, deg", report["jaw_angle_rmse_deg"], ".1f",
             targets["jaw_angle_rmse_deg"]),
            ("jaw angle RMSE, frames estimated from their own observation, deg",
             report["jaw_angle_rmse_deg_estimated"], ".1f", None),
            ("jaw opening RMSE, deg", report["jaw_opening_rmse_deg"], ".1f", None),
            ("articulate, s", report["articulate_seconds"], ".1f", None),
            ("export --sim of one frame, s", report["export_seconds"], ".1f",
             targets["export_seconds"]),
            ("MuJoCo jaw tracking error, max deg (1,000 steps)",
             sweep["max_tracking_error_deg"], ".2f", None),
            ("MuJoCo jaw tracking error, mean deg", sweep["mean_tracking_error_deg"], ".2f", None),
            ("probe resting distance to the tissue mesh, mm", probe["contact_distance_mm"],
             ".2f", 1.0)]
    for name, value, spec, target in rows:
        bound = "" if target is None else f"<= {target:g}"
        lines.append(f"| {name} | {format(value, spec)} | {bound} |")
    return "\n".join(lines)


def camera_grads_table(report: dict) -> str:
    """Markdown for one bench_camera_grads report: projection forward and backward with and
    without the camera's gradients, and their accuracy against the float64 reference."""
    system, accuracy = report["system"], report["accuracy"]
    lines = [
        f"{report['cpu']} ({system['logical_cpus']} logical CPUs, ISA {system['isa']}, "
        f"{report['threads']} threads), {report['width']}x{report['height']}, median of "
        f"{report['repeats']} alternations, {report['date'][:10]}:",
        "",
        "| Gaussians | without camera gradients ms | with ms | ratio |",
        "|---|---|---|---|",
    ]
    for row in report["timing"]:
        lines.append(f"| {row['gaussians']} | {row['without_camera_ms']:.1f} "
                     f"| {row['with_camera_ms']:.1f} | {row['ratio']:.3f} |")
    lines += ["", f"Native float32 camera gradients against the float64 reference "
                  f"({accuracy['gaussians']} Gaussians), largest error over the largest entry: "
                  f"K {accuracy['K_relative_error']:.1e}, world_to_camera "
                  f"{accuracy['world_to_camera_relative_error']:.1e}."]
    return "\n".join(lines)


def onnx_models_table(report: dict) -> str:
    """Markdown for one bench_onnx_models report: seconds per frame through ONNX Runtime and
    through the exporting PyTorch network, per input size and batch."""
    system = report["system"]
    lines = [
        f"{report['cpu']} ({system['logical_cpus']} logical CPUs, {system['torch_threads']} "
        f"threads), {report['network']}, {report['parameters'] / 1e6:.2f}M parameters, "
        f"{report['frame_size_wh'][0]}x{report['frame_size_wh'][1]} frames, load average "
        f"{report['load_average_1min']['start']:.1f} at the start, {report['date'][:10]}:",
        "",
        "| input | batch | s/frame (wall) | CPU s/frame | PyTorch s/frame | ONNX / PyTorch |",
        "|---|---|---|---|---|---|",
    ]
    for row in report["rows"]:
        width, height = row["input_size_wh"]
        lines.append(f"| {width}x{height} | {row['batch']} | {cell(row, 'seconds_per_frame', '.3f')} "
                     f"| {cell(row, 'cpu_seconds_per_frame', '.3f')} "
                     f"| {cell(row, 'torch_seconds_per_frame', '.3f')} "
                     f"| {cell(row, 'onnx_to_torch_ratio', '.2f')} |")
    return "\n".join(lines)


def train_table(report: dict, results: str = "benchmarks/results") -> str:
    """Markdown for one bench_train report: one row per case (times raw and scaled to the
    reference probe), then issue 52's targets, the phases of each case profiled over its whole
    run, then the plot of the curves (a link into `results`, the results folder relative to the
    page)."""
    system = report["system"]
    lines = [
        f"{report['cpu']} ({system['logical_cpus']} logical CPUs, ISA {system['isa']}, "
        f"--threads {report['threads']}), {report['date'][:10]}, `{report['command']}`; scaled "
        f"= seconds x this case's probe / {report['reference_probe_evals_per_s']:.2g} "
        "evaluations per second:",
        "",
        "| scene | preset | iterations | final psnr_tissue | s to -1 dB | scaled | s to -0.3 dB "
        "| scaled | wall s scaled | s/iter | Gaussians | render FPS | measured |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["rows"]:
        settings = "".join(f" `{setting}`" for setting in row["settings"])
        variant = "" if row.get("isa", system["isa"]) == system["isa"] else f" ({row['isa']})"
        lines.append(
            f"| {row['scene']} | {row['preset']}{settings}{variant} | {row['iterations']} "
            f"| {cell(row, 'test_psnr_tissue', '.2f')} "
            f"| {cell(row, 'seconds_to_minus_1db', '.0f')} "
            f"| {cell(row, 'seconds_to_minus_1db_scaled', '.0f')} "
            f"| {cell(row, 'seconds_to_minus_0p3db', '.0f')} "
            f"| {cell(row, 'seconds_to_minus_0p3db_scaled', '.0f')} "
            f"| {cell(row, 'wall_seconds_scaled', '.0f')} "
            f"| {cell(row, 'seconds_per_iter', '.3f')} | {row['num_gaussians']} "
            f"| {cell(row, 'render_fps', '.1f')} | {row.get('date', report['date'][:10])} |")
    if report["targets"]:  # none when no case ran at its default schedule
        lines += ["", "| target | measured | bound | met |", "|---|---|---|---|"]
    for target in report["targets"]:
        digits = 2 if "psnr" in target["rule"] else 0  # dB to 0.01, seconds to 1
        measured = "not reached" if target["value"] is None else f"{target['value']:.{digits}f}"
        lines.append(f"| {target['rule']} | {measured} | {target['relation']} "
                     f"{target['bound']:.{digits}f} | {'yes' if target['met'] else '**no**'} |")
    lines += isa_ratio_lines(report)
    for row in report["rows"]:  # a profile of the first iterations only is left in the JSON
        if row.get("profile", {}).get("iterations") == row["iterations"]:
            lines += ["", *step_phases_table(row, report["reference_probe_evals_per_s"])]
    lines += ["", f"![test psnr_tissue against scaled training seconds]"
                  f"({results}/{report['plot']})"]
    return "\n".join(lines)


def isa_ratio_lines(report: dict) -> list[str]:
    """Markdown lines comparing, per case run on more than one ISA variant (bench_train
    --isas), each lesser variant's scaled wall seconds with the report's own variant's (both
    scaled by the probe of the machine's fastest variant)."""
    best = report["system"]["isa"]
    by_case: dict[tuple, dict[str, dict]] = {}
    for row in report["rows"]:
        case = (row["scene"], row["preset"], tuple(row["settings"]))
        by_case.setdefault(case, {})[row.get("isa", best)] = row
    lines = []
    for (scene, preset, _), variants in by_case.items():
        for isa, row in variants.items():
            if isa != best and best in variants:
                reference = variants[best]
                lines.append(
                    f"| {scene} | {preset} | {isa} | {row['wall_seconds_scaled']:.0f} "
                    f"| {reference['wall_seconds_scaled']:.0f} "
                    f"| {row['wall_seconds_scaled'] / reference['wall_seconds_scaled']:.2f} "
                    f"| {row['test_psnr_tissue'] - reference['test_psnr_tissue']:+.2f} |")
    if not lines:
        return []
    return ["", f"Each case on a lesser ISA variant of the native kernels against {best} on "
                f"this machine (scaled wall seconds, by the probe of {best}):", "",
            f"| scene | preset | ISA | wall s scaled | on {best} | ratio | psnr_tissue "
            "difference, dB |", "|---|---|---|---|---|---|---|", *lines]


RASTERISER_PHASES = ("rasterize forward", "rasterize backward")


def step_phases_table(row: dict, reference_probe: float) -> list[str]:
    """Markdown lines of one bench_train row's profile: each phase's share of a training step
    and its scaled seconds over the row's steps (its share of seconds_per_iter x iterations),
    then the rasteriser's forward and backward together and everything else."""
    profile = row["profile"]
    steps_scaled = (row["seconds_per_iter"] * row["iterations"] * row["probe_evals_per_s"]
                    / reference_probe)
    shares = profile["step_shares"]
    rasteriser = sum(shares.get(phase, 0.0) for phase in RASTERISER_PHASES)
    lines = [f"Where a step of {row['preset']} on {row['scene']} goes (py-spy, "
             f"{profile['step_samples']} samples over {profile['iterations']} iterations); "
             f"scaled s = the share of the {steps_scaled:.0f} scaled seconds of its "
             f"{row['iterations']} steps:", "",
             "| phase | share of a step | scaled s |", "|---|---|---|"]
    lines += [f"| {phase} | {share:.1%} | {share * steps_scaled:.1f} |"
              for phase, share in shares.items()]
    lines += [f"| **rasteriser, forward and backward** | {rasteriser:.1%} "
              f"| {rasteriser * steps_scaled:.1f} |",
              f"| **everything else** | {1 - rasteriser:.1%} "
              f"| {(1 - rasteriser) * steps_scaled:.1f} |"]
    if "min_visible_fraction" in row:
        lines += ["", f"Every test render of the run (after its first) touched at least "
                      f"{row['min_visible_fraction']:.2%} of the Gaussians: an optimiser step "
                      f"over the visible Gaussians alone would leave out at most "
                      f"{1 - row['min_visible_fraction']:.2%} of the rows."]
    return lines


def op_census_table(report: dict) -> str:
    """Markdown for one op_census report: per preset, a step's time and ATen calls and the
    shares of its operators' self time by kind, then each preset's operators with the most self
    time."""
    system = report["system"]
    kinds = list(report["rows"][0]["shares"])
    lines = [
        f"{report['cpu']} ({system['logical_cpus']} logical CPUs, ISA {system['isa']}, "
        f"{report['threads']} threads), {report['date'][:10]}, `{report['command']}`; the "
        f"{report['steps']} steps after the first {report['warmup']} of each preset:", "",
        "| preset | Gaussians | ms per step | ATen calls per step | "
        + " | ".join(kinds) + " |",
        "|---|---|---|---|" + "---|" * len(kinds)]
    for row in report["rows"]:
        lines.append(f"| {row['preset']} | {row['num_gaussians']} "
                     f"| {row['seconds_per_step'] * 1e3:.0f} | {row['aten_calls_per_step']:.0f} | "
                     + " | ".join(f"{row['shares'][kind]:.0%}" for kind in kinds) + " |")
    lines += ["", "The operators with the most self time (ms per step, calls per step):", "",
              "| preset | operators |", "|---|---|"]
    for row in report["rows"]:
        top = ", ".join(f"`{op['operator']}` {op['ms_per_step']:.1f} ({op['calls_per_step']:.0f})"
                        for op in row["top"])
        lines.append(f"| {row['preset']} | {top} |")
    return "\n".join(lines)


def densify_split_table(report: dict) -> str:
    """Markdown for one bench_densify_split report: one row per split mode."""
    rows = report["rows"]
    lines = [
        f"{report['cpu']}, {report['date'][:10]}, `{report['preset']}` on the full pulling "
        f"phantom, {rows[0]['iterations']} iterations:",
        "",
        "| split | test psnr_tissue change across each densifying step, dB | mean dB "
        "| first iteration at 35 dB | final test psnr_tissue | Gaussians |",
        "|---|---|---|---|---|---|",
    ]
    for row in rows:
        changes = ", ".join(f"{step['change_db']:+.2f}" for step in row["densifying_steps"])
        lines.append(f"| {row['split']} | {changes} | {cell(row, 'mean_change_db', '+.2f')} "
                     f"| {row['iteration_to_35db'] or 'not reached'} "
                     f"| {cell(row, 'final_test_psnr_tissue', '.2f')} | {row['num_gaussians']} |")
    return "\n".join(lines)


def stream_table(report: dict, results: str = "benchmarks/results") -> str:
    """Markdown for one bench_stream report: a row per scene and rate (means over the seeds),
    the highest rate followed, issue 57's targets, and the plot of lag and PSNR over the
    streams (a link into `results`)."""
    system = report["system"]
    seeds = sorted({len(row["seeds"]) for row in report["rows"]})
    lines = [
        f"{report['cpu']} ({system['logical_cpus']} logical CPUs, --threads "
        f"{report['threads']}, probe {report['probe_evals_per_s']:.2g} evaluations/s), "
        f"{report['date'][:10]}, `{report['command']}`; means over {'/'.join(map(str, seeds))} "
        f"seed(s); psnr_tissue on the test frames; offline = `surgsplat train --budget` for the "
        f"stream's wall time (first frame to last step), polished = a stream with "
        f"`--polish {report['polish_seconds']:g}` against an offline run of that much longer:",
        "",
        "| scene | fps | frames | lag median s | lag max s | lag growth s/s | untrained | steps "
        "| psnr_tissue | offline | polished | offline | forgetting dB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["rows"]:
        lines.append(
            f"| {row['scene']} | {row['rate']:g} | {cell(row, 'frames', 'd')} "
            f"| {cell(row, 'lag_median_s', '.2f')} | {cell(row, 'lag_max_s', '.2f')} "
            f"| {cell(row, 'lag_slope', '.2f')} | {cell(row, 'untrained_frames', 'd')} | {cell(row, 'steps', 'd')} "
            f"| {cell(row, 'psnr_tissue', '.2f')} | {cell(row, 'psnr_tissue_offline', '.2f')} "
            f"| {cell(row, 'psnr_tissue_polished', '.2f')} "
            f"| {cell(row, 'psnr_tissue_polished_offline', '.2f')} "
            f"| {cell(row, 'forgetting_db', '.2f')} |")
    followed = ", ".join(f"{scene} {'none' if rate is None else f'{rate:g} fps'}"
                         for scene, rate in report["highest_rate_followed"].items())
    lines += ["", f"Highest of these rates followed (the lag does not grow over the stream, "
                  f"its median <= 1 s and its max <= 3 s, every frame trained on): {followed}."]
    if report["targets"]:  # the targets are at 5 fps
        lines += ["", "| case | target | measured | bound | met |", "|---|---|---|---|---|"]
    for target in report["targets"]:
        spec = "d" if target["metric"] == "untrained_frames" else ".2f"
        lines.append(f"| {target['case']} | {target['rule']} | {cell(target, 'value', spec)} "
                     f"| {cell(target, 'bound', spec)} "
                     f"| {'yes' if target['met'] else '**no**'} |")
    lines += ["", f"![lag of each frame over the stream, and PSNR per frame on arrival, once "
                  f"integrated and at the end]({results}/{report['plot']})"]
    return "\n".join(lines)


RENDERERS = {"bench_render": render_table, "bench_train": train_table,
             "op_census": op_census_table,
             "bench_densify_split": densify_split_table,
             "bench_threads": render_threads_table,
             "bench_outputs": outputs_table, "bench_auto_masks": auto_masks_table,
             "bench_shading_depth": shading_depth_table, "bench_batch": methods_table,
             "bench_long_clip": long_clip_table,
             "bench_long_clip_validation": long_clip_validation_table,
             "bench_articulation": articulation_table,
             "bench_faults": faults_table, "bench_onnx_models": onnx_models_table,
             "bench_poses": poses_table, "bench_camera_grads": camera_grads_table,
             "bench_stream": stream_table}
METHOD_SUITE_REGION = re.compile(r"<!-- (bench_methods_\w+):begin -->")
"""A region of one bench_methods suite, e.g. bench_methods_endoplanar."""
PRESET_REGION = re.compile(r"<!-- (preset_[a-z0-9]+_\w+):begin -->")
"""A region of one preset's rows of one bench_methods suite, preset_<suite>_<preset>, e.g.
preset_fidelity_endogsg."""
DOCS = ROOT / "docs"


def preset_region_parts(benchmark: str) -> tuple[str, str] | None:
    """The suite and the preset of a region preset_<suite>_<preset>; None for other regions."""
    if not PRESET_REGION.fullmatch(f"<!-- {benchmark}:begin -->"):
        return None
    suite, preset = benchmark.removeprefix("preset_").split("_", 1)
    return suite, preset


def preset_table(report: dict, preset: str) -> str:
    """Markdown of one preset's rows of a bench_methods suite report (the preset in every case
    of the suite that trains it) with the columns those rows have, and the targets of those
    rows; empty when the report has no row of the preset (another machine's report, say)."""
    rows = [row for row in report["rows"] if row.get("method") == preset]
    if not rows:
        return ""
    cases = {row["case"] for row in rows}
    columns = [key for key in report["columns"] if any(row.get(key) is not None for row in rows)]
    targets = [target for target in report.get("targets", []) if target["case"] in cases]
    return methods_table({**report, "rows": rows, "columns": columns, "targets": targets})


def renderer(benchmark: str, results: str):
    """The function that turns one report of `benchmark`'s results into Markdown, for a page
    from which the results folder is at the relative path `results`."""
    if (parts := preset_region_parts(benchmark)) is not None:
        return lambda report: preset_table(report, parts[1])
    if benchmark == "bench_train":
        return lambda report: train_table(report, results)
    if benchmark == "bench_stream":
        return lambda report: stream_table(report, results)
    return methods_table if benchmark.startswith("bench_methods_") else RENDERERS[benchmark]


def generated_region(benchmark: str, page: Path) -> str:
    parts = preset_region_parts(benchmark)
    source = benchmark if parts is None else f"bench_methods_{parts[0]}"
    reports = [json.loads(path.read_text())
               for path in sorted(RESULTS.glob(f"{source}-*.json"))]
    if not reports:
        sys.exit(f"no {source} results in {RESULTS}: run the benchmark that writes them")
    render = renderer(benchmark, os.path.relpath(RESULTS, page.parent).replace(os.sep, "/"))
    body = "\n\n".join(table for report in reports if (table := render(report)))
    if not body:
        sys.exit(f"{page.relative_to(ROOT)}: region {benchmark} has no rows in {RESULTS}")
    note = ("<!-- generated by benchmarks/readme_tables.py from benchmarks/results/; "
            "do not edit -->")
    return f"<!-- {benchmark}:begin -->\n{note}\n{body}\n<!-- {benchmark}:end -->"


def replace_region(text: str, benchmark: str, page: Path) -> str:
    begin, end = f"<!-- {benchmark}:begin -->", f"<!-- {benchmark}:end -->"
    if text.count(begin) != 1 or text.count(end) != 1:
        sys.exit(f"{page.relative_to(ROOT)}: expected one {begin} and one {end}")
    head, rest = text.split(begin)
    _, tail = rest.split(end)
    return head + generated_region(benchmark, page) + tail


def regions(text: str) -> list[str]:
    """The generated regions a page holds."""
    return [*(benchmark for benchmark in RENDERERS if f"<!-- {benchmark}:begin -->" in text),
            *METHOD_SUITE_REGION.findall(text), *PRESET_REGION.findall(text)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true",
                        help="exit 1 if a page under docs/ differs from the results instead of "
                             "writing")
    args = parser.parse_args()
    pages, placed = {}, {}
    for page in sorted(DOCS.rglob("*.md")):
        text = page.read_text()
        found = regions(text)
        for benchmark in found:
            if benchmark in placed:
                sys.exit(f"region {benchmark} is in both {placed[benchmark]} and "
                         f"{page.relative_to(ROOT)}; keep one")
            placed[benchmark] = page.relative_to(ROOT)
        if found:
            updated = text
            for benchmark in found:
                updated = replace_region(updated, benchmark, page)
            pages[page] = (text, updated)
    missing = [benchmark for benchmark in RENDERERS if benchmark not in placed]
    if missing:
        sys.exit(f"no page under docs/ has the region of {', '.join(missing)}")
    stale = [page for page, (text, updated) in pages.items() if text != updated]
    if args.check:
        sys.exit(0 if not stale else ", ".join(str(page.relative_to(ROOT)) for page in stale)
                 + " not up to date with benchmarks/results: run benchmarks/readme_tables.py")
    for page in stale:
        page.write_text(pages[page][1])


if __name__ == "__main__":
    main()
