"""Named method presets: each returns a MethodConfig of components and values; none has logic.

Every preset is written out whole, and each has the colour curves and the exposure curve beside
its paper's components. A group of values that several presets share (one paper's loss
weights) is a function returning a fresh dict, so that no preset is built from another.
`PRESETS` maps a name to a `Preset` (a one-line description and the function that builds the
config); `surgsplat methods` lists them. What each preset measures, and each deviation from its
paper with its A/B, is on its method page, docs/methods/<preset>.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from surgsplat.errors import SurgsplatError
from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.fields.sdf import SDFConfig
from surgsplat.losses.biomechanics import BiomechanicsConfig
from surgsplat.losses.depth import DepthLossConfig
from surgsplat.losses.photometric import PhotometricConfig
from surgsplat.methods.config import MethodConfig
from surgsplat.methods.ranges import check_config
from surgsplat.methods.settings import LossWeight, TrainConfig
from surgsplat.model.camera_refine import CameraRefineConfig  # noqa: F401  (kind "camera_refine")
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.gaussians import GaussianConfig
from surgsplat.model.init_points import InitConfig
from surgsplat.model.lumistate import LumiStateConfig
from surgsplat.model.mesh_anchor import MeshAnchorConfig
from surgsplat.model.planar import PlanarConfig
from surgsplat.model.specular import SpecularConfig
from surgsplat.model.tool_field import ToolFieldConfig

DEFAULT_PRESET = "deform3dgs"
"""The preset a command uses when `--method` names none."""

DEPTH_WEIGHT = 4.5
"""Weight of the baselines' depth L1, which is relative (divided by the median measured depth):
the 0.05 per millimetre of Deform3DGS and EndoGaussian at the phantom's median depth of 90 mm."""

TOOL_MASK_WEIGHT = 0.1
"""PhysioSplat's lambda_mask: weight of the tool field's mask loss."""

ENDOPLANAR_THICKNESS = 1e-6
"""Initial thickness of EndoPlanar's discs, as a fraction of their radius. The paper starts s_3
at exp(-1e9) = 0, which leaves its flatten loss without a gradient; 1e-6 keeps one (and float32
logs finite)."""

ENDOPLANAR_NORMAL_STOP = 2 / 3
"""Fraction of the run after which EndoPlanar's depth-normal loss leaves the objective (the
paper keeps it to the end)."""

ENDO_GSG_GAMMA = 100.0
"""gamma of Endo-GSG's occlusion importance map, which the paper does not give: Eq. 11 divides
by the Frobenius norm of the summed masks, so gamma must be of the order of sqrt(tool pixels)
for the map to matter."""

ENDO_GSG_PROJECTION_START = 1 / 3
"""Fraction of the run after which Endo-GSG's projection term starts pulling the Gaussians onto
the SDF's zero level; until then the field learns its surface from the opacity bell, the SDA
and Eikonal terms."""

LUMISTATE_STAGE2 = 1 / 3
"""Fraction of the run after which LumiState's Stage 2 (Retinex, bright-channel and
illumination-transfer losses) starts, once geometry and reflectance have settled under the
photometric loss."""

LUMISTATE_TIE_STOP = 2 / 3
"""Fraction of the run after which LumiState's illumination-transfer tie leaves the
objective."""

COARSE_START_FRACTION = 0.1
"""Fraction of deform3dgs's run trained on frames at half their size, before densification
starts (train.coarse_fraction with train.coarse_factor 2)."""


@dataclass(frozen=True)
class Preset:
    """A named method."""

    description: str
    build: Callable[[], MethodConfig]


def hexplane_regularisers() -> dict[str, LossWeight]:
    """EndoGaussian's weights of the HexPlane field's plane TV and time smoothness."""
    return {"plane_tv": LossWeight(1e-4), "time_smoothness": LossWeight(1e-3)}


def endoplanar_disc_losses(normal_stop: float) -> dict[str, LossWeight]:
    """EndoPlanar's flatten loss (lambda_scaling 100) and its depth-normal loss, from a sixth of
    the run until the fraction `normal_stop`."""
    return {"flatten": LossWeight(100.0),
            "normal": LossWeight(0.05, start=1 / 6, stop=normal_stop)}


