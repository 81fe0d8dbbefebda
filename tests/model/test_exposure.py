"""The exposure curve: identity at start, linear interpolation between knots, learnable."""

import math

import torch

from surgsplat.model.exposure import ExposureConfig, ExposureCurve


def test_starts_as_identity_and_interpolates():
    curve = ExposureCurve(ExposureConfig(knots=5))
    torch.testing.assert_close(curve.gain(0.3), torch.ones(3))
    with torch.no_grad():
        curve.log_gains[1] = math.log(2.0)  # knot at t = 0.25
    torch.testing.assert_close(curve.gain(0.25), torch.full((3,), 2.0))
    torch.testing.assert_close(curve.gain(0.125), torch.full((3,), 2.0**0.5))
    torch.testing.assert_close(curve.gain(1.5), torch.ones(3))  # clamped to t = 1


def test_without_knots_the_gain_is_one():
    assert torch.equal(ExposureCurve(ExposureConfig(knots=0)).gain(0.7), torch.ones(3))


def test_fits_a_smooth_exposure_change():
    curve = ExposureCurve(ExposureConfig(knots=8))
    optimizer = torch.optim.Adam(curve.parameters(), lr=0.05)
    times = torch.linspace(0, 1, 30)
    truth = 1.0 + 0.15 * torch.sin(2 * math.pi * times)
    for _ in range(300):
        loss = sum((curve.gain(float(t))[0] - g) ** 2 for t, g in zip(times, truth))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with torch.no_grad():
        errors = [abs(float(curve.gain(float(t))[0]) - float(g)) for t, g in zip(times, truth)]
    assert max(errors) < 0.03
