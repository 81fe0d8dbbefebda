"""`surgsplat batch CLIPS... --out DIR`: reconstruct many clips as Ray tasks.

Every clip (a video, a folder of frames or a scene folder) is imported, trained, evaluated and
rendered as four chained Ray tasks that declare their CPUs and memory, on a local Ray instance
or, with --ray-address, on an existing cluster (whose workers must have surgsplat installed and
see DIR and the clips at the same paths). A failing task is retried (--retries), then its clip
is recorded failed with its error while the others go on. The batch is resumable: clips that
finished (done or failed) are skipped, an interrupted clip re-imports only when its scene is
incomplete and resumes training from its checkpoint. DIR/summary.csv collects every clip's
state and metrics, DIR/report.html (with the `report` extra) their runs.

A failed clip is one line on the console (its stage and error, never a task's traceback), and
the batch then exits with status 1; a second batch into a DIR in use is refused.
"""

from __future__ import annotations

import csv
import io
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import TextColumn

from surgsplat.atomic import write_text_atomic
from surgsplat.cli.batch_stages import (DONE, FAILED, STAGES, ClipJob, StageFailure,
                                        attempt_stage, error_line, job_config, planned_iterations,
                                        read_status, record_outcome, summary_row,
                                        trained_iterations)
from surgsplat.cli.progress import progress_bar
from surgsplat.errors import SurgsplatError
from surgsplat.methods.registry import PRESETS
from surgsplat.train.run import run_lock

SUMMARY_FILE = "summary.csv"
REPORT_FILE = "report.html"
POLL_SECONDS = 1.0
GIB = 2**30


def clip_jobs(clips: list[Path], out: Path, method: str, iterations: int | None, threads: int,
              fps: float, geometry: bool = True, settings: tuple[str, ...] = ()) -> list[ClipJob]:
    """One job per clip, in OUT/<clip file or folder name without suffix>; SurgsplatError for
    a missing clip or two clips of one name."""
    jobs, names = [], {}
    for clip in clips:
        if not clip.exists():
            raise SurgsplatError(f"{clip}: no such clip (expected a video, a folder of frames or "
                                 "a scene folder)")
        name = clip.stem if clip.is_file() else clip.name
        if name in names:
            raise SurgsplatError(f"{clip}: same name {name!r} as {names[name]}; clips are kept in "
                                 f"{out}/<name>, so names must differ")
        names[name] = clip
        jobs.append(ClipJob(clip.resolve(), out.resolve() / name, method, iterations, threads,
                            fps, geometry, settings))
    return jobs


def ray_module():
    """The ray package, or a SurgsplatError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise SurgsplatError("surgsplat batch needs Ray: pip install 'surgsplat[batch]'") \
            from None
    return ray


def submit_clip(ray, job: ClipJob, memory_gb: float, retries: int) -> list:
    """The clip's chained tasks, one per stage, submitted; their ObjectRefs in stage order. A
    stage retries its errors itself (attempt_stage); Ray retries a task whose worker died."""
    options = {"num_cpus": job.threads, "memory": int(memory_gb * GIB),
               "max_retries": retries, "retry_exceptions": False}
    refs, previous = [], None
    for stage in STAGES:
        previous = ray.remote(attempt_stage).options(name=f"{stage} {job.name}", **options) \
            .remote(stage, job, previous, retries)
        refs.append(previous)
    return refs


def run_batch(jobs: list[ClipJob], ray_address: str | None, num_cpus: int | None,
              memory_gb: float, retries: int, console: Console) -> list[dict]:
    """Run every job without a status on Ray (starting a local instance unless one is running
    or `ray_address` names a cluster); returns the statuses recorded now."""
    pending = [job for job in jobs if read_status(job) is None]
    if not pending:
        return []
    ray = ray_module()
    started_here = not ray.is_initialized()
    if started_here:
        ray.init(address=ray_address, num_cpus=None if ray_address else num_cpus,
                 include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        return _follow(ray, pending, memory_gb, retries, console)
    finally:
        if started_here:
            ray.shutdown()


def _follow(ray, jobs: list[ClipJob], memory_gb: float, retries: int,
            console: Console) -> list[dict]:
    """Submit the jobs, show each clip's stage and training progress until all end, and
    record each clip's status as it ends."""
    started = time.perf_counter()
    refs = {job.name: submit_clip(ray, job, memory_gb, retries) for job in jobs}
    recorded = []
    with progress_bar(TextColumn("{task.fields[stage]}")) as bar:
        tasks = {job.name: bar.add_task(job.name, stage="queued", total=planned_iterations(job))
                 for job in jobs}
        waiting = list(jobs)
        while waiting:
            all_refs = [ref for job in waiting for ref in refs[job.name]]
            ready, _ = ray.wait(all_refs, num_returns=len(all_refs), timeout=POLL_SECONDS)
            ready = set(ready)
            for job in list(waiting):
                stage_refs = refs[job.name]
                task = tasks[job.name]
                if stage_refs[-1] in ready:  # the last stage ends after the others
                    outcome = _clip_outcome(ray, stage_refs, retries)
                    status = record_outcome(job, outcome, time.perf_counter() - started)
                    recorded.append(status)
                    bar.update(task, stage=status["state"] if status["state"] == DONE else
                               f"failed in {status['stage']}: {status['error']}")
                    waiting.remove(job)
                    continue
                done = sum(ref in ready for ref in stage_refs)
                bar.update(task, completed=trained_iterations(job.run_dir), stage=STAGES[done])
    for status in recorded:
        if status["state"] == FAILED:
            console.print(f"{status['clip']}: failed in {status['stage']}: {status['error']}",
                          markup=False, highlight=False)
    return recorded


