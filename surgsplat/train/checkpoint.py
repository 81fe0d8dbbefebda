"""Checkpoints: written atomically, read without executing code, and the model they hold.

A checkpoint is a torch.save'd dict of tensors, numbers, strings, lists and dicts only, so it is
read with `torch.load(weights_only=True)`, which refuses anything that would run code.
"""

from __future__ import annotations

from pathlib import Path
from typing import BinaryIO

import torch
from torch import Tensor

from surgsplat.atomic import write_atomic
from surgsplat.errors import DataError
from surgsplat.methods.config import MethodConfig
from surgsplat.model.component import Component
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GEOMETRY_KEYS, GaussianModel
from surgsplat.model.phases import order_by_phase


def previous_path(path: Path) -> Path:
    """Where the checkpoint before `path` is kept: checkpoints/latest.pt -> previous.pt."""
    return path.with_name("previous" + path.suffix)


class _WriteErrorKeeper:
    """A binary handle's write and flush, keeping the first OSError they raise (a full disk,
    say): torch.save turns that error into a RuntimeError about its zip container, which names
    neither the file nor the cause."""

    def __init__(self, handle: BinaryIO):
        self.handle = handle
        self.error: OSError | None = None

    def write(self, data: bytes) -> int:
        return self._keeping_error(self.handle.write, data)

    def flush(self) -> None:
        self._keeping_error(self.handle.flush)

    def _keeping_error(self, call, *args):
        try:
            return call(*args)
        except OSError as err:
            self.error = self.error or err
            raise


def torch_save(state: dict, handle: BinaryIO) -> None:
    """torch.save `state` to `handle`; an OSError of the handle's writes is raised as itself."""
    writer = _WriteErrorKeeper(handle)
    try:
        torch.save(state, writer)
    except RuntimeError:
        if writer.error is None:
            raise
        raise writer.error from None


def save_atomic(state: dict, path: Path) -> None:
    """Write `state` to `path` atomically: a crash, kill or full disk during the write leaves
    the previous checkpoint intact; the one it replaces is kept as previous_path(path). A
    failed write raises an OSError naming `path` (e.g. No space left on device)."""
    write_atomic(path, lambda handle: torch_save(state, handle), keep_previous=previous_path(path))


def load_latest_or_previous(path: Path) -> tuple[dict, Path, DataError | None]:
    """The checkpoint at `path`, or, when that one is damaged, the one kept before it: (state,
    the file it came from, the error that made `path` unusable or None). DataError about
    `path` when neither loads."""
    try:
        return load_checkpoint(path), path, None
    except DataError as err:
        previous = previous_path(path)
        if not previous.is_file():
            raise
        try:
            return load_checkpoint(previous), previous, err
        except DataError:
            raise err from None


def load_checkpoint(path: Path) -> dict:
    """Read a checkpoint written by save_atomic; DataError if it is missing or not one."""
    if not path.is_file():
        raise DataError(path, "checkpoint not found")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for corrupt or unsafe files
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise DataError(path, f"cannot be read as a surgsplat checkpoint: damaged or not one "
                              f"({first})") from err
    if not isinstance(state, dict) or "iteration" not in state:
        raise DataError(path, "is not a surgsplat checkpoint (no 'iteration' entry)")
    return state


def build_components(config: MethodConfig) -> dict[str, Component]:
    """A fresh component of each of the method's component configs, by name, built in the
    config's order and returned in the order of their phases (`model.phases`)."""
    return order_by_phase({name: component.build()
                           for name, component in config.components.items()})


def model_state(config: MethodConfig, model: SplatModel) -> dict:
    """The checkpoint entries that hold a model: its Gaussians (per-Gaussian parameters and
    buffers) and each component's state."""
    return {
        "method": config.name,
        "gaussians": {name: value.detach() for name, value in model.gaussians.params.items()},
        "gaussian_buffers": dict(model.gaussians.buffer_dict.items()),
        "sh_degree": model.gaussians.sh_degree,
        "components": {name: component.state_dict()
                       for name, component in model.components.items()},
    }


def model_from_state(config: MethodConfig, state: dict, path: Path) -> SplatModel:
    """Rebuild the model a checkpoint `state` (read from `path`) holds, for the method `config`;
    DataError naming the file when the checkpoint belongs to another method or layout."""
    saved = state.get("method")
    if saved != config.name:
        raise DataError(path, f"holds a {saved!r} run, not {config.name!r}")
    components = build_components(config)
    stored = state.get("components", {})
    if set(stored) != set(components):
        raise DataError(path, f"holds components {sorted(stored)}, but the method has "
                              f"{sorted(components)}")
    for name, component in components.items():
        try:
            component.load_state_dict(stored[name])
        except RuntimeError as err:
            raise DataError(path, f"component {name!r} does not match the run's config "
                                  f"({str(err).splitlines()[0]})") from err
    params, buffers = saved_per_gaussian(state, components)
    gaussians = GaussianModel(params, int(state["sh_degree"]), buffers)
    return SplatModel(gaussians, components)


def saved_per_gaussian(state: dict, components: dict[str, Component]
                       ) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """The per-Gaussian parameters and buffers a checkpoint `state` holds. A saved parameter
    that neither the Gaussians nor a component learns is a buffer: checkpoints written before
    per-Gaussian buffers kept non-learnable state (mesh_anchor's anchor faces) as parameters
    of learning rate 0."""
    learned = set(GEOMETRY_KEYS).union(*(component.attribute_lrs()
                                         for component in components.values()))
    params = {name: value for name, value in state["gaussians"].items() if name in learned}
    buffers = {name: value for name, value in state["gaussians"].items() if name not in learned}
    return params, {**buffers, **state.get("gaussian_buffers", {})}


def optimizer_state_in_order(saved: dict, names: list[str], path: Path) -> dict:
    """A saved optimiser state_dict with its groups in the order `names` (the optimiser's
    groups, by name), for `Optimizer.load_state_dict`, which matches groups by position: a run
    saved before components were ordered by phase may hold them in another order. Saved groups
    not in `names` (a per-Gaussian tensor that has become a buffer) are left out with their
    state; DataError naming `path` when one of `names` was not saved."""
    groups = {group["name"]: group for group in saved["param_groups"]}
    missing = [name for name in names if name not in groups]
    if missing:
        raise DataError(path, f"holds no optimiser state for {missing[0]!r}: it belongs to "
                              "another version of the method")
    ordered = [groups[name] for name in names]
    kept = {index for group in ordered for index in group["params"]}
    return {"state": {index: value for index, value in saved["state"].items()
                      if index in kept},
            "param_groups": ordered}
