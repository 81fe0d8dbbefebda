"""Checkpoints: written atomically, read without executing code, checked, and the model they
hold.

A checkpoint is a torch.save'd dict of tensors, numbers, strings, lists and dicts only, so it is
read with `torch.load(weights_only=True)`, which refuses anything that would run code. What it
holds is checked as it is read: every number finite (training never saves one that is not), and
every per-Gaussian tensor (parameters, buffers and their optimiser moments) of one length N.
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any, BinaryIO

import torch
from torch import Tensor

from surgsplat.atomic import write_atomic
from surgsplat.errors import DataError
from surgsplat.methods.config import MethodConfig
from surgsplat.model.component import Component
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GEOMETRY_KEYS, GaussianModel
from surgsplat.model.phases import order_by_phase
from surgsplat.train.per_gaussian import MOMENT_KEYS


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


def has_checkpoint(path: Path) -> bool:
    """Whether there is a checkpoint to continue from: the one at `path`, or the one kept
    before it (`load_latest_or_previous` reads either)."""
    return path.is_file() or previous_path(path).is_file()


def load_latest_or_previous(path: Path, entries: tuple[str, ...] = ()
                            ) -> tuple[dict, Path, DataError | None]:
    """The checkpoint at `path`, or, when that one is missing or damaged (`load_checkpoint`,
    with `entries`), the one kept before it: (state, the file it came from, the error that made
    `path` unusable or None). DataError about `path` when neither loads."""
    try:
        return load_checkpoint(path, entries), path, None
    except DataError as err:
        previous = previous_path(path)
        if not previous.is_file():
            raise
        try:
            return load_checkpoint(previous, entries), previous, err
        except DataError:
            raise err from None


def read_torch_file(path: Path, expected: str) -> Any:
    """What the PyTorch file at `path` holds, read without running code (tensors, numbers,
    strings, lists and dicts only); DataError naming `path` and `expected` (what it should be)
    when it cannot be read so. torch's warnings about the file's pickle protocol are not shown."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for corrupt, foreign or unsafe files
        raise DataError(path, f"cannot be read as {expected}: damaged, cut short, of another "
                              "format, or holding objects other than tensors and plain "
                              "values") from err


READ_ENTRIES = ("gaussians", "sh_degree", "iteration", "elapsed_seconds", "peak_rss_mb")
"""Entries of a training checkpoint that reading its run (eval, render, export...) uses."""
RESUME_ENTRIES = (*READ_ENTRIES, "optimizer", "strategy", "scene_extent", "frame_generator",
                  "frame_queue", "torch_rng")
"""Entries of a training checkpoint that resuming the training uses."""


def load_checkpoint(path: Path, entries: tuple[str, ...] = ()) -> dict:
    """Read a checkpoint written by save_atomic; DataError if it is missing, not one, lacks one
    of `entries`, or holds values no training run saves (`check_checkpoint_values`)."""
    if not path.is_file():
        raise DataError(path, "checkpoint not found")
    state = read_torch_file(path, "a surgsplat checkpoint")
    if not isinstance(state, dict) or "iteration" not in state:
        raise DataError(path, "is not a surgsplat checkpoint (no 'iteration' entry)")
    missing = [entry for entry in entries if entry not in state]
    if missing:
        raise DataError(path, f"is damaged: it has no {', '.join(repr(m) for m in missing)} "
                              f"entr{'ies' if len(missing) > 1 else 'y'}, which training saves")
    check_checkpoint_values(state, path)
    return state


def check_checkpoint_values(state: dict, path: Path) -> None:
    """DataError naming `path` and the entry when checkpoint `state` holds a number that is not
    finite, or per-Gaussian tensors of different lengths: a damaged file."""
    bad = first_non_finite(state)
    if bad is not None:
        raise DataError(path, f"is damaged: {bad} holds values that are not finite (NaN or "
                              "infinite), which training never saves")
    rows = per_gaussian_rows(state)
    if rows:
        (first, count), *others = rows.items()
        for other, other_count in others:
            if other_count != count:
                raise DataError(path, f"is damaged: its per-Gaussian tensors disagree in length "
                                      f"({first} has {count} rows, {other} {other_count})")


