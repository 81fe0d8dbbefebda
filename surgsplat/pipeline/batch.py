"""Many clips reconstructed as Ray tasks: each clip's import, training, evaluation and
rendering are chained tasks (`batch_stages`) on a local Ray instance or a cluster
(`batch_cluster`); `run_batch` submits the clips that have no status yet and follows them to
their end, recording each clip's status as it ends, and `write_summary` collects every clip of
the batch folder into summary.csv and report.html. `surgsplat batch` shows their progress."""

from __future__ import annotations

import csv
import io
import time
from collections.abc import Callable
from pathlib import Path

from surgsplat.atomic import write_text_atomic
from surgsplat.errors import SurgsplatError
from surgsplat.pipeline.batch_cluster import GIB, check_nodes_hold, connect, ray_module, ray_nodes
from surgsplat.pipeline.batch_stages import (DONE, FAILED, RUN_DIR, STAGES, ClipJob,
                                             StageFailure, attempt_stage, error_line,
                                             read_status, record_outcome, summary_row,
                                             trained_iterations)

SUMMARY_FILE = "summary.csv"
REPORT_FILE = "report.html"
POLL_SECONDS = 1.0

ClipUpdate = Callable[[ClipJob, str, int], None]
"""Called for each running clip at every poll with its stage (or, once it ended, "done" or
"failed in STAGE: ERROR") and its trained iterations."""


def ignore_update(job: ClipJob, stage: str, iterations: int) -> None:
    """A `ClipUpdate` that shows nothing."""


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


def forget_failed(jobs: list[ClipJob]) -> None:
    """Remove the status of every job's clip recorded failed, so that the batch runs it again."""
    for job in jobs:
        if (read_status(job.folder) or {}).get("state") == FAILED:
            job.status_path.unlink()


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
              memory_gb: float, retries: int, on_update: ClipUpdate = ignore_update
              ) -> list[dict]:
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
        return _follow(ray, pending, memory_gb, retries, on_update)
    finally:
        if started_here:
            ray.shutdown()


def _follow(ray, jobs: list[ClipJob], memory_gb: float, retries: int,
            on_update: ClipUpdate) -> list[dict]:
    """Submit the jobs and poll them until all end, telling `on_update` each clip's stage and
    training progress, and recording each clip's status as it ends."""
    started = time.perf_counter()
    refs = {job.name: submit_clip(ray, job, memory_gb, retries) for job in jobs}
    recorded = []
    waiting = list(jobs)
    while waiting:
        all_refs = [ref for job in waiting for ref in refs[job.name]]
        ready, _ = ray.wait(all_refs, num_returns=len(all_refs), timeout=POLL_SECONDS)
        ready = set(ready)
        for job in list(waiting):
            stage_refs = refs[job.name]
            iterations = trained_iterations(job.run_dir)
            if stage_refs[-1] in ready:  # the last stage ends after the others
                outcome = _clip_outcome(ray, stage_refs, retries)
                status = record_outcome(job, outcome, time.perf_counter() - started)
                recorded.append(status)
                on_update(job, status["state"] if status["state"] == DONE else
                          f"failed in {status['stage']}: {status['error']}", iterations)
                waiting.remove(job)
                continue
            on_update(job, STAGES[sum(ref in ready for ref in stage_refs)], iterations)
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


def finished_line(jobs: list[ClipJob]) -> str:
    """How many of the jobs' clips are recorded done and failed, e.g. "2 of 3 clips done, 1
    failed"."""
    states = [(read_status(job.folder) or {}).get("state") for job in jobs]
    return f"{states.count(DONE)} of {len(jobs)} clips done, {states.count(FAILED)} failed"
