"""The `surgsplat` preset."""

from __future__ import annotations

from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.endogaussian.preset import hexplane_regularisers
from surgsplat.methods.endoplanar.planar import PlanarConfig
from surgsplat.methods.endoplanar.preset import ENDOPLANAR_THICKNESS, endoplanar_disc_losses
from surgsplat.methods.lumistate.decomposition import LumiStateConfig
from surgsplat.methods.lumistate.preset import lumistate_stage2_losses
from surgsplat.methods.settings import LossWeight
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.gaussians import GaussianConfig
from surgsplat.model.init_points import InitConfig


def surgsplat() -> MethodConfig:
    """EndoGaussian's HexPlane deformation, EndoPlanar's flat discs with their flatten and
    depth-normal losses (this one to the end of the run) and LumiState's reflectance x
    illumination with its Stage 2 losses, each at its own paper's values, on the baselines'
    depth L1 and MAPF point fusion."""
    return MethodConfig(
        name="surgsplat",
        components={"deformation": HexPlaneConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(), "lumistate": LumiStateConfig(),
                    "planar": PlanarConfig(),
                    "photometric": PhotometricConfig(), "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **hexplane_regularisers(), **endoplanar_disc_losses(normal_stop=1.0),
                **lumistate_stage2_losses()},
        gaussians=GaussianConfig(init_thickness=ENDOPLANAR_THICKNESS),
        init=InitConfig(fusion="mapf"))


PRESET = Preset("surgsplat's own method: EndoGaussian's HexPlane deformation, EndoPlanar's "
                "discs and depth-normal loss, LumiState's reflectance x illumination", surgsplat)
