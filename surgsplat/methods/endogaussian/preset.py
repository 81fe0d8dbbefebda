"""The `endogaussian` preset, and the HexPlane regularisers' weights that the presets built
on a HexPlane field share."""

from __future__ import annotations

from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.settings import LossWeight
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.init_points import InitConfig


def hexplane_regularisers() -> dict[str, LossWeight]:
    """EndoGaussian's weights of the HexPlane field's plane TV and time smoothness."""
    return {"plane_tv": LossWeight(1e-4), "time_smoothness": LossWeight(1e-3)}


def endogaussian() -> MethodConfig:
    """HexPlane deformation with its plane TV and time smoothness, L1 + D-SSIM and depth L1,
    MAPF point fusion."""
    return MethodConfig(
        name="endogaussian",
        components={"deformation": HexPlaneConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "photometric": PhotometricConfig(), "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **hexplane_regularisers()},
        init=InitConfig(fusion="mapf"))


PRESET = Preset("EndoGaussian baseline: HexPlane deformation field with plane TV and time "
                "smoothness", endogaussian)
