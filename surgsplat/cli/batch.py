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

import csv
import io
import time
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.progress import TextColumn

from surgsplat.atomic import write_text_atomic
from surgsplat.cli.progress import progress_bar
from surgsplat.errors import SurgsplatError
from surgsplat.methods.registry import DEFAULT_PRESET, PRESETS
from surgsplat.pipeline.batch_cluster import (GIB, check_local_request, check_nodes_hold,
                                              connect, ray_module, ray_nodes)
from surgsplat.pipeline.batch_stages import (DONE, FAILED, RUN_DIR, STAGES, ClipJob,
                                             StageFailure, attempt_stage, error_line, job_config,
                                             planned_iterations, read_status, record_outcome,
                                             summary_row, trained_iterations)
from surgsplat.train.run import run_lock

SUMMARY_FILE = "summary.csv"
REPORT_FILE = "report.html"
POLL_SECONDS = 1.0


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


def check_clip_folders(jobs: list[ClipJob]) -> None:
    """SurgsplatError for a clip whose folder holds another clip that an earlier batch into
    the same DIR finished (same name, other source): its results would be taken for this
    clip's."""
    for job in jobs:
        recorded = (read_status(job.folder) or {}).get("clip")
        if recorded is not None and Path(recorded) != job.source:
            raise SurgsplatError(f"{job.source}: {job.folder} holds the results of another "
                                 f"clip of the same name, {recorded}; rename the clip or "
                                 "choose another --out")


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
    """Run every job without a status on Ray (starting a local instance unless this process
    is connected to one or `ray_address` names a cluster), once its nodes are known to hold
    the clips' tasks; returns the statuses recorded now."""
    pending = [job for job in jobs if read_status(job.folder) is None]
    if not pending:
        return []
    ray = ray_module()
    started_here = not ray.is_initialized()
    where = connect(ray, ray_address, num_cpus) if started_here else "the running Ray instance"
    try:
        check_nodes_hold(ray_nodes(ray), pending[0].threads, memory_gb, where)
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


def summary_clips(jobs: list[ClipJob], out: Path) -> list[tuple[Path, Path]]:
    """(folder, source) of every clip the summary of DIR covers: the jobs' clips in order, then
    the clips that earlier batches into DIR finished, by name."""
    clips = [(job.folder, job.source) for job in jobs]
    own = {job.folder for job in jobs}
    for folder in sorted(out.resolve().iterdir()) if out.is_dir() else ():
        status = read_status(folder) if folder.is_dir() and folder not in own else None
        if status is not None:
            clips.append((folder, Path(status["clip"])))
    return clips


def summary_text(rows: list[dict]) -> str:
    """The CSV table of the summary's rows, a column per key that any row has."""
    columns = list(dict.fromkeys(key for row in rows for key in row))
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=columns, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return text.getvalue()


def write_summary(jobs: list[ClipJob], out: Path) -> list[dict]:
    """DIR/summary.csv: one row per clip of the jobs and per clip finished in DIR before (name,
    state, timing, error, metrics); and DIR/report.html of the finished runs when the report
    extra is installed. Both are left as they are when the summary would not change."""
    clips = summary_clips(jobs, out)
    rows = [summary_row(folder, source) for folder, source in clips]
    text = summary_text(rows)
    summary = out / SUMMARY_FILE
    if summary.is_file() and summary.read_text() == text:
        return rows
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(summary, text)
    finished = [folder / RUN_DIR for (folder, _), row in zip(clips, rows) if row["state"] == DONE]
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
    """Run the batch in OUT (held by this process), write its summary and print its final
    line; returns how many clips are recorded failed. A stop (Ctrl-C or SIGTERM) is a
    SurgsplatError saying how many clips finished."""
    console = Console(soft_wrap=True)  # one line per message, whatever the terminal's width
    check_clip_folders(jobs)
    if retry_failed:
        for job in jobs:
            if (read_status(job.folder) or {}).get("state") == FAILED:
                job.status_path.unlink()
    skipped = sum(read_status(job.folder) is not None for job in jobs)
    if skipped:
        console.print(f"{skipped} of {len(jobs)} clips already finished; skipped")
    try:
        run_batch(jobs, ray_address, num_cpus, memory_gb, retries, console)
    except KeyboardInterrupt:
        raise SurgsplatError(f"interrupted (Ctrl-C or SIGTERM) with {finished_line(jobs)}; "
                             "run the same command again to go on: finished clips are skipped, "
                             "the others resume") from None
    write_summary(jobs, out)
    console.print(f"{finished_line(jobs)}; summary: {out / SUMMARY_FILE}")
    return [(read_status(job.folder) or {}).get("state") for job in jobs].count(FAILED)


def finished_line(jobs: list[ClipJob]) -> str:
    """How many of the jobs' clips are recorded done and failed, e.g. "2 of 3 clips done, 1
    failed"."""
    states = [(read_status(job.folder) or {}).get("state") for job in jobs]
    return f"{states.count(DONE)} of {len(jobs)} clips done, {states.count(FAILED)} failed"
