"""`surgsplat info DIR`: load and validate a scene folder and print its summary."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from surgsplat.data.scene import load_scene
from surgsplat.data.summary import format_summary, summarise


def print_summary_table(scene_dir: Path, depth_scale: float | None = None) -> None:
    """Load `scene_dir` (raising DataError on any problem) and print its summary table."""
    summary = summarise(load_scene(scene_dir, depth_scale=depth_scale))
    table = Table(title="scene summary", show_header=False)
    for label, value in format_summary(summary):
        table.add_row(label, value)
    Console().print(table)


def info_command(
    scene_dir: Annotated[Path, typer.Argument(help="EndoNeRF-layout scene folder.")],
    depth_scale: Annotated[float | None, typer.Option(
        help="Scene units per stored integer of PNG depth files (overrides scene.json).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
) -> None:
    """Load and validate a scene; print frames, size, split, depth range and tool coverage."""
    if as_json:
        summary = summarise(load_scene(scene_dir, depth_scale=depth_scale))
        print(json.dumps(asdict(summary), indent=2))
    else:
        print_summary_table(scene_dir, depth_scale)
