"""The `physiosplat` preset, and the tool field and its mask weight that `drawer` keeps."""

from __future__ import annotations

from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.endogaussian.preset import hexplane_regularisers
from surgsplat.methods.physiosplat.biomechanics import BiomechanicsConfig
from surgsplat.methods.physiosplat.specular import SpecularConfig
from surgsplat.methods.physiosplat.tool_field import ToolFieldConfig
from surgsplat.methods.settings import LossWeight
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.gaussians import GaussianConfig
from surgsplat.model.init_points import InitConfig

TOOL_MASK_WEIGHT = 0.1
"""lambda_mask: weight of the tool field's mask loss."""


def articulated_tool_field() -> ToolFieldConfig:
    """The tool field of `physiosplat` and `drawer`: its jaws on a hinge and the tissue no frame
    shows filled, where the paper's tool is rigid (the A/B: docs/methods/physiosplat.md)."""
    return ToolFieldConfig(motion="articulated", fill_never_seen=True)


def physiosplat() -> MethodConfig:
    """HexPlane tissue with a volume-preservation loss, the articulated tool field with its mask
    loss, ARAP
    strain and tool-collision losses, a co-located specular lobe on SH0 colour, MAPF point
    fusion."""
    return MethodConfig(
        name="physiosplat",
        components={"deformation": HexPlaneConfig(volume_samples=512),
                    "color_curves": ColorCurvesConfig(), "tool": articulated_tool_field(),
                    "exposure": ExposureConfig(), "specular": SpecularConfig(),
                    "biomechanics": BiomechanicsConfig(), "photometric": PhotometricConfig(),
                    "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **hexplane_regularisers(), "mask": LossWeight(TOOL_MASK_WEIGHT),
                "strain": LossWeight(1.3e-4), "collision": LossWeight(1.3e-3),
                "volume": LossWeight(1.1e-8)},
        gaussians=GaussianConfig(sh_degree=0),
        init=InitConfig(fusion="mapf"))


PRESET = Preset("PhysioSplat: tool Gaussians (a shaft and two hinged jaws, posed per frame) "
                "with semantic logits beside HexPlane tissue, tool-free rendering with never-seen "
                "tissue filled, ARAP strain, tool collision and volume losses, co-located "
                "specular lobe", physiosplat)
