"""Per-Gaussian colour curves: each Gaussian's diffuse colour changes over time.

Every Gaussian carries an offset of its SH DC colour over time, a sum of B Gaussian basis
functions of time with their own amplitudes, centres and widths: the Gaussian-basis field's
curves (`fields.gaussian_basis`, EndoPlanar eq. 2), applied to the colour only.

Why: a highlight that slides over the tissue, as the surface tilts under a tool with the light at
the camera, brightens each tissue point for a while and then leaves it. A Gaussian-basis field
follows it by moving bright Gaussians with it; a field shared by all Gaussians (HexPlane)
cannot, since its grid is far coarser than a highlight, and its colour output
(`HexPlaneConfig.deform_color`) did not help (issue 28). A curve per Gaussian can brighten and
dim each Gaussian where the highlight passes, and leaves the geometry to the field.

Every preset has them, as every preset has the exposure curve: neither is in the papers, both
model what the papers' scenes do to the colour. Measured (full phantom, 3000 iterations, issue
28), psnr_tissue without and with the curves: endogaussian 40.43 -> 46.95 dB and 40.38 -> 46.26
(seeds 0 and 1; psnr_specular 33.3 -> 43.1, outside the highlights 45.9 -> 48.1, psnr_occluded
29.7 -> 28.8), deform3dgs 44.14 -> 45.65 (seed 0), surgsplat 41.26 -> 45.43 (seed 0);
deform3dgs on the CholecSeg8k clip 26.64 -> 26.80 (seed 0). Achromatic curves (one curve added to
every channel, as the dichromatic model's highlight) gave endogaussian only 41.44 dB (seed 0):
the phantom's highlights, like an endoscope's, clip the red channel, so the light they add is
not grey.

Per-Gaussian attributes (in `GaussianModel.params`, so densification carries them along):
color_basis_weights [N, 3, B] (SH DC units; [N, 1, B] when achromatic), color_basis_centres [N, B] (time) and
color_basis_log_widths [N, B]. All weights start at 0, so the curves start as the identity.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import torch

from surgsplat.errors import SurgsplatError
from surgsplat.fields.deformation import COLOR_CHANNELS, time_capacity
from surgsplat.fields.gaussian_basis import deformation_channels, identity_curves
from surgsplat.model.component import Component, ComponentConfig, FrameTime, SceneInfo
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState

WEIGHTS = "color_basis_weights"
CENTRES = "color_basis_centres"
LOG_WIDTHS = "color_basis_log_widths"


@dataclass
class ColorCurvesConfig(ComponentConfig, kind="color_curves"):
    """Basis size and learning rates of the colour curves."""

    num_basis: int = field(default=8, metadata={"range": "[2, inf)"})
    """Basis functions B per Gaussian (at least 2; at most one per two frames of the clip)."""
    long_clip_frames_per_basis: int = field(default=250, metadata={"range": "[1, inf)"})
    """Clips longer than this x num_basis frames get one basis function per this many frames."""
    max_basis: int = field(default=16, metadata={"range": "[2, inf)"})
    """Upper limit of the basis functions of a long clip."""
    init_width: float = field(default=1.0, metadata={"range": "(0, inf)"})
    """Initial width of every basis function, in units of the spacing of the centres."""
    weights_lr: float = field(default=2.5e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the amplitudes (SH DC units, as 3DGS's colour rate)."""
    centres_lr: float = field(default=1.6e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the centres (time units; the clip spans [0, 1])."""
    log_widths_lr: float = field(default=1e-2, metadata={"range": "[0, inf)"})
    """Adam learning rate of the log-widths."""
    lr_decay: float = field(default=0.1, metadata={"range": "(0, 1]"})
    """Final over initial learning rate of the three (exponential decay over the run)."""
    achromatic: bool = False
    """One curve per Gaussian added to all three channels (light of the light's colour, as a
    specular highlight of the dichromatic reflection model), instead of one per channel."""

    def resolve(self, scene: SceneInfo) -> "ColorCurvesConfig":
        """This config for the scene's clip (`time_capacity`, as the Gaussian-basis field)."""
        return dataclasses.replace(self, num_basis=time_capacity(
            scene.num_frames, self.num_basis, self.long_clip_frames_per_basis, self.max_basis))

    def build(self) -> "ColorCurves":
        return ColorCurves(self)


class ColorCurves(Component):
    """See the module docstring."""
    phase = Phase.APPEARANCE

    def __init__(self, config: ColorCurvesConfig):
        super().__init__()
        if config.num_basis < 2:
            raise SurgsplatError(f"color_curves num_basis must be >= 2, got {config.num_basis}")
        self.config = config

    def initial_attributes(self, context) -> dict[str, torch.Tensor]:
        channels = 1 if self.config.achromatic else COLOR_CHANNELS
        weights, centres, log_widths = identity_curves(
            context.points.shape[0], channels, self.config.num_basis, self.config.init_width)
        return {WEIGHTS: weights, CENTRES: centres, LOG_WIDTHS: log_widths}

    def attribute_lrs(self) -> dict[str, float]:
        config = self.config
        return {WEIGHTS: config.weights_lr, CENTRES: config.centres_lr,
                LOG_WIDTHS: config.log_widths_lr}

    def attribute_lr_finals(self) -> dict[str, float]:
        return {name: rate * self.config.lr_decay for name, rate in self.attribute_lrs().items()}

    def transform(self, state: GaussianState, gaussians, when: FrameTime) -> GaussianState:
        """The SH DC colour plus each Gaussian's curve at `when`."""
        params = gaussians.params
        offsets = deformation_channels(params[WEIGHTS], params[CENTRES], params[LOG_WIDTHS],
                                       when.time)  # [N, 3], or [N, 1] achromatic
        return state.with_dc_offset(offsets.expand(-1, COLOR_CHANNELS))
