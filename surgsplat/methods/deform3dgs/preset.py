"""The `deform3dgs` preset."""

from __future__ import annotations

from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.settings import LossWeight, TrainConfig
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.init_points import InitConfig

DEPTH_WEIGHT = 4.5
"""Weight of the baselines' depth L1, which is relative (divided by the median measured depth):
the 0.05 per millimetre of Deform3DGS and EndoGaussian at the phantom's median depth of 90 mm.
Every preset keeps it."""

COARSE_START_FRACTION = 0.1
"""Fraction of the run trained on frames at half their size, before densification starts
(train.coarse_fraction with train.coarse_factor 2)."""


def deform3dgs() -> MethodConfig:
    """Gaussian-basis deformation, L1 + D-SSIM and depth L1, MAPF point fusion, the first
    COARSE_START_FRACTION of the run on half-size frames."""
    return MethodConfig(
        name="deform3dgs",
        components={"deformation": GaussianBasisConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "photometric": PhotometricConfig(), "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT)},
        train=TrainConfig(coarse_fraction=COARSE_START_FRACTION, coarse_factor=2),
        init=InitConfig(fusion="mapf"))


PRESET = Preset("Deform3DGS baseline: per-Gaussian Gaussian-basis deformation, motion-aware "
                "point fusion, L1 + D-SSIM and depth L1", deform3dgs)