def endo_gsg_sdf_losses() -> dict[str, LossWeight]:
    """Endo-GSG's weights of its SDF's terms: Eikonal, projection (from
    ENDO_GSG_PROJECTION_START), orientation (off) and SDA."""
    return {"eikonal": LossWeight(0.1),
            "projection": LossWeight(100.0, start=ENDO_GSG_PROJECTION_START),
            "orientation": LossWeight(0.0), "sda": LossWeight(0.1)}


def lumistate_stage2_losses() -> dict[str, LossWeight]:
    """LumiState's Stage 2 from LUMISTATE_STAGE2: the Retinex and bright-channel losses, and the
    illumination-transfer tie until LUMISTATE_TIE_STOP."""
    return {"retinex": LossWeight(0.05, start=LUMISTATE_STAGE2),
            "bright_channel": LossWeight(0.25, start=LUMISTATE_STAGE2),
            "illumination_transfer": LossWeight(0.1, start=LUMISTATE_STAGE2,
                                                stop=LUMISTATE_TIE_STOP)}


def deform3dgs() -> MethodConfig:
    """Deform3DGS: Gaussian-basis deformation, L1 + D-SSIM and depth L1, MAPF point fusion,
    the first COARSE_START_FRACTION of the run on half-size frames."""
    return MethodConfig(
        name="deform3dgs",
        components={"deformation": GaussianBasisConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "photometric": PhotometricConfig(), "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT)},
        train=TrainConfig(coarse_fraction=COARSE_START_FRACTION, coarse_factor=2),
        init=InitConfig(fusion="mapf"))


def endogaussian() -> MethodConfig:
    """EndoGaussian: HexPlane deformation with its plane TV and time smoothness, L1 + D-SSIM and
    depth L1, MAPF point fusion."""
    return MethodConfig(
        name="endogaussian",
        components={"deformation": HexPlaneConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "photometric": PhotometricConfig(), "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **hexplane_regularisers()},
        init=InitConfig(fusion="mapf"))


def endoplanar() -> MethodConfig:
    """EndoPlanar: Gaussian-basis deformation, planar discs that start flat
    (ENDOPLANAR_THICKNESS) with the flatten loss and the depth-normal loss until
    ENDOPLANAR_NORMAL_STOP, the inverse-depth L1 at the baselines' strength, MOG2 point fusion."""
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


def endogsg() -> MethodConfig:
    """Endo-GSG: HexPlane deformation, a canonical neural SDF with its terms, photometric and
    depth losses weighted by the occlusion importance map (ENDO_GSG_GAMMA), MAPF point
    fusion."""
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


def drawer() -> MethodConfig:
    """DRAWER: Endo-GSG's components and weights with the tissue Gaussians anchored on the SDF's
    mesh (the anchor first, so that the deformation moves the anchored Gaussians) and
    PhysioSplat's tool field with its mask loss."""
    return MethodConfig(
        name="drawer",
        components={"anchor": MeshAnchorConfig(), "deformation": HexPlaneConfig(),
                    "color_curves": ColorCurvesConfig(), "tool": ToolFieldConfig(),
                    "exposure": ExposureConfig(),
                    "sdf": SDFConfig(),
                    "photometric": PhotometricConfig(occlusion_gamma=ENDO_GSG_GAMMA),
                    "depth": DepthLossConfig(occlusion_gamma=ENDO_GSG_GAMMA)},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **endo_gsg_sdf_losses(), **hexplane_regularisers(),
                "mask": LossWeight(TOOL_MASK_WEIGHT)},
        init=InitConfig(fusion="mapf"))


def lumistate() -> MethodConfig:
    """LumiState: reflectance x illumination with its Stage 2 losses, on Deform3DGS's
    Gaussian-basis deformation and exposure curve, so that the decomposition is the only
    difference from the deform3dgs baseline."""
    return MethodConfig(
        name="lumistate",
        components={"deformation": GaussianBasisConfig(), "color_curves": ColorCurvesConfig(),
                    "exposure": ExposureConfig(),
                    "lumistate": LumiStateConfig(), "photometric": PhotometricConfig(),
                    "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **lumistate_stage2_losses()},
        init=InitConfig(fusion="mapf"))


def physiosplat() -> MethodConfig:
    """PhysioSplat: HexPlane tissue with a volume-preservation loss, the tool field with its
    mask loss, ARAP strain and tool-collision losses, a co-located specular lobe on SH0 colour,
    MAPF point fusion."""
    return MethodConfig(
        name="physiosplat",
        components={"deformation": HexPlaneConfig(volume_samples=512),
                    "color_curves": ColorCurvesConfig(), "tool": ToolFieldConfig(),
                    "exposure": ExposureConfig(), "specular": SpecularConfig(),
                    "biomechanics": BiomechanicsConfig(), "photometric": PhotometricConfig(),
                    "depth": DepthLossConfig()},
        losses={"photometric": LossWeight(1.0), "depth": LossWeight(DEPTH_WEIGHT),
                **hexplane_regularisers(), "mask": LossWeight(TOOL_MASK_WEIGHT),
                "strain": LossWeight(1.3e-4), "collision": LossWeight(1.3e-3),
                "volume": LossWeight(1.1e-8)},
        gaussians=GaussianConfig(sh_degree=0),
        init=InitConfig(fusion="mapf"))


def surgsplat() -> MethodConfig:
    """The project's own method: EndoGaussian's HexPlane deformation, EndoPlanar's flat discs
    with their flatten and depth-normal losses (this one to the end of the run) and LumiState's
    reflectance x illumination with its Stage 2 losses, each at its own paper's values, on the
    baselines' depth L1 and MAPF point fusion."""
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


PRESETS: dict[str, Preset] = {
    "surgsplat": Preset("surgsplat's own method: EndoGaussian's HexPlane deformation, "
                        "EndoPlanar's discs and depth-normal loss, LumiState's reflectance x "
                        "illumination", surgsplat),
    "deform3dgs": Preset("Deform3DGS baseline: per-Gaussian Gaussian-basis deformation, "
                         "motion-aware point fusion, L1 + D-SSIM and depth L1", deform3dgs),
    "endogaussian": Preset("EndoGaussian baseline: HexPlane deformation field with plane TV and "
                           "time smoothness", endogaussian),
    "endoplanar": Preset("EndoPlanar: flattened Gaussians with unbiased plane depth, inverse-depth "
                         "loss, edge-aware depth-normal loss, MOG2 point fusion", endoplanar),
    "endogsg": Preset("Endo-GSG: HexPlane deformation, canonical neural SDF giving each Gaussian "
                      "its opacity, SDA / projection / orientation / Eikonal losses, occlusion "
                      "importance map", endogsg),
    "drawer": Preset("DRAWER: Endo-GSG with Gaussians anchored on the faces of the SDF's "
                     "marching-cubes mesh (face-local offset clipped straight-through, scales "
                     "projected onto their clip, re-anchored every 100 steps) and PhysioSplat's "
                     "tool field", drawer),
    "lumistate": Preset("LumiState: reflectance x illumination (UNet on max(R,G,B), per-Gaussian "
                        "SH modulation from its embedding, Retinex and bright-channel losses "
                        "in Stage 2), Gaussian-basis deformation", lumistate),
    "physiosplat": Preset("PhysioSplat: tool Gaussians with per-frame rigid motion and semantic "
                          "logits beside HexPlane tissue, tool-free rendering, ARAP strain, tool "
                          "collision and volume losses, co-located specular lobe", physiosplat),
}


def method_config(name: str) -> MethodConfig:
    """The preset called `name`, its values checked against their declared ranges;
    SurgsplatError listing the known presets otherwise."""
    if name not in PRESETS:
        raise SurgsplatError(f"unknown method {name!r}; known: {', '.join(sorted(PRESETS))}")
    config = PRESETS[name].build()
    check_config(config, name)
    return config
