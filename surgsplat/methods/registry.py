"""Named method presets: each returns a MethodConfig; none has logic of its own."""

from __future__ import annotations

from collections.abc import Callable

from surgsplat.errors import SurgsplatError
from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.methods.config import MethodConfig
from surgsplat.model.init_points import InitConfig
from surgsplat.train.config import TrainConfig


def deform3dgs() -> MethodConfig:
    """Deform3DGS baseline: per-Gaussian Gaussian-basis deformation, motion-aware point fusion."""
    return MethodConfig(name="deform3dgs", deformation=GaussianBasisConfig(),
                        init=InitConfig(fusion="mapf"))


def endogaussian() -> MethodConfig:
    """EndoGaussian baseline: HexPlane deformation field with plane TV regularisation."""
    return MethodConfig(name="endogaussian", deformation=HexPlaneConfig(),
                        init=InitConfig(fusion="mapf"),
                        train=TrainConfig(regularisation={"plane_tv": 1e-4,
                                                          "time_smoothness": 1e-3}))


PRESETS: dict[str, Callable[[], MethodConfig]] = {
    "deform3dgs": deform3dgs,
    "endogaussian": endogaussian,
}


def method_config(name: str) -> MethodConfig:
    """The preset called `name`; SurgsplatError listing the known ones otherwise."""
    if name not in PRESETS:
        raise SurgsplatError(f"unknown method {name!r}; known: {', '.join(sorted(PRESETS))}")
    return PRESETS[name]()
