"""The stages of reconstructing one clip in a batch: import, train, evaluate, render.

Each stage is a plain function of the clip's folders that can run again after a stop: import
is skipped when the scene is complete, training resumes from the run's checkpoint, evaluation
and rendering rewrite their files. Train, evaluate and render call `surgsplat.pipeline`
without progress bars (the batch shows each clip's progress itself). `surgsplat.pipeline.batch`
runs them as Ray tasks; they run as well one after another in one process.

A batch folder holds one folder per clip, OUT/<clip name>/, with scene/ (the imported scene,
unless the clip already is a scene folder), run/ (the run folder, with metrics.json and
videos/) and status.json (state "done" or "failed", the failing stage and its error).

`attempt_stage` runs one stage with its retries and returns a failure as a value (StageFailure)
instead of raising it, so that Ray never prints a task's traceback: the batch reports one line
per failed clip.
"""

from __future__ import annotations

import json
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

from surgsplat.atomic import write_text_atomic
from surgsplat.data.importer import ImportConfig, import_scene
from surgsplat.data.layout import POSES_FILE
from surgsplat.data.scene import load_scene
from surgsplat.errors import os_error_line
from surgsplat.eval.run_metrics import METRICS_FILE, EvalOptions
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.overrides import build_method_config
from surgsplat.pipeline.evaluate import evaluate
from surgsplat.pipeline.render import write_run_videos
from surgsplat.pipeline.train import train_run
from surgsplat.render.native import set_threads
from surgsplat.train.checkpoint import has_checkpoint
from surgsplat.train.run import load_trained_run, run_lock
from surgsplat.train.trainer import CHECKPOINT, LOG_FILE, read_log

STATUS_FILE = "status.json"
RUN_DIR = "run"
DONE, FAILED = "done", "failed"


@dataclass(frozen=True)
class ClipJob:
    """One clip of a batch and what to do with it."""

    source: Path  # a video, a folder of frames, or a scene folder
    folder: Path  # OUT/<name>
    method: str  # method preset
    iterations: int | None  # None: the preset's
    threads: int  # torch and native-kernel threads of every stage
    fps: float  # of the rendered videos
    geometry: bool = True  # evaluate geometry against gt/ meshes when the scene has them
    settings: tuple[str, ...] = ()  # `--set KEY=VALUE` assignments for a new run

    @property
    def name(self) -> str:
        return self.folder.name

    @property
    def run_dir(self) -> Path:
        return self.folder / RUN_DIR

    @property
    def status_path(self) -> Path:
        return self.folder / STATUS_FILE


def job_config(job: ClipJob) -> MethodConfig:
    """The method configuration of a new run of the clip: its preset with its settings applied
    as `surgsplat train --set` applies them (SurgsplatError naming a bad one)."""
    return build_method_config(job.method, None, list(job.settings))


def planned_iterations(job: ClipJob) -> int:
    """The iterations the clip's run trains for."""
    return job.iterations if job.iterations is not None else job_config(job).train.iterations


def is_scene_folder(path: Path) -> bool:
    """Whether `path` is an EndoNeRF-layout scene folder (it holds poses_bounds.npy)."""
    return path.is_dir() and (path / POSES_FILE).is_file()


def import_stage(job: ClipJob) -> Path:
    """The clip's scene folder: the clip itself when it is one, else OUT/<name>/scene (imported
    now unless a complete one is there). Loading it checks every file."""
    set_threads(job.threads)
    if is_scene_folder(job.source):
        scene_dir = job.source
    else:
        scene_dir = job.folder / "scene"
        if not is_scene_folder(scene_dir):
            shutil.rmtree(scene_dir, ignore_errors=True)  # what a killed import left
            import_scene(job.source, scene_dir, ImportConfig())
    load_scene(scene_dir)
    return scene_dir


def train_stage(job: ClipJob, scene_dir: Path) -> Path:
    """Train the clip's run to its end, resuming from its checkpoint when it has one."""
    set_threads(job.threads)
    with run_lock(job.run_dir, create=True):
        resume = has_checkpoint(job.run_dir / CHECKPOINT)
        train_run(job_config(job), scene_dir, job.run_dir, resume, job.iterations)
    return job.run_dir


def eval_stage(job: ClipJob, run_dir: Path) -> Path:
    """Evaluate the run on its test frames (writes RUN/metrics.json)."""
    set_threads(job.threads)
    with run_lock(run_dir):
        evaluate(load_trained_run(run_dir), EvalOptions(geometry=job.geometry))
    return run_dir


