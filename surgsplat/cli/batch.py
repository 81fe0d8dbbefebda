"""`surgsplat batch CLIPS... --out DIR`: reconstruct many clips as Ray tasks.

Every clip (a video, a folder of frames or a scene folder) is imported, trained, evaluated and
rendered as four chained Ray tasks that declare their CPUs and memory, on a local Ray instance
or, with --ray-address, on an existing cluster (whose workers must have surgsplat installed and
see DIR and the clips at the same paths). A failing task is retried (--retries), then its clip
is recorded failed with its error while the others go on. The batch is resumable: clips that
finished (done or failed) are skipped, an interrupted clip re-imports only when its scene is
incomplete and resumes training from its checkpoint. DIR/summary.csv collects every clip's
state and metrics, DIR/report.html (with the `report` extra) their runs: the clips of this
batch and those that earlier batches into DIR, with other clips, finished. A clip named as one
that an earlier batch finished from another source is refused.

A failed clip is one line on the console (its stage and error, never a task's traceback), and
the batch then exits with status 1; a second batch into a DIR in use is refused, and so is a
batch whose tasks no node could hold (see `surgsplat.pipeline.batch_cluster`). A stop (Ctrl-C or
SIGTERM) is one line saying how many clips finished; running the command again goes on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import TextColumn

from surgsplat.cli.progress import progress_bar
from surgsplat.errors import SurgsplatError
from surgsplat.methods.registry import DEFAULT_PRESET, PRESETS
from surgsplat.pipeline.batch import (SUMMARY_FILE, check_clip_folders, clip_jobs, finished_line,
                                      forget_failed, run_batch, write_summary)
from surgsplat.pipeline.batch_cluster import check_local_request
from surgsplat.pipeline.batch_stages import (FAILED, ClipJob, job_config, planned_iterations,
                                             read_status)
from surgsplat.train.run import run_lock


def batch_command(
    clips: Annotated[list[Path], typer.Argument(help="Videos, folders of frames or scene "
                                                     "folders, one clip each.")],
    out: Annotated[Path, typer.Option(help="Batch folder: one sub-folder per clip, "
                                           "summary.csv, report.html.")],
    method: Annotated[str, typer.Option(help=f"Method preset: {', '.join(PRESETS)}.")] =
        DEFAULT_PRESET,
    iters: Annotated[int | None, typer.Option(help="Training iterations per clip (preset "
                                                    "default if omitted).")] = None,
    ray_address: Annotated[str | None, typer.Option(
        help="Address of an existing Ray cluster: HOST:PORT of its head, ray://HOST:10001 "
             "(needs pip install \"ray[client]\") or auto (the cluster `ray start` runs on "
             "this machine); default: a new local Ray instance.")] = None,
    cpus_per_clip: Annotated[int, typer.Option(min=1, help="CPUs each task declares (and its "
                                                           "thread count).")] = 1,
    memory_gb: Annotated[float, typer.Option(min=0.1, help="Memory each task declares, "
                                                           "GiB.")] = 4.0,
    num_cpus: Annotated[int | None, typer.Option(min=1, help="CPUs of the local Ray instance "
                                                             "(default: all).")] = None,
    retries: Annotated[int, typer.Option(min=0, help="Retries of a failing task before its "
                                                     "clip is recorded failed.")] = 1,
    retry_failed: Annotated[bool, typer.Option(help="Run clips recorded failed again.")] = False,
    fps: Annotated[float, typer.Option(help="Frames per second of the videos.")] = 15.0,
    geometry: Annotated[bool, typer.Option(help="Evaluate geometry against gt/ meshes "
                                                "(phantoms).")] = True,
    set_: Annotated[list[str] | None, typer.Option(
        "--set", help="Change one setting of every clip's new run, as `surgsplat train --set` "
                      "does (repeatable).")] = None,
) -> None:
    """Import, train, evaluate and render many clips as Ray tasks; resumable. Exit status 1
    when a clip failed."""
    if iters is not None and iters <= 0:
        raise SurgsplatError(f"--iters must be positive, got {iters}")
    jobs = clip_jobs(clips, out, method, iters, cpus_per_clip, fps, geometry, tuple(set_ or ()))
    if jobs:
        job_config(jobs[0])  # an unknown preset or a bad --set stops here, before any work
    if ray_address is None:
        check_local_request(cpus_per_clip, memory_gb, num_cpus)
    with run_lock(out, create=True):
        failed = run_batch_folder(jobs, out, ray_address, num_cpus, memory_gb, retries,
                                  retry_failed)
    if failed:
        raise typer.Exit(1)


def run_batch_folder(jobs: list[ClipJob], out: Path, ray_address: str | None,
                     num_cpus: int | None, memory_gb: float, retries: int,
                     retry_failed: bool) -> int:
    """Run the batch in OUT (held by this process) with a progress bar per clip, write its
    summary and print its final line; returns how many clips are recorded failed. A stop
    (Ctrl-C or SIGTERM) is a SurgsplatError saying how many clips finished."""
    console = Console(soft_wrap=True)  # one line per message, whatever the terminal's width
    check_clip_folders(jobs)
    if retry_failed:
        forget_failed(jobs)
    skipped = sum(read_status(job.folder) is not None for job in jobs)
    if skipped:
        console.print(f"{skipped} of {len(jobs)} clips already finished; skipped")
    try:
        with progress_bar(TextColumn("{task.fields[stage]}")) as bar:
            tasks = {}

            def show(job: ClipJob, stage: str, iterations: int) -> None:
                if job.name not in tasks:
                    tasks[job.name] = bar.add_task(job.name, stage="queued",
                                                   total=planned_iterations(job))
                bar.update(tasks[job.name], completed=iterations, stage=stage)

            recorded = run_batch(jobs, ray_address, num_cpus, memory_gb, retries, show)
    except KeyboardInterrupt:
        raise SurgsplatError(f"interrupted (Ctrl-C or SIGTERM) with {finished_line(jobs)}; "
                             "run the same command again to go on: finished clips are skipped, "
                             "the others resume") from None
    for status in recorded:
        if status["state"] == FAILED:
            console.print(f"{status['clip']}: failed in {status['stage']}: {status['error']}",
                          markup=False, highlight=False)
    write_summary(jobs, out)
    console.print(f"{finished_line(jobs)}; summary: {out / SUMMARY_FILE}")
    return [(read_status(job.folder) or {}).get("state") for job in jobs].count(FAILED)
