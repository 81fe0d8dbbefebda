"""The `drawer` preset."""

from __future__ import annotations

from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.deform3dgs.preset import DEPTH_WEIGHT
from surgsplat.methods.drawer.mesh_anchor import MeshAnchorConfig
from surgsplat.methods.endogaussian.preset import hexplane_regularisers
from surgsplat.methods.endogsg.preset import ENDO_GSG_GAMMA, endo_gsg_sdf_losses
from surgsplat.methods.endogsg.sdf import SDFConfig
from surgsplat.methods.physiosplat.preset import TOOL_MASK_WEIGHT, articulated_tool_field
from surgsplat.methods.settings import LossWeight
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.init_points import InitConfig


def drawer() -> MethodConfig:
    """Endo-GSG's components and weights with the tissue Gaussians anchored on the SDF's mesh
    (the anchor first, so that the deformation moves the anchored Gaussians) and PhysioSplat's
    tool field with its mask loss."""
    return MethodConfig(
        name="drawer",
        components={"anchor": MeshAnchorConfig(), "deformation": HexPlaneConfig(),
                    "color_curves": ColorCurvesConfig(), "tool": articulated_tool_field(),
                    "exposure": ExposureConfig(),
                    "sdf": SDFConfig(),
                    "photometric": PhotometricConfig(occlusion_gamma=ENDO_GSG_GAMMA),
                    "depth": DepthLossConfig(occlusion_gamma=ENDO_GSG_GAMMA)},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **endo_gsg_sdf_losses(), **hexplane_regularisers(),
                "mask": LossWeight(TOOL_MASK_WEIGHT)},
        init=InitConfig(fusion="mapf"))


PRESET = Preset("DRAWER: Endo-GSG with Gaussians anchored on the faces of the SDF's "
                "marching-cubes mesh (face-local offset clipped straight-through, scales "
                "projected onto their clip, re-anchored every 100 steps) and PhysioSplat's "
                "tool field", drawer)
