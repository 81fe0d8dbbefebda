"""A method is one typed configuration: named components plus the settings every method has.
A method's package names its preset (`Preset`), which only sets values; `overrides.py` applies a
user's changes.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from surgsplat.model.component import ComponentConfig, SceneInfo
from surgsplat.model.gaussians import GaussianConfig
from surgsplat.model.init_points import InitConfig
from surgsplat.methods.settings import DensifyConfig, LossWeight, TrainConfig

KIND_KEY = "kind"
"""Key naming a component's registered kind in a saved config."""


@dataclass
class MethodConfig:
    """Everything a training run needs besides the data."""

    name: str
    """Preset this configuration started from."""
    components: dict[str, ComponentConfig] = field(default_factory=dict)
    """The method's components by name, in any order: the model applies them in the order of
    their phases (`model.phases`: anchor, deformation, tool, exposure, illumination, opacity,
    surface, shading, loss). They are built in this order (which draws its random initial
    weights first), and those of a phase several may share keep it among themselves."""
    losses: dict[str, LossWeight] = field(default_factory=dict)
    """Weight of every loss term the components declare, by term name."""
    gaussians: GaussianConfig = field(default_factory=GaussianConfig)
    """Canonical Gaussians."""
    init: InitConfig = field(default_factory=InitConfig)
    """Initial point cloud."""
    train: TrainConfig = field(default_factory=TrainConfig)
    """Optimisation."""
    densify: DensifyConfig = field(default_factory=DensifyConfig)
    """Densification and pruning."""

    def resolved(self, scene: SceneInfo) -> "MethodConfig":
        """A copy adapted to `scene`: every component's `resolve`, and the initial point count
        capped at half the Gaussian budget (leaving room for densification). The input is left
        unchanged; resolving a resolved config changes nothing."""
        config = copy.deepcopy(self)
        config.components = {name: component.resolve(scene)
                              for name, component in config.components.items()}
        budget = config.gaussians.cap(scene.width, scene.height)
        config.init.max_points = min(config.init.max_points, budget // 2)
        return config


def to_dict(config: Any) -> Any:
    """A JSON-ready form of a (nested) config: dataclasses as dicts, components with their kind."""
    if dataclasses.is_dataclass(config):
        values = {f.name: to_dict(getattr(config, f.name)) for f in dataclasses.fields(config)}
        if isinstance(config, ComponentConfig):
            values = {KIND_KEY: config.kind, **values}
        return values
    if isinstance(config, dict):
        return {key: to_dict(value) for key, value in config.items()}
    if isinstance(config, (tuple, list)):
        return [to_dict(value) for value in config]
    return config


@dataclass(frozen=True)
class Preset:
    """A named method, as a method's package declares it (its `PRESET`): a one-line
    description, and the function that builds the whole config (no preset edits another)."""

    description: str
    build: Callable[[], MethodConfig]
