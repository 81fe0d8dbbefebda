"""`surgsplat <command>`: the command-line entry point.

Each command lives in its own module of this package as a plain function with typer
annotations; this module only registers them and turns user errors into one clear line.
"""

from __future__ import annotations

import sys
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.errors import SurgsplatError

app = typer.Typer(
    name="surgsplat",
    help="4D Gaussian-splat reconstruction of endoscopic surgical video, on the CPU.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback()
def _root(
    threads: Annotated[int | None, typer.Option(
        "--threads", min=1, help="Threads of torch and the native kernels (default: one per "
        "core, or OMP_NUM_THREADS).")] = None,
) -> None:
    """surgsplat: endoscopic video in, deforming 3D tissue, meshes, videos and metrics out."""
    if threads is not None:
        from surgsplat.render.native import set_threads

        set_threads(threads)


def _register() -> None:
    from surgsplat.cli import (demo, eval_cmd, export_cmd, import_cmd, info, methods, phantom,
                               render_videos, report_cmd, train, view)

    app.command("demo")(demo.demo_command)
    app.command("phantom")(phantom.phantom_command)
    app.command("import")(import_cmd.import_command)
    app.command("info")(info.info_command)
    app.command("methods")(methods.methods_command)
    app.command("train")(train.train_command)
    app.command("eval")(eval_cmd.eval_command)
    app.command("render")(render_videos.render_command)
    app.command("export")(export_cmd.export_command)
    app.command("report")(report_cmd.report_command)
    app.command("view")(view.view_command)


def main() -> None:
    """Run the CLI; a SurgsplatError becomes `error: <message>` and exit status 2."""
    _register()
    try:
        app(standalone_mode=True)
    except SurgsplatError as err:
        Console(stderr=True, soft_wrap=True).print(f"[bold red]error:[/] {err}", highlight=False)
        sys.exit(2)


if __name__ == "__main__":
    main()