def _clip_outcome(ray, stage_refs: list, retries: int) -> Path | StageFailure:
    """What a clip's finished tasks came to: the first StageFailure, else the last stage's
    result. Every task's result is fetched, so that Ray reports none as an unhandled error."""
    outcomes = []
    for stage, ref in zip(STAGES, stage_refs):
        try:
            outcomes.append(ray.get(ref))
        except ray.exceptions.RayError as err:  # the task's worker died, on every retry
            outcomes.append(StageFailure(stage, retries + 1,
                                         error_line(getattr(err, "cause", None) or err)))
    return next((o for o in outcomes if isinstance(o, StageFailure)), outcomes[-1])


def write_summary(jobs: list[ClipJob], out: Path) -> list[dict]:
    """DIR/summary.csv: one row per clip (name, state, timing, error, metrics); and
    DIR/report.html of the finished runs when the report extra is installed."""
    rows = [summary_row(job) for job in jobs]
    columns = list(dict.fromkeys(key for row in rows for key in row))
    out.mkdir(parents=True, exist_ok=True)
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(out / SUMMARY_FILE, text.getvalue())
    finished = [job.run_dir for job, row in zip(jobs, rows) if row["state"] == DONE]
    if finished:
        try:
            from surgsplat.export.report import write_report
        except ImportError:  # the report extra (matplotlib) is not installed
            return rows
        write_report(finished, out / REPORT_FILE)
    return rows


def batch_command(
    clips: Annotated[list[Path], typer.Argument(help="Videos, folders of frames or scene "
                                                     "folders, one clip each.")],
    out: Annotated[Path, typer.Option(help="Batch folder: one sub-folder per clip, "
                                           "summary.csv, report.html.")],
    method: Annotated[str, typer.Option(help=f"Method preset: {', '.join(PRESETS)}.")] =
        "deform3dgs",
    iters: Annotated[int | None, typer.Option(help="Training iterations per clip (preset "
                                                    "default if omitted).")] = None,
    ray_address: Annotated[str | None, typer.Option(
        help="Address of an existing Ray cluster, e.g. ray://head:10001 or auto (default: a "
             "local Ray instance on this machine).")] = None,
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
    with run_lock(out, create=True):
        failed = run_batch_folder(jobs, out, ray_address, num_cpus, memory_gb, retries,
                                  retry_failed)
    if failed:
        raise typer.Exit(1)


def run_batch_folder(jobs: list[ClipJob], out: Path, ray_address: str | None,
                     num_cpus: int | None, memory_gb: float, retries: int,
                     retry_failed: bool) -> int:
    """Run the batch in OUT (held by this process), write its summary and print its final
    line; returns how many clips are recorded failed."""
    console = Console(soft_wrap=True)  # one line per message, whatever the terminal's width
    if retry_failed:
        for job in jobs:
            if (read_status(job) or {}).get("state") == FAILED:
                job.status_path.unlink()
    skipped = sum(read_status(job) is not None for job in jobs)
    if skipped:
        console.print(f"{skipped} of {len(jobs)} clips already finished; skipped")
    recorded = run_batch(jobs, ray_address, num_cpus, memory_gb, retries, console)
    if recorded or not (out / SUMMARY_FILE).is_file():
        write_summary(jobs, out)
    states = [(read_status(job) or {}).get("state") for job in jobs]
    console.print(f"{states.count(DONE)} of {len(jobs)} clips done, {states.count(FAILED)} "
                  f"failed; summary: {out / SUMMARY_FILE}")
    return states.count(FAILED)
