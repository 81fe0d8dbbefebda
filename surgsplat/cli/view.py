"""`surgsplat view RUN`: an interactive 4D viewer of a run in the browser (viser, offline)."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from surgsplat.errors import SurgsplatError
from surgsplat.export.viewer import RunViewer
from surgsplat.pipeline.stream_scene import LIVE_FILE, LiveFollower, load_live_run
from surgsplat.train.run import load_trained_run

MAX_HEIGHT = 4320
"""Largest --height accepted (8K video's height)."""


def view_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `surgsplat train`.")],
    port: Annotated[int, typer.Option(help="Port of the viewer's web server; a port in use is "
                                           "refused, not replaced by another.")] = 8080,
    host: Annotated[str, typer.Option(help="Address to serve on (127.0.0.1: this machine "
                                           "only).")] = "127.0.0.1",
    height: Annotated[int | None, typer.Option(
        help="Rendered image height in pixels (default: the scene's).")] = None,
) -> None:
    """Orbit, pan and zoom a run, scrub or play its time, and switch between colour, depth and
    normals; frames are rendered by surgsplat on this CPU. A run that `surgsplat stream` is
    still training is followed as it grows, at its latest frame. Ctrl-C stops the server. A
    --port in use or a --host that cannot be served on stops it at once with one line (the
    address the server listens on is the one printed)."""
    if not 0 < port < 65536:
        raise SurgsplatError(f"--port must be in 1..65535, got {port}")
    if height is not None and not 0 < height <= MAX_HEIGHT:
        raise SurgsplatError(f"--height must be in 1..{MAX_HEIGHT} pixels, got {height}")
    if (run_dir / LIVE_FILE).is_file():  # a stream is training the run: follow it
        run = load_live_run(run_dir)
        viewer = RunViewer(run, host=host, port=port, height=height,
                           follow=LiveFollower(run_dir, run))
    else:
        viewer = RunViewer(load_trained_run(run_dir), host=host, port=port, height=height)
    Console().print(f"viewer at {viewer.url} (Ctrl-C stops it)", highlight=False)
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        viewer.stop()
