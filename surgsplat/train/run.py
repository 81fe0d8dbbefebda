"""Reading a run folder back: its resolved config, its scene, and its trained model."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from surgsplat.data.scene import Scene, load_scene
from surgsplat.errors import DataError
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.overrides import method_from_values
from surgsplat.methods.registry import method_config
from surgsplat.model.dynamic import SplatModel
from surgsplat.train.checkpoint import load_checkpoint, model_from_state
from surgsplat.train.trainer import CHECKPOINT, CONFIG_FILE, SCENE_FILE


def read_run_config(run_dir: Path) -> MethodConfig:
    """The MethodConfig saved in RUN/config.json (its preset, with the saved values applied)."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.is_file():
        raise DataError(path, "missing: not a surgsplat run folder (train one with "
                              "`surgsplat train`)")
    try:
        saved = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DataError(path, f"is not valid JSON ({err})") from err
    if not isinstance(saved, dict) or "name" not in saved:
        raise DataError(path, "expected a saved method configuration with a 'name'")
    return method_from_values(saved, method_config(saved["name"]), where=str(path))


def read_run_scene(run_dir: Path, data_dir: Path | None = None) -> Scene:
    """The run's scene (the path in RUN/scene.txt, or `data_dir` when given)."""
    if data_dir is None:
        path = Path(run_dir) / SCENE_FILE
        if not path.is_file():
            raise DataError(path, "missing: the run does not say which scene it was trained on")
        data_dir = Path(path.read_text().strip())
    return load_scene(data_dir)


@dataclass
class TrainedRun:
    """A run's model as saved in its latest checkpoint."""

    run_dir: Path
    config: MethodConfig
    scene: Scene
    model: SplatModel
    iteration: int
    train_seconds: float
    peak_rss_mb: float  # of the training process


def load_trained_run(run_dir: Path, data_dir: Path | None = None) -> TrainedRun:
    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    scene = read_run_scene(run_dir, data_dir)
    path = run_dir / CHECKPOINT
    state = load_checkpoint(path)
    model = model_from_state(config, state, path)
    model.eval()
    return TrainedRun(run_dir=run_dir, config=config, scene=scene, model=model,
                      iteration=int(state["iteration"]),
                      train_seconds=float(state["elapsed_seconds"]),
                      peak_rss_mb=float(state["peak_rss_mb"]))
