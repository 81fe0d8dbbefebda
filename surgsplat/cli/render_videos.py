"""`surgsplat render RUN`: mp4 videos of the reconstruction over all frames.

`--channels` picks the videos (default: rgb, depth, normal, side_by_side; any other channel the
run's method declares, e.g. a reflectance and an illumination); `--relight uniform|FRAME`
renders them under another illumination state (methods that model one), into files named
NAME-relit-SOURCE.mp4.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.cli.progress import progress_bar
from surgsplat.errors import SurgsplatError
from surgsplat.model.capabilities import UNIFORM
from surgsplat.model.channels import OBSERVED
from surgsplat.pipeline.render import DEFAULT_CHANNELS, video_channels, write_run_videos
from surgsplat.pipeline.run_folders import claim_output_folder, load_run
from surgsplat.train.run import TrainedRun, run_lock

MAX_FPS = 1000.0
"""Largest --fps accepted."""


def parse_channels(text: str) -> tuple[str, ...]:
    """--channels "a,b,..." -> the names (the run's method says which it renders, see
    `write_run_videos`); SurgsplatError when there is none."""
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    if not names:
        raise SurgsplatError(f"--channels: expected a comma-separated list of videos, e.g. "
                             f"{','.join(DEFAULT_CHANNELS)}; got {text!r}")
    return names


def parse_relight(text: str | None, num_frames: int) -> str | int | None:
    """--relight "uniform" or a frame index -> the source; SurgsplatError otherwise."""
    if text is None or text == UNIFORM:
        return text
    if text.isdigit() and int(text) < num_frames:
        return int(text)
    raise SurgsplatError(f"--relight: expected {UNIFORM!r} or a frame index in "
                         f"[0, {num_frames}), got {text!r}")


def write_videos_with_progress(run: TrainedRun, out_dir: Path, fps: float,
                               channels: tuple[str, ...] = DEFAULT_CHANNELS,
                               relight: str | int | None = None,
                               tissue_only: bool = False) -> list[Path]:
    """`write_run_videos` with a progress bar; the videos' paths."""
    with progress_bar() as bar:
        task = bar.add_task("render", total=len(run.scene.frames))
        return write_run_videos(run, out_dir, fps, channels, relight, tissue_only,
                                progress=lambda done, _: bar.update(task, completed=done))


def render_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    out: Annotated[Path | None, typer.Option(
        help="Video folder (default RUN/videos): a new or empty one, or one surgsplat wrote "
             "videos or exports into before.")] = None,
    fps: Annotated[float, typer.Option(help="Frames per second of the videos.")] = 15.0,
    data: Annotated[Path | None, typer.Option(
        help="Scene folder (default: the run's; its content must be the run's scene).")] = None,
    channels: Annotated[str, typer.Option(
        help="Comma-separated videos to write: " + ", ".join(DEFAULT_CHANNELS)
             + ", or any other channel the run's method declares (e.g. reflectance and "
               "illumination, for a method that separates them).")]
        = ",".join(DEFAULT_CHANNELS),
    relight: Annotated[str | None, typer.Option(
        help="Render under another illumination state: 'uniform' (the training frames' mean, "
             "constant over time) or a frame index (that frame's); runs of a method with an "
             "illumination state only. Files are named NAME-relit-SOURCE.mp4.")] = None,
    tool_free: Annotated[bool, typer.Option(
        "--tool-free", help="Render the tissue only, the tool left out (methods with a tool "
        "field only); default folder RUN/videos_tool_free; with the default --channels, also "
        "the observed channel of a method that fills tissue no frame shows.")] = False,
) -> None:
    """Render RGB, colour-mapped depth, normal maps and input|render|depth side-by-side mp4
    videos (or the --channels chosen)."""
    if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
        raise SurgsplatError(f"--fps must be a number in (0, {MAX_FPS:g}], got {fps}")
    names = parse_channels(channels)
    with run_lock(run_dir):
        run = load_run(run_dir, data)
        if tool_free and not run.model.separates_tool:
            raise SurgsplatError(f"--tool-free: method {run.config.name!r} of {run_dir} has no "
                                 "tool field to leave out (train with a method that has one; "
                                 "`surgsplat methods` lists each method's components)")
        if tool_free and names == DEFAULT_CHANNELS and OBSERVED in video_channels(run.model):
            names = (*names, OBSERVED)
        folder = out or run_dir / ("videos_tool_free" if tool_free else "videos")
        source = parse_relight(relight, len(run.scene.frames))
        claim_output_folder(folder, run_dir, "--out",
                            "render writes " + ", ".join(f"{name}.mp4" for name in names))
        paths = write_videos_with_progress(run, folder, fps, names, source,
                                           tissue_only=tool_free)
    Console().print("videos: " + ", ".join(str(p) for p in paths))
