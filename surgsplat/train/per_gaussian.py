"""Changing the number of Gaussians while keeping the optimiser consistent.

Every per-Gaussian parameter lives in `GaussianModel.params` and has its own optimiser group
named after it; these helpers replace such a parameter by a selected or extended version and
carry the Adam moments along (zeros for new rows). The per-Gaussian buffers
(`GaussianModel.buffer_dict`) are selected or extended the same way, without an optimiser.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn

from surgsplat.model.gaussians import GaussianModel

MOMENT_KEYS = ("exp_avg", "exp_avg_sq")


def _replace(model: GaussianModel, optimizer: torch.optim.Optimizer,
             edit: Callable[[str, Tensor, bool], Tensor]) -> None:
    """Apply `edit(name, tensor, is_moment)` to each per-Gaussian parameter and its moments,
    and to each per-Gaussian buffer."""
    for group in optimizer.param_groups:
        name = group["name"]
        if name not in model.params:
            continue
        old = group["params"][0]
        new = nn.Parameter(edit(name, old.detach(), False))
        state = optimizer.state.pop(old, None)
        if state:
            optimizer.state[new] = {key: edit(name, value, True) if key in MOMENT_KEYS else value
                                    for key, value in state.items()}
        group["params"][0] = new
        model.params[name] = new
    for name, tensor in list(model.buffer_dict.items()):
        model.buffer_dict[name] = edit(name, tensor, False)


def keep_gaussians(model: GaussianModel, optimizer: torch.optim.Optimizer, keep: Tensor) -> None:
    """Keep the Gaussians where keep [N] bool is True."""
    _replace(model, optimizer, lambda _, tensor, __: tensor[keep].contiguous())


def append_gaussians(model: GaussianModel, optimizer: torch.optim.Optimizer,
                     new_rows: dict[str, Tensor]) -> None:
    """Append Gaussians; new_rows holds an [M, ...] tensor for every per-Gaussian parameter
    and buffer."""
    missing = set(model.per_gaussian()) - set(new_rows)
    if missing:
        raise ValueError(f"new Gaussians lack values for {sorted(missing)}")

    def extend(name: str, tensor: Tensor, is_moment: bool) -> Tensor:
        rows = new_rows[name].to(tensor)
        return torch.cat([tensor, torch.zeros_like(rows) if is_moment else rows], dim=0)

    _replace(model, optimizer, extend)
