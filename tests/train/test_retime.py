"""Retiming: the time-dependent components follow a time axis that a stream stretches."""

from __future__ import annotations

import torch

from surgsplat.fields.gaussian_basis import GaussianBasisConfig, deformation_channels
from surgsplat.model.color_curves import ColorCurvesConfig
from surgsplat.model.component import SceneInfo, SetupContext
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.gaussians import GaussianConfig, GaussianModel


def curved_gaussians(attributes: dict[str, torch.Tensor]) -> GaussianModel:
    """Twelve Gaussians with random curves in `attributes` (weights, centres, widths)."""
    generator = torch.Generator().manual_seed(0)
    for name, value in attributes.items():
        attributes[name] = value + 0.3 * torch.randn(value.shape, generator=generator)
    return GaussianModel.from_points(torch.randn(12, 3, generator=generator),
                                     torch.rand(12, 3, generator=generator), GaussianConfig(),
                                     attributes)


def test_curves_are_retimed_exactly():
    """A curve compressed by a factor is, at factor x t, what it was at t (float32 to 1e-5)."""
    context = SetupContext(SceneInfo(16, 32, 32, ()), torch.zeros(12, 3), 1.0, ())
    for config, names in ((GaussianBasisConfig(), ("basis_weights", "basis_centres",
                                                   "basis_log_widths")),
                          (ColorCurvesConfig(), ("color_curve_weights", "color_curve_centres",
                                                 "color_curve_log_widths"))):
        component = config.build()
        gaussians = curved_gaussians(component.initial_attributes(context))
        params = gaussians.params
        before = [deformation_channels(*(params[n] for n in names), t).detach()
                  for t in (0.0, 0.3, 0.9)]
        for factor in (0.5, 64 / 100, 1.7):
            component.retime(gaussians, factor)
            after = [deformation_channels(*(params[n] for n in names), factor * t).detach()
                     for t in (0.0, 0.3, 0.9)]
            for old, new in zip(before, after):
                torch.testing.assert_close(new, old, rtol=1e-5, atol=1e-5)
            component.retime(gaussians, 1 / factor)


def test_exposure_is_resampled_onto_its_knots():
    """The exposure's knots take the old curve at their retimed times: exact at times that
    fall on a knot both before and after (tolerance 1e-6), and constant past the old end."""
    exposure = ExposureConfig(knots=9).build()
    with torch.no_grad():
        exposure.log_gains.copy_(torch.linspace(-0.4, 0.4, 27).reshape(9, 3).sin())
    before = {t: exposure.gain(t) for t in (0.0, 0.25, 0.5, 1.0)}
    exposure.retime(None, 0.5)
    for t, gain in before.items():
        torch.testing.assert_close(exposure.gain(0.5 * t), gain, rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(exposure.gain(0.8), before[1.0], rtol=1e-6, atol=1e-6)
