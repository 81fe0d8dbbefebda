"""The `lumistate` preset, and its Stage 2 losses, which `surgsplat` keeps."""

from __future__ import annotations

from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.lumistate.decomposition import LumiStateConfig
from surgsplat.methods.settings import LossWeight
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.init_points import InitConfig

LUMISTATE_STAGE2 = 1 / 3
"""Fraction of the run after which Stage 2 (Retinex, bright-channel and illumination-transfer
losses) starts, once geometry and reflectance have settled under the photometric loss."""

LUMISTATE_TIE_STOP = 2 / 3
"""Fraction of the run after which the illumination-transfer tie leaves the objective."""


def lumistate_stage2_losses() -> dict[str, LossWeight]:
    """Stage 2 from LUMISTATE_STAGE2: the Retinex and bright-channel losses, and the
    illumination-transfer tie until LUMISTATE_TIE_STOP."""
    return {"retinex": LossWeight(0.05, start=LUMISTATE_STAGE2),
            "bright_channel": LossWeight(0.25, start=LUMISTATE_STAGE2),
            "illumination_transfer": LossWeight(0.1, start=LUMISTATE_STAGE2,
                                                stop=LUMISTATE_TIE_STOP)}


def lumistate() -> MethodConfig:
    """Reflectance x illumination with its Stage 2 losses, on Deform3DGS's Gaussian-basis
    deformation and exposure curve, so that the decomposition is the only difference from the
    deform3dgs baseline."""
    return MethodConfig(
        name="lumistate",
        components={"deformation": GaussianBasisConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "lumistate": LumiStateConfig(), "photometric": PhotometricConfig(),
                    "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **lumistate_stage2_losses()},
        init=InitConfig(fusion="mapf"))


PRESET = Preset("LumiState: reflectance x illumination (UNet on max(R,G,B), per-Gaussian SH "
                "modulation from its embedding, Retinex and bright-channel losses in Stage 2), "
                "Gaussian-basis deformation", lumistate)
