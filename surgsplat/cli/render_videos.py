"""`surgsplat render RUN`: mp4 videos of the reconstruction over all frames."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import numpy as np
import torch
import typer
from rich.console import Console

from surgsplat.cli.progress import progress_bar
from surgsplat.eval.normals import surface_normals
from surgsplat.export.video import colorize_depth, colorize_normals, even_size, to_uint8, write_video
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import render_frame
from surgsplat.errors import SurgsplatError
from surgsplat.train.run import TrainedRun, load_trained_run, run_lock

VIDEO_NAMES = ("rgb.mp4", "depth.mp4", "normal.mp4", "side_by_side.mp4")
MAX_FPS = 1000.0
"""Largest --fps accepted."""


def depth_range(run: TrainedRun) -> tuple[float, float]:
    """Colour-map range: 1st-99th percentile of the scene's valid depth (or of frame 0's
    rendered depth for scenes without depth)."""
    if run.scene.has_depth:
        values = torch.cat([f.depth[f.depth > 0][::97] for f in run.scene.frames])
    else:
        out = render_frame(run.model, run.scene.frames[0].camera, FrameTime(0, 0.0))
        values = out.depth[out.alpha > 0.5]
    if values.numel() == 0:
        return 0.0, 1.0
    return float(values.quantile(0.01)), float(values.quantile(0.99))


def write_run_videos(run: TrainedRun, out_dir: Path, fps: float,
                     tissue_only: bool = False) -> list[Path]:
    """Render every frame of the run's scene; write rgb, depth and side-by-side videos; with
    `tissue_only`, of the tissue-only render (the tool left out)."""
    near, far = depth_range(run)
    background = torch.tensor(run.config.train.background, dtype=torch.float32)
    frames = run.scene.frames
    videos: list[list[np.ndarray]] = [[] for _ in VIDEO_NAMES]
    with progress_bar() as bar:
        task = bar.add_task("render", total=len(frames))
        for frame in frames:
            camera = frame.camera
            when = FrameTime(frame.index, frame.time, tissue_only=tissue_only)
            out = render_frame(run.model, camera, when, background)
            rgb = to_uint8(out.rgb.numpy())
            depth = colorize_depth(out.depth.numpy(), near, far)
            normals, valid, _ = surface_normals(out, camera.K)
            normal = colorize_normals(normals.numpy(), valid.numpy())
            side = np.concatenate([to_uint8(frame.image.numpy()), rgb, depth], axis=1)
            for video, image in zip(videos, (rgb, depth, normal, side)):
                video.append(even_size(image))
            bar.advance(task)
    paths = [out_dir / name for name in VIDEO_NAMES]
    for path, video in zip(paths, videos):
        write_video(path, video, fps)
    return paths


def render_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    out: Annotated[Path | None, typer.Option(help="Video folder (default RUN/videos).")] = None,
    fps: Annotated[float, typer.Option(help="Frames per second of the videos.")] = 15.0,
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
    tool_free: Annotated[bool, typer.Option(
        "--tool-free", help="Render the tissue only, the tool left out (methods with a tool "
        "field, e.g. physiosplat); default folder RUN/videos_tool_free.")] = False,
) -> None:
    """Render RGB, colour-mapped depth, normal maps and input|render|depth side-by-side mp4
    videos."""
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise SurgsplatError(f"--fps must be a number in (0, {MAX_FPS:g}], got {fps}")
    with run_lock(run_dir):
        run = load_trained_run(run_dir, data)
        if tool_free and not run.model.separates_tool:
            raise SurgsplatError(f"--tool-free: method {run.config.name!r} of {run_dir} has no "
                                 "tool field to leave out (train e.g. --method physiosplat)")
        default = run_dir / ("videos_tool_free" if tool_free else "videos")
        paths = write_run_videos(run, out or default, fps, tissue_only=tool_free)
    Console().print("videos: " + ", ".join(str(p) for p in paths))
