"""The `endogsg` preset, and the SDF terms' weights and occlusion gamma that `drawer` keeps."""

from __future__ import annotations

from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.endogaussian.preset import hexplane_regularisers
from surgsplat.methods.endogsg.sdf import SDFConfig
from surgsplat.methods.settings import LossWeight
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.init_points import InitConfig

ENDO_GSG_GAMMA = 100.0
"""gamma of the occlusion importance map, which the paper does not give: Eq. 11 divides by the
Frobenius norm of the summed masks, so gamma must be of the order of sqrt(tool pixels) for the
map to matter."""

ENDO_GSG_PROJECTION_START = 1 / 3
"""Fraction of the run after which the projection term starts pulling the Gaussians onto the
SDF's zero level; until then the field learns its surface from the opacity bell, the SDA and
Eikonal terms."""


def endo_gsg_sdf_losses() -> dict[str, LossWeight]:
    """The weights of the SDF's terms: Eikonal, projection (from ENDO_GSG_PROJECTION_START),
    orientation (off) and SDA."""
    return {"eikonal": LossWeight(0.1),
            "projection": LossWeight(100.0, start=ENDO_GSG_PROJECTION_START),
            "orientation": LossWeight(0.0), "sda": LossWeight(0.1)}


def endogsg() -> MethodConfig:
    """HexPlane deformation, a canonical neural SDF with its terms, photometric and depth losses
    weighted by the occlusion importance map (ENDO_GSG_GAMMA), MAPF point fusion."""
    return MethodConfig(
        name="endogsg",
        components={"deformation": HexPlaneConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "sdf": SDFConfig(),
                    "photometric": PhotometricConfig(occlusion_gamma=ENDO_GSG_GAMMA),
                    "depth": DepthLossConfig(occlusion_gamma=ENDO_GSG_GAMMA)},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **endo_gsg_sdf_losses(), **hexplane_regularisers()},
        init=InitConfig(fusion="mapf"))


PRESET = Preset("Endo-GSG: HexPlane deformation, canonical neural SDF giving each Gaussian its "
                "opacity, SDA / projection / orientation / Eikonal losses, occlusion importance "
                "map", endogsg)
