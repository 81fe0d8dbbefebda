"""`surgsplat render RUN`: mp4 videos of the reconstruction over all frames."""

from __future__ import annotations

import math
from contextlib import ExitStack
from pathlib import Path
from typing import Annotated

import numpy as np
import torch
import typer
from rich.console import Console

from surgsplat.cli.progress import progress_bar
from surgsplat.eval.normals import surface_normals
from surgsplat.export.video import (VideoWriter, colorize_depth, colorize_normals, even_size,
                                    to_uint8)
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


def write_run_videos(run: TrainedRun, out_dir: Path, fps: float) -> list[Path]:
    """Render every frame of the run's scene; write rgb, depth, normal and side-by-side videos,
    frame by frame (memory does not grow with the clip)."""
    near, far = depth_range(run)
    background = torch.tensor(run.config.train.background, dtype=torch.float32)
    frames = run.scene.frames
    with ExitStack() as files, progress_bar() as bar:
        videos = [files.enter_context(VideoWriter(out_dir / name, fps)) for name in VIDEO_NAMES]
        task = bar.add_task("render", total=len(frames))
        for frame in frames:
            camera = frame.camera
            out = render_frame(run.model, camera, FrameTime(frame.index, frame.time), background)
            rgb = to_uint8(out.rgb.numpy())
            depth = colorize_depth(out.depth.numpy(), near, far)
            normals, valid, _ = surface_normals(out, camera.K)
            normal = colorize_normals(normals.numpy(), valid.numpy())
            side = np.concatenate([to_uint8(frame.image.numpy()), rgb, depth], axis=1)
            for video, image in zip(videos, (rgb, depth, normal, side)):
                video.add(even_size(image))
            bar.advance(task)
    return [video.path for video in videos]


def render_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    out: Annotated[Path | None, typer.Option(help="Video folder (default RUN/videos).")] = None,
    fps: Annotated[float, typer.Option(help="Frames per second of the videos.")] = 15.0,
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
) -> None:
    """Render RGB, colour-mapped depth, normal maps and input|render|depth side-by-side mp4
    videos."""
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise SurgsplatError(f"--fps must be a number in (0, {MAX_FPS:g}], got {fps}")
    with run_lock(run_dir):
        run = load_trained_run(run_dir, data)
        paths = write_run_videos(run, out or run_dir / "videos", fps)
    Console().print("videos: " + ", ".join(str(p) for p in paths))