def first_non_finite(value: Any, key: str = "") -> str | None:
    """The dotted key of the first tensor or number in `value` (nested dicts, lists and
    tuples) that holds a NaN or an infinity, or None."""
    if isinstance(value, Tensor):
        finite = not value.is_floating_point() or bool(torch.isfinite(value).all())
        return None if finite else key
    if isinstance(value, float):
        return None if math.isfinite(value) else key
    if isinstance(value, dict):
        items = value.items()
    elif isinstance(value, (list, tuple)):
        items = enumerate(value)
    else:
        return None
    for name, entry in items:
        found = first_non_finite(entry, f"{key}.{name}" if key else str(name))
        if found is not None:
            return found
    return None


def per_gaussian_rows(state: dict) -> dict[str, int]:
    """Rows (first dimension; 0 for what is not a tensor of one dimension or more) of every
    per-Gaussian tensor of checkpoint `state`, by dotted key: its Gaussians' parameters and
    buffers, and the optimiser's moments of each parameter."""
    gaussians = dict_entry(state, "gaussians")
    tensors = {f"gaussians.{name}": value for name, value in gaussians.items()}
    tensors.update({f"gaussian_buffers.{name}": value
                    for name, value in dict_entry(state, "gaussian_buffers").items()})
    tensors.update(saved_moments(dict_entry(state, "optimizer"), set(gaussians)))
    return {key: value.shape[0] if isinstance(value, Tensor) and value.dim() else 0
            for key, value in tensors.items()}


def saved_moments(optimizer: dict, names: set[str]) -> dict[str, Any]:
    """The Adam moments (MOMENT_KEYS) that a saved optimiser state_dict holds for its groups
    called one of `names`, by dotted key (optimizer.NAME.MOMENT)."""
    moments = dict_entry(optimizer, "state")
    found = {}
    groups = optimizer.get("param_groups")
    for group in groups if isinstance(groups, list) else []:
        name = group.get("name") if isinstance(group, dict) else None
        params = group.get("params") if isinstance(name, str) and name in names else None
        for index in params if isinstance(params, list) else []:
            saved = moments.get(index, {}) if isinstance(index, int) else {}
            found.update({f"optimizer.{name}.{key}": saved[key]
                          for key in MOMENT_KEYS if isinstance(saved, dict) and key in saved})
    return found


def dict_entry(state: dict, key: str) -> dict:
    """state[key] when it is a dict, else an empty one."""
    value = state.get(key)
    return value if isinstance(value, dict) else {}


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
    missing = sorted(learned_per_gaussian(components) - set(params))
    if missing:
        raise DataError(path, f"holds no per-Gaussian {missing[0]!r}: it is damaged or belongs "
                              "to another version of the method")
    gaussians = GaussianModel(params, int(state["sh_degree"]), buffers)
    return SplatModel(gaussians, components)


def learned_per_gaussian(components: dict[str, Component]) -> set[str]:
    """Names of the per-Gaussian tensors that are learnt: the Gaussians' own and the
    components' attributes."""
    return set(GEOMETRY_KEYS).union(*(component.attribute_lrs()
                                      for component in components.values()))


def saved_per_gaussian(state: dict, components: dict[str, Component]
                       ) -> tuple[dict[str, Tensor], dict[str, Tensor]]:
    """The per-Gaussian parameters and buffers a checkpoint `state` holds. A saved parameter
    that neither the Gaussians nor a component learns is a buffer: checkpoints written before
    per-Gaussian buffers kept non-learnable state (mesh_anchor's anchor faces) as parameters
    of learning rate 0."""
    learned = learned_per_gaussian(components)
    saved = dict_entry(state, "gaussians")
    params = {name: value for name, value in saved.items() if name in learned}
    buffers = {name: value for name, value in saved.items() if name not in learned}
    return params, {**buffers, **dict_entry(state, "gaussian_buffers")}


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
