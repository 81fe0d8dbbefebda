"""`surgsplat <command>`: the command-line entry point.

Each command lives in its own module of this package as a plain function with typer
annotations; this module only registers them and turns user errors, operating-system errors
(permissions, a full disk, a missing folder, a file where a folder belongs) and stops (Ctrl-C,
SIGTERM) into one clear line.
"""

from __future__ import annotations

import functools
import signal
import sys
from collections.abc import Callable
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from surgsplat.errors import SurgsplatError, os_error_line

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


def _stoppable(command: Callable) -> Callable:
    """`command` with a stop (Ctrl-C or SIGTERM, seen as KeyboardInterrupt) turned into a
    SurgsplatError; commands that save work on a stop (train) report it themselves first."""

    @functools.wraps(command)
    def run(*args, **kwargs):
        try:
            return command(*args, **kwargs)
        except KeyboardInterrupt:
            raise SurgsplatError("interrupted (Ctrl-C or SIGTERM); every file it wrote is "
                                 "complete") from None

    return run


def _register() -> None:
    from surgsplat.cli import (articulate_cmd, batch, demo, eval_cmd, export_cmd, import_cmd, info,
                               methods, phantom, refine_masks_cmd, render_videos, report_cmd,
                               stream_cmd, train, view)

    for name, command in (("demo", demo.demo_command), ("phantom", phantom.phantom_command),
                          ("import", import_cmd.import_command), ("info", info.info_command),
                          ("methods", methods.methods_command), ("train", train.train_command),
                          ("stream", stream_cmd.stream_command),
                          ("eval", eval_cmd.eval_command),
                          ("render", render_videos.render_command),
                          ("export", export_cmd.export_command),
                          ("articulate", articulate_cmd.articulate_command),
                          ("refine-masks", refine_masks_cmd.refine_masks_command),
                          ("report", report_cmd.report_command), ("view", view.view_command),
                          ("batch", batch.batch_command)):
        app.command(name)(_stoppable(command))


def _terminate(signum: int, frame: object) -> None:
    """SIGTERM takes Ctrl-C's path: training checkpoints, then the command stops cleanly."""
    raise KeyboardInterrupt


def main() -> None:
    """Run the CLI; a SurgsplatError or an OSError becomes `error: <message>` and exit status 2."""
    _register()
    signal.signal(signal.SIGTERM, _terminate)
    console = Console(stderr=True, soft_wrap=True)
    try:
        app(standalone_mode=True)
    except SurgsplatError as err:
        console.print(f"[bold red]error:[/] {escape(str(err))}", highlight=False)
        sys.exit(2)
    except OSError as err:
        console.print(f"[bold red]error:[/] {escape(os_error_line(err))}", highlight=False)
        sys.exit(2)


if __name__ == "__main__":
    main()
