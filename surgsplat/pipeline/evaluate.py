"""Evaluate a run on its test frames (or its training frames) into RUN/metrics.json (see
eval/run_metrics.py)."""

from __future__ import annotations

import json
from collections.abc import Callable

from surgsplat.atomic import write_text_atomic
from surgsplat.errors import DataError
from surgsplat.eval.run_metrics import METRICS_FILE, EvalOptions, evaluate_run
from surgsplat.train.run import TrainedRun
from surgsplat.train.trainer import scene_identity


def evaluate(run: TrainedRun, options: EvalOptions | None = None,
             progress: Callable[[int, int], None] | None = None) -> dict:
    """The run's metrics with its method and scene, written to RUN/metrics.json;
    `progress(done, total)` after each frame scored."""
    options = options or EvalOptions()
    if not options.frames_of(run):
        raise DataError(run.scene.root, "has no test frame (frames 1, 9, 17, ...): held-out "
                                        "evaluation needs a scene of at least 2 frames; "
                                        "`--frames train` scores the fit to the training frames")
    metrics = evaluate_run(run, options, progress)
    metrics["method"] = run.config.name
    metrics["scene"] = scene_identity(run.scene)
    write_text_atomic(run.run_dir / METRICS_FILE, json.dumps(metrics, indent=2) + "\n")
    return metrics
