"""Per-Gaussian colour curves: each Gaussian's diffuse colour changes over time.

Every Gaussian carries an offset of its SH DC colour over time, a sum of B Gaussian basis
functions of time with their own amplitudes, centres and widths: the Gaussian-basis field's
curves (`fields.gaussian_basis`), applied to the colour only.

Why: a highlight that slides over the tissue, as the surface tilts under a tool with the light at
the camera, brightens each tissue point for a while and then leaves it. A Gaussian-basis field
follows it by moving bright Gaussians with it; a field shared by all Gaussians (HexPlane)
cannot, since its grid is far coarser than a highlight, and its colour output
(`HexPlaneConfig.deform_color`) does not help. A curve per Gaussian can brighten and dim each
Gaussian where the highlight passes, and leaves the geometry to the field.

Every built-in method has them, as it has the exposure curve: they model what an endoscope's
light does to the colour of the scene, whatever the method does to its geometry. There is one
curve per colour channel: an endoscope's highlights clip the red channel, so the light they add
is not grey, and one curve shared by the three channels (`achromatic`) fits them less well. The
measurements behind these choices are on the documentation page "Components every method
shares" (docs/methods/shared-components.md).

Per-Gaussian attributes (in `GaussianModel.params`, so densification carries them along):
color_curve_weights [N, 3, B] (SH DC units; [N, 1, B] when achromatic), color_curve_centres
[N, B] (time) and color_curve_log_widths [N, B]. All weights start at 0, so the curves start
as the identity.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from surgsplat.errors import SurgsplatError
from surgsplat.fields.deformation import COLOR_CHANNELS
from surgsplat.fields.gaussian_basis import (BasisCurvesConfig, deformation_channels,
                                             identity_curves, retime_curves)
from surgsplat.model.capabilities import Retimable
from surgsplat.model.component import Component, FrameTime
from surgsplat.model.phases import Phase
from surgsplat.model.state import GaussianState

WEIGHTS = "color_curve_weights"
CENTRES = "color_curve_centres"
LOG_WIDTHS = "color_curve_log_widths"


@dataclass
class ColorCurvesConfig(BasisCurvesConfig, kind="color_curves"):
    """The colour curves: the Gaussian-basis field's basis, size and rates (`BasisCurvesConfig`),
    but for the amplitudes' rate, and whether one curve serves all three channels."""

    weights_lr: float = field(default=2.5e-3, metadata={"range": "[0, inf)"})
    """Adam learning rate of the amplitudes (SH DC units, 3DGS's rate of the colour itself)."""
    achromatic: bool = False
    """One curve per Gaussian added to all three channels (light of the light's colour, as a
    specular highlight of the dichromatic reflection model), instead of one per channel."""

    def build(self) -> "ColorCurves":
        return ColorCurves(self)


class ColorCurves(Component):
    """See the module docstring."""
    phase = Phase.APPEARANCE
    provides = (Retimable,)

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

    def attribute_lrs(self) -> dict[str, tuple[float, float]]:
        return self.config.curve_lrs(WEIGHTS, CENTRES, LOG_WIDTHS)

    def retime(self, gaussians, factor: float) -> None:
        retime_curves(gaussians, CENTRES, LOG_WIDTHS, factor)

    def transform(self, state: GaussianState, gaussians, when: FrameTime) -> GaussianState:
        """The SH DC colour plus each Gaussian's curve at `when`."""
        params = gaussians.params
        offsets = deformation_channels(params[WEIGHTS], params[CENTRES], params[LOG_WIDTHS],
                                       when.time)  # [N, 3], or [N, 1] achromatic
        return state.with_dc_offset(offsets.expand(-1, COLOR_CHANNELS))
