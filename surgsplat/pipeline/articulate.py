"""A run's tool articulation: estimated and written to RUN/articulation.json, the file's one
writer (`surgsplat articulate`, after training as the product ARTICULATION of every method with
a tool field, and before a simulation export that needs it)."""

from __future__ import annotations

from pathlib import Path

from surgsplat.export.articulation import (ARTICULATION_FILE, articulate, read_articulation,
                                           write_articulation)
from surgsplat.model.capabilities import ToolMotion
from surgsplat.pipeline.products import RunProduct
from surgsplat.train.run import TrainedRun


def articulate_run(run: TrainedRun) -> dict:
    """Estimate `run`'s tool articulation and write it to RUN/articulation.json; returns it.
    SurgsplatError when the method has no tool field or the estimate cannot be made."""
    articulation = articulate(run)
    write_articulation(run.run_dir, articulation)
    return articulation


def saved_or_new_articulation(run: TrainedRun) -> dict:
    """RUN/articulation.json, estimated and written first when the run has none."""
    saved = read_articulation(run.run_dir)
    return saved if saved is not None else articulate_run(run)


def articulation_summary(articulation: dict, path: Path) -> str:
    """One line describing an articulation written to `path`."""
    estimated = sum(record["estimated"] for record in articulation["frames"])
    limits = ", ".join(f"[{low:.1f}, {high:.1f}]" for low, high in articulation["limits_deg"])
    return (f"articulation of {articulation['parts']} tool Gaussians (shaft, jaws), {estimated} "
            f"frames estimated, jaw ranges {limits} deg: {path}")


ARTICULATION = RunProduct(
    "articulation", applies=lambda model: model.find(ToolMotion) is not None,
    make=lambda run: articulation_summary(articulate_run(run), run.run_dir / ARTICULATION_FILE))
"""The tool's articulation, made after training for every model with a tool field."""
