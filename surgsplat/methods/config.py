"""A method is one typed configuration; presets (see registry.py) only change its values."""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Any

from surgsplat.errors import SurgsplatError
from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.gaussians import GaussianConfig
from surgsplat.model.init_points import InitConfig
from surgsplat.train.config import TrainConfig
from surgsplat.train.strategy import DensifyConfig


@dataclass
class MethodConfig:
    """Everything a training run needs besides the data."""

    name: str
    """Preset this configuration started from."""
    deformation: HexPlaneConfig | GaussianBasisConfig
    """Deformation field over time."""
    gaussians: GaussianConfig = field(default_factory=GaussianConfig)
    """Canonical Gaussians."""
    init: InitConfig = field(default_factory=InitConfig)
    """Initial point cloud."""
    train: TrainConfig = field(default_factory=TrainConfig)
    """Optimisation."""
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    """Densification and pruning."""
    exposure: ExposureConfig = field(default_factory=ExposureConfig)
    """Per-time exposure gain of the rendered image."""


def to_dict(config: Any) -> dict:
    """A JSON-ready dict of a (nested) config dataclass."""
    return dataclasses.asdict(config)


def update_from_dict(config: Any, values: dict, where: str = "config") -> Any:
    """A copy of dataclass `config` with `values` (a nested dict, e.g. a saved config.json)
    applied; unknown keys raise SurgsplatError naming them."""
    hints = typing.get_type_hints(type(config))
    changes = {}
    for key, value in values.items():
        if key not in hints:
            raise SurgsplatError(f"{where}: unknown setting {key!r}")
        current = getattr(config, key)
        if dataclasses.is_dataclass(current) and isinstance(value, dict):
            changes[key] = update_from_dict(current, value, f"{where}.{key}")
        elif isinstance(current, tuple) and isinstance(value, list):
            changes[key] = tuple(value)
        else:
            changes[key] = value
    return dataclasses.replace(config, **changes)
