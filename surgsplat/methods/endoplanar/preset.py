"""The `endoplanar` preset, and its disc losses and thickness, which `surgsplat` keeps."""

from __future__ import annotations

from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.endoplanar.planar import PlanarConfig
from surgsplat.methods.settings import LossWeight
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.gaussians import GaussianConfig
from surgsplat.model.init_points import InitConfig

ENDOPLANAR_THICKNESS = 1e-6
"""Initial thickness of the discs, as a fraction of their radius. The paper starts s_3 at
exp(-1e9) = 0, which leaves its flatten loss without a gradient; 1e-6 keeps one (and float32
logs finite)."""

ENDOPLANAR_NORMAL_STOP = 2 / 3
"""Fraction of the run after which the depth-normal loss leaves the objective (the paper keeps
it to the end)."""


def endoplanar_disc_losses(normal_stop: float) -> dict[str, LossWeight]:
    """The flatten loss (lambda_scaling 100) and the depth-normal loss, from a sixth of the run
    until the fraction `normal_stop`."""
    return {"flatten": LossWeight(100.0),
            "normal": LossWeight(0.05, start=1 / 6, stop=normal_stop)}


def endoplanar() -> MethodConfig:
    """Gaussian-basis deformation, planar discs that start flat (ENDOPLANAR_THICKNESS) with the
    flatten loss and the depth-normal loss until ENDOPLANAR_NORMAL_STOP, the inverse-depth L1 at
    the baselines' strength, MOG2 point fusion."""
    return MethodConfig(
        name="endoplanar",
        components={"deformation": GaussianBasisConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "planar": PlanarConfig(), "photometric": PhotometricConfig(),
                    "depth": DepthLossConfig(form="inverse_l1")},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **endoplanar_disc_losses(normal_stop=ENDOPLANAR_NORMAL_STOP)},
        gaussians=GaussianConfig(init_thickness=ENDOPLANAR_THICKNESS),
        init=InitConfig(fusion="mogf"))


PRESET = Preset("EndoPlanar: flattened Gaussians with unbiased plane depth, inverse-depth loss, "
                "edge-aware depth-normal loss, MOG2 point fusion", endoplanar)
