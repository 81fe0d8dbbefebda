"""`surgsplat phantom --out DIR`: generate the ground-truth phantom scene."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.cli.info import print_summary_table
from surgsplat.cli.progress import progress_bar
from surgsplat.data.phantom.camera_path import CAMERAS
from surgsplat.data.phantom.generate import (MAX_SEED, PRESETS, PhantomConfig,
                                             check_phantom_request, generate_phantom)
from surgsplat.data.phantom.motion import MOTIONS
from surgsplat.data.phantom.shading import LIGHTINGS


def phantom_command(
    out: Annotated[Path, typer.Option(help="New (or empty) folder to write the scene to.")],
    preset: Annotated[str, typer.Option(help=f"Size: {', '.join(PRESETS)}.")] = "small",
    motion: Annotated[str, typer.Option(help=f"Tissue motion: {', '.join(MOTIONS)}.")] = "pulling",
    camera: Annotated[str, typer.Option(
        help=f"Endoscope: {', '.join(CAMERAS)} (moving: translates a few mm and turns a few "
             "degrees; poses in poses_bounds.npy and gt/camera_poses.npy).")] = "static",
    seed: Annotated[int, typer.Option(
        help=f"Seed of texture, shape and tool path, 0..{MAX_SEED}.")] = 0,
    frames: Annotated[int | None, typer.Option(help="Number of frames (preset default if "
                                                     "omitted).")] = None,
    lighting: Annotated[str, typer.Option(
        help=f"Light over the clip: {', '.join(LIGHTINGS)} (livar: the standard light with the "
             "true shading in gt/shading; hivar: light intensity and exposure each vary over "
             "2x and the light circles off the camera centre).")] = "standard",
) -> None:
    """Ray-cast a synthetic deforming tissue with a tool, with ground truth under gt/."""
    start = time.perf_counter()
    config = PhantomConfig(preset=preset, motion=motion, camera=camera, seed=seed,
                           num_frames=frames, lighting=lighting)
    _, num_frames = check_phantom_request(config, out)
    with progress_bar() as bar:
        task = bar.add_task(f"phantom {preset} {motion} {camera} {lighting}", total=num_frames)

        def report(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        scene_dir = generate_phantom(config, out, report)
    print_summary_table(scene_dir)
    Console().print(f"phantom written to {scene_dir} in {time.perf_counter() - start:.1f} s")
