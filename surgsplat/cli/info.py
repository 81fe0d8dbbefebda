"""`surgsplat info DIR`: load and validate a scene folder and print its summary;
`surgsplat info --system`: the CPU, the native kernels' ISA variant and the threads."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from surgsplat.data.scene import check_depth_scale, load_scene
from surgsplat.data.summary import format_summary, summarise
from surgsplat.errors import SurgsplatError
from surgsplat.render.native import system_info


def print_summary_table(scene_dir: Path, depth_scale: float | None = None) -> None:
    """Load `scene_dir` (raising DataError on any problem) and print its summary table."""
    summary = summarise(load_scene(scene_dir, depth_scale=depth_scale))
    table = Table(title="scene summary", show_header=False)
    for label, value in format_summary(summary):
        table.add_row(label, value)
    Console().print(table)


def print_system(as_json: bool) -> None:
    """Print system_info() as a table, or as JSON."""
    info = system_info()
    if as_json:
        print(json.dumps(info, indent=2))
        return
    table = Table(title="system", show_header=False)
    for label, value in info.items():
        table.add_row(label.replace("_", " "),
                      ", ".join(value) if isinstance(value, list) else str(value))
    Console().print(table)


def info_command(
    scene_dir: Annotated[Path | None, typer.Argument(
        help="EndoNeRF-layout scene folder.")] = None,
    depth_scale: Annotated[float | None, typer.Option(
        help="Scene units per stored integer of PNG depth files (overrides scene.json).")] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")] = False,
    system: Annotated[bool, typer.Option(
        "--system", help="Print the CPU, the ISA variant of the native kernels in use and the "
        "threads instead of a scene summary.")] = False,
) -> None:
    """Load and validate a scene; print frames, size, split, depth range and tool coverage
    (or, with --system, what runs the kernels)."""
    if system:
        print_system(as_json)
        return
    if scene_dir is None:
        raise SurgsplatError("info: give a scene folder, or --system")
    if depth_scale is not None:
        check_depth_scale(depth_scale, "--depth-scale")
    if as_json:
        summary = summarise(load_scene(scene_dir, depth_scale=depth_scale))
        print(json.dumps(asdict(summary), indent=2))
    else:
        print_summary_table(scene_dir, depth_scale)
