"""`surgsplat stream SOURCE --out RUN`: reconstruct while the video plays."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import TextColumn

from surgsplat.cli.progress import progress_bar
from surgsplat.cli.train import new_run_folder
from surgsplat.methods.overrides import build_method_config
from surgsplat.methods.registry import DEFAULT_PRESET
from surgsplat.pipeline.stream import (BAD_FRAME_ACTIONS, MASK_SOURCES, STREAM_LOG,
                                       StreamOptions, stream_run)
from surgsplat.train.trainer import StepStats


def stream_command(
    source: Annotated[str, typer.Argument(
        help="A video file (played at its frame rate, or --rate), a folder that frames are "
             "being written into (image files, or a scene folder's images/ with depth/ and "
             "masks/), or a camera's OpenCV index.")],
    out: Annotated[Path, typer.Option(help="Run folder to write.")] = Path("runs/stream"),
    method: Annotated[str | None, typer.Option(
        help=f"Method preset (default {DEFAULT_PRESET}). Its components must follow a clip "
             "that grows; a method that cannot is refused, naming what stops it and the "
             "methods that stream.")] = None,
    rate: Annotated[float | None, typer.Option(
        help="Play a video at this many frames per second instead of its own rate.",
        min=0.01)] = None,
    frames: Annotated[int | None, typer.Option(
        help="Frames the source will send, when it cannot say: the clip's time axis is set "
             "up for them (a longer stream doubles it), and a folder's stream ends after them "
             "(a scene folder's poses_bounds.npy says it otherwise).", min=2)] = None,
    polish: Annotated[float, typer.Option(
        help="Seconds of training after the last frame (the learning rates decay over them).",
        min=0.0)] = 0.0,
    checkpoint_every: Annotated[float, typer.Option(
        help="Seconds between checkpoints while the stream runs (and after its first frame): "
             "what `surgsplat view RUN` shows meanwhile.", min=1.0)] = 10.0,
    tool_masks: Annotated[str, typer.Option(
        help=f"Tool masks: {', '.join(MASK_SOURCES)} (given: a scene folder's masks/; auto: "
             "the automatic segmenter on each frame as it arrives, one frame behind).")
    ] = "given",
    focal: Annotated[float | None, typer.Option(
        help="Focal length in pixels of a video or camera (default: a 70 degree horizontal "
             "field of view; a scene folder's own camera otherwise).", min=0.001)] = None,
    idle_timeout: Annotated[float, typer.Option(
        help="A folder's stream ends after this many seconds without a new frame, if not "
             "after its frames (and is an error when none came).", min=0.01)] = 10.0,
    on_bad_frame: Annotated[str, typer.Option(
        help=f"A frame that cannot be read: {' or '.join(BAD_FRAME_ACTIONS)} (the run so far "
             "is kept either way).")] = "skip",
    config: Annotated[Path | None, typer.Option(
        "--config", help="JSON or TOML file of method settings.")] = None,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Change one method setting (repeatable; applied after --config).")
    ] = None,
) -> None:
    """Train a reconstruction while the frames arrive, keeping up with the source; Ctrl-C
    ends the stream and keeps the run. RUN is an ordinary run (eval, render, view, export)
    with RUN/stream_log.jsonl: each frame's arrival, lag and PSNR."""
    method_config = build_method_config(method, config, set_ or [])
    options = StreamOptions(source=source, out=out, rate=rate, frames=frames,
                            idle_timeout=idle_timeout, on_bad_frame=on_bad_frame,
                            tool_masks=tool_masks, focal=focal, polish_seconds=polish,
                            checkpoint_seconds=checkpoint_every)
    console = Console(soft_wrap=True)  # a line per note, whatever the terminal's width
    with new_run_folder(out), progress_bar(
            TextColumn("{task.fields[frames]} frames"), TextColumn("PSNR {task.fields[psnr]:.2f}"),
            TextColumn("{task.fields[gaussians]} Gaussians")) as bar:
        task = bar.add_task(f"stream {method_config.name}", total=None, frames=0, psnr=0.0,
                            gaussians=0)

        def report(stats: StepStats, frames_so_far: int) -> None:
            bar.update(task, completed=stats.iteration, frames=frames_so_far, psnr=stats.psnr,
                       gaussians=stats.num_gaussians)

        result = stream_run(method_config, options,
                            lambda text: console.print(text, markup=False, highlight=False),
                            report)
    lags = sorted(r.lag for r in result.records if r.lag is not None)
    median = lags[len(lags) // 2] if lags else float("nan")
    console.print(f"streamed {len(result.records)} frames ({len(result.bad_frames)} bad) in "
                  f"{result.steps_streaming} steps, {result.polish_steps} polishing; median lag "
                  f"{median:.2f} s, max {max(lags, default=float('nan')):.2f} s; run folder: "
                  f"{out} (per frame: {out / STREAM_LOG})", highlight=False)