def render_stage(job: ClipJob, run_dir: Path) -> Path:
    """Render the run's videos into RUN/videos."""
    set_threads(job.threads)
    with run_lock(run_dir):
        write_run_videos(load_trained_run(run_dir), run_dir / "videos", job.fps)
    return run_dir


STAGE_FUNCTIONS: dict[str, Callable[[ClipJob, Path | None], Path]] = {
    "import": lambda job, _: import_stage(job), "train": train_stage, "eval": eval_stage,
    "render": render_stage}
"""Each stage's function of the job and the previous stage's result, in order."""
STAGES = tuple(STAGE_FUNCTIONS)


@dataclass(frozen=True)
class StageFailure:
    """A stage that failed on every attempt."""

    stage: str  # one of STAGES
    attempts: int  # attempts made: 1 + retries
    error: str  # one line: the last attempt's error


def error_line(err: BaseException) -> str:
    """One line saying what went wrong: `<path>: <what>` for an OSError, else the first line of
    the message (the exception's type when it has none)."""
    if isinstance(err, OSError):
        return os_error_line(err)
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__


def attempt_stage(stage: str, job: ClipJob, previous: Path | StageFailure | None,
                  retries: int) -> Path | StageFailure:
    """Run `stage` of `job` on the previous stage's result, up to 1 + `retries` times: its
    result, or a StageFailure with the last attempt's error (returned, not raised). A
    StageFailure of an earlier stage is passed on unchanged: the clip's later stages skip."""
    if isinstance(previous, StageFailure):
        return previous
    for attempt in range(1, retries + 2):
        try:
            return STAGE_FUNCTIONS[stage](job, previous)
        except Exception as err:  # recorded per clip; the batch goes on
            failure = StageFailure(stage, attempt, error_line(err))
    return failure


def record_outcome(job: ClipJob, outcome: Path | StageFailure, seconds: float) -> dict:
    """Record the clip's status from what its last stage returned; returns the status."""
    if isinstance(outcome, StageFailure):
        return record_status(job, FAILED, seconds, outcome.attempts, outcome.stage,
                             outcome.error)
    return record_status(job, DONE, seconds, 1)


def run_clip_here(job: ClipJob, retries: int = 0) -> dict:
    """Every stage of `job` in this process, one after another; records and returns its
    status (a failure is recorded, not raised)."""
    started = time.perf_counter()
    outcome = None
    for stage in STAGES:
        outcome = attempt_stage(stage, job, outcome, retries)
    return record_outcome(job, outcome, time.perf_counter() - started)


@dataclass
class ClipStatus:
    """What status.json says about a clip."""

    clip: str  # the source path
    state: str  # DONE or FAILED
    seconds: float  # wall time of the invocation that finished it
    attempts: int  # attempts of the failing stage (1 + retries) or 1
    stage: str = ""  # the failing stage
    error: str = ""  # its error


def record_status(job: ClipJob, state: str, seconds: float, attempts: int, stage: str = "",
                  error: str = "") -> dict:
    """Write OUT/<name>/status.json and return its contents."""
    status = asdict(ClipStatus(str(job.source), state, round(seconds, 2), attempts, stage, error))
    job.folder.mkdir(parents=True, exist_ok=True)
    write_text_atomic(job.status_path, json.dumps(status, indent=2) + "\n")
    return status


def read_status(folder: Path) -> dict | None:
    """The status.json of the clip kept in `folder` (OUT/<name>), or None when it has none
    (never finished) or it is unreadable."""
    try:
        status = json.loads((folder / STATUS_FILE).read_text())
    except (OSError, ValueError):  # ValueError: not JSON, or not UTF-8 text
        return None
    return status if isinstance(status, dict) and status.get("state") in (DONE, FAILED) \
        and isinstance(status.get("clip"), str) else None


def trained_iterations(run_dir: Path) -> int:
    """The last logged iteration of a run (0 before its first log entry)."""
    entries = read_log(run_dir / LOG_FILE)
    return entries[-1]["iteration"] if entries else 0


def summary_row(folder: Path, source: Path) -> dict:
    """The status of the clip kept in `folder` (from `source`; state "pending" before it
    finishes) with its run's metrics (scalar values only) once done."""
    row = {"name": folder.name,
           **(read_status(folder) or {"clip": str(source), "state": "pending"})}
    try:
        metrics = json.loads((folder / RUN_DIR / METRICS_FILE).read_text())
    except (OSError, ValueError):  # ValueError: not JSON, or not UTF-8 text
        metrics = {}
    if row["state"] == DONE:
        row.update({key: value for key, value in metrics.items()
                    if isinstance(value, (int, float, str)) or value is None})
    return row
