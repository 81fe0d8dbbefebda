"""`surgsplat methods`: the method presets, one line each, or one preset's full config."""

from __future__ import annotations

import json
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from surgsplat.methods.config import to_dict
from surgsplat.methods.registry import PRESETS, UNLOADABLE, method_config


def methods_command(
    show: Annotated[str | None, typer.Argument(
        help="Print this preset's full configuration as JSON (usable with --config).")] = None,
) -> None:
    """List the method presets (those of installed packages too), or print one preset's
    configuration."""
    console = Console()
    if show is not None:
        console.print_json(json.dumps(to_dict(method_config(show))))
        return
    table = Table(title="methods", show_header=True)
    table.add_column("preset")
    table.add_column("components")
    table.add_column("description")
    for name, preset in PRESETS.items():
        components = ", ".join(f"{key} ({value.kind})"
                               for key, value in preset.build().components.items())
        table.add_row(name, components, preset.description)
    console.print(table)
    for name, error in UNLOADABLE.items():
        console.print(f"not loaded: method {name!r}: {error}", markup=False, highlight=False)
