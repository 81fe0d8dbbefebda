"""Checkpoints: written atomically, read without executing code.

A checkpoint is a torch.save'd dict of tensors, numbers, strings, lists and dicts only, so it is
read with `torch.load(weights_only=True)`, which refuses anything that would run code.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from surgsplat.errors import DataError


def save_atomic(state: dict, path: Path) -> None:
    """Write `state` to `path` via a temporary file and an atomic rename: a crash or Ctrl-C
    during the write leaves the previous checkpoint intact."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as handle:
        torch.save(state, handle)
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def load_checkpoint(path: Path) -> dict:
    """Read a checkpoint written by save_atomic; DataError if it is missing or not one."""
    if not path.is_file():
        raise DataError(path, "checkpoint not found")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises several types for corrupt or unsafe files
        raise DataError(path, f"cannot be read as a surgsplat checkpoint ({err})") from err
    if not isinstance(state, dict) or "iteration" not in state:
        raise DataError(path, "is not a surgsplat checkpoint (no 'iteration' entry)")
    return state
