"""`surgsplat render RUN`: mp4 videos of the reconstruction over all frames.

`--channels` picks the videos (default: rgb, depth, normal, side_by_side; a decomposing method
such as lumistate adds reflectance and illumination); `--relight uniform|FRAME` renders them
under another illumination state (see model/lumistate.py), into files named NAME-relit-SOURCE.mp4.
"""

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
from surgsplat.model.lumistate import UNIFORM, LumiState
from surgsplat.model.dynamic import render_frame
from surgsplat.errors import SurgsplatError
from surgsplat.train.run import TrainedRun, load_trained_run, run_lock

VIDEO_NAMES = ("rgb.mp4", "depth.mp4", "normal.mp4", "side_by_side.mp4")
DEFAULT_CHANNELS = tuple(name.removesuffix(".mp4") for name in VIDEO_NAMES)
EXTRA_CHANNELS = ("reflectance", "illumination")
"""Videos of render channels that only some methods have (output.extras)."""
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


def parse_channels(text: str) -> tuple[str, ...]:
    """--channels "a,b,..." -> the names; SurgsplatError naming the valid ones otherwise."""
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    valid = DEFAULT_CHANNELS + EXTRA_CHANNELS
    unknown = [name for name in names if name not in valid]
    if unknown or not names:
        raise SurgsplatError(f"--channels: expected a comma-separated list of {', '.join(valid)}; "
                             f"got {text!r}")
    return names


def parse_relight(text: str | None, num_frames: int) -> str | int | None:
    """--relight "uniform" or a frame index -> the source; SurgsplatError otherwise."""
    if text is None or text == UNIFORM:
        return text
    if text.isdigit() and int(text) < num_frames:
        return int(text)
    raise SurgsplatError(f"--relight: expected {UNIFORM!r} or a frame index in "
                         f"[0, {num_frames}), got {text!r}")


def illumination_component(run: TrainedRun) -> LumiState:
    """The run's illumination component; SurgsplatError when its method has none."""
    found = [c for c in run.model.components.values() if isinstance(c, LumiState)]
    if not found:
        raise SurgsplatError(f"--relight: method {run.config.name!r} has no illumination "
                             "state to change (lumistate has)")
    return found[0]


def write_run_videos(run: TrainedRun, out_dir: Path, fps: float,
                     channels: tuple[str, ...] = DEFAULT_CHANNELS,
                     relight: str | int | None = None, tissue_only: bool = False) -> list[Path]:
    """Render every frame of the run's scene (under illumination `relight` when given, see
    LumiState.relit; with `tissue_only`, the tissue-only render, the tool left out); write one
    video per channel in `channels`, frame by frame (memory does not grow with the clip)."""
    near, far = depth_range(run)
    background = torch.tensor(run.config.train.background, dtype=torch.float32)
    frames = run.scene.frames
    suffix = "" if relight is None else f"-relit-{relight}"
    with ExitStack() as stack:
        if relight is not None:
            stack.enter_context(illumination_component(run).relit(relight))
        videos = {name: stack.enter_context(VideoWriter(out_dir / f"{name}{suffix}.mp4", fps))
                  for name in channels}
        bar = stack.enter_context(progress_bar())
        task = bar.add_task("render", total=len(frames))
        for frame in frames:
            camera = frame.camera
            when = FrameTime(frame.index, frame.time, tissue_only=tissue_only)
            out = render_frame(run.model, camera, when, background)
            missing = [name for name in channels if name in EXTRA_CHANNELS
                       and name not in out.extras]
            if missing:
                raise SurgsplatError(f"--channels: method {run.config.name!r} renders no "
                                     f"{missing[0]!r} channel (lumistate does)")
            images = {"rgb": lambda: to_uint8(out.rgb.numpy()),
                      "depth": lambda: colorize_depth(out.depth.numpy(), near, far),
                      "normal": lambda: colorize_normals(*(x.numpy() for x in
                                                           surface_normals(out, camera.K)[:2])),
                      "side_by_side": lambda: np.concatenate(
                          [to_uint8(frame.image.numpy()), to_uint8(out.rgb.numpy()),
                           colorize_depth(out.depth.numpy(), near, far)], axis=1),
                      "reflectance": lambda: to_uint8(out.extras["reflectance"].numpy()),
                      "illumination": lambda: to_uint8(
                          out.extras["illumination"].expand(-1, -1, 3).numpy())}
            for name, video in videos.items():
                video.add(even_size(images[name]()))
            bar.advance(task)
    return [video.path for video in videos.values()]


def render_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    out: Annotated[Path | None, typer.Option(help="Video folder (default RUN/videos).")] = None,
    fps: Annotated[float, typer.Option(help="Frames per second of the videos.")] = 15.0,
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
    channels: Annotated[str, typer.Option(
        help="Comma-separated videos to write: " + ", ".join(DEFAULT_CHANNELS + EXTRA_CHANNELS)
             + " (reflectance and illumination: methods that decompose, e.g. lumistate).")]
        = ",".join(DEFAULT_CHANNELS),
    relight: Annotated[str | None, typer.Option(
        help="Render under another illumination state: 'uniform' (the training frames' mean, "
             "constant over time) or a frame index (that frame's); lumistate runs only. Files "
             "are named NAME-relit-SOURCE.mp4.")] = None,
    tool_free: Annotated[bool, typer.Option(
        "--tool-free", help="Render the tissue only, the tool left out (methods with a tool "
        "field, e.g. physiosplat); default folder RUN/videos_tool_free.")] = False,
) -> None:
    """Render RGB, colour-mapped depth, normal maps and input|render|depth side-by-side mp4
    videos (or the --channels chosen)."""
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise SurgsplatError(f"--fps must be a number in (0, {MAX_FPS:g}], got {fps}")
    names = parse_channels(channels)
    with run_lock(run_dir):
        run = load_trained_run(run_dir, data)
        if tool_free and not run.model.separates_tool:
            raise SurgsplatError(f"--tool-free: method {run.config.name!r} of {run_dir} has no "
                                 "tool field to leave out (train e.g. --method physiosplat)")
        default = run_dir / ("videos_tool_free" if tool_free else "videos")
        source = parse_relight(relight, len(run.scene.frames))
        paths = write_run_videos(run, out or default, fps, names, source, tissue_only=tool_free)
    Console().print("videos: " + ", ".join(str(p) for p in paths))
