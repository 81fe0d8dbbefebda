"""The colour curves change each Gaussian's SH DC colour over time by its own basis curve, start
as the identity, and train with the Gaussians (densification carries their rows)."""

from __future__ import annotations

from types import SimpleNamespace

import torch

from surgsplat.data.scene import load_scene
from surgsplat.fields.gaussian_basis import basis_values
from surgsplat.methods.registry import method_config
from surgsplat.model.color_curves import CENTRES, LOG_WIDTHS, WEIGHTS, ColorCurvesConfig
from surgsplat.model.component import FrameTime
from surgsplat.model.state import GaussianState
from surgsplat.train.trainer import Trainer


def random_state(n: int, generator: torch.Generator) -> GaussianState:
    return GaussianState(means=torch.zeros(n, 3), scales=torch.ones(n, 3),
                         quats=torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
                         opacities=torch.full((n,), 0.5),
                         sh=torch.randn(n, 4, 3, generator=generator), sh_degree=1)


def test_curves_start_as_the_identity_and_then_offset_only_the_dc_colour():
    generator = torch.Generator().manual_seed(0)
    n = 40
    curves = ColorCurvesConfig(num_basis=5).build()
    params = curves.initial_attributes(SimpleNamespace(points=torch.zeros(n, 3)))
    assert params[WEIGHTS].shape == (n, 3, 5) and params[CENTRES].shape == (n, 5)
    state = random_state(n, generator)
    gaussians = SimpleNamespace(params=params)
    when = FrameTime(2, 0.3)
    assert torch.equal(curves.transform(state, gaussians, when).sh, state.sh)

    params[WEIGHTS] = torch.randn(n, 3, 5, generator=generator, requires_grad=True)
    moved = curves.transform(state, gaussians, when)
    expected = torch.einsum("ncb,nb->nc", params[WEIGHTS],
                            basis_values(params[CENTRES], params[LOG_WIDTHS], when.time))
    torch.testing.assert_close(moved.sh[:, 0] - state.sh[:, 0], expected, rtol=1e-5, atol=1e-6)
    assert torch.equal(moved.sh[:, 1:], state.sh[:, 1:])
    for field in ("means", "scales", "quats", "opacities"):
        assert torch.equal(getattr(moved, field), getattr(state, field))
    moved.sh.sum().backward()
    assert params[WEIGHTS].grad.abs().sum() > 0


def test_achromatic_curves_add_one_offset_to_every_channel():
    generator = torch.Generator().manual_seed(1)
    n = 30
    curves = ColorCurvesConfig(num_basis=4, achromatic=True).build()
    params = curves.initial_attributes(SimpleNamespace(points=torch.zeros(n, 3)))
    assert params[WEIGHTS].shape == (n, 1, 4)
    params[WEIGHTS] = torch.randn(n, 1, 4, generator=generator)
    state = random_state(n, generator)
    offset = (curves.transform(state, SimpleNamespace(params=params), FrameTime(0, 0.6)).sh[:, 0]
              - state.sh[:, 0])
    torch.testing.assert_close(offset, offset[:, :1].expand(-1, 3), rtol=0, atol=1e-6)
    assert offset.abs().amax() > 0


def test_the_curves_rates_decay_to_lr_decay_of_their_start():
    curves = ColorCurvesConfig(weights_lr=0.01, lr_decay=0.2).build()
    rates = curves.attribute_lrs()
    assert rates["color_curve_weights"][0] == 0.01
    for initial, final in rates.values():
        assert abs(final - 0.2 * initial) < 1e-15


def test_a_hexplane_method_with_colour_curves_trains_them_with_its_gaussians(small_phantom,
                                                                            tmp_path):
    config = method_config("endogaussian")
    config.components["color_curves"] = ColorCurvesConfig()
    config.train.iterations = 60
    config.init.max_points = 2000
    config.densify.start = 0.0
    config.densify.every = 10
    trainer = Trainer(config, load_scene(small_phantom), tmp_path / "run")
    trainer.fit()
    params = trainer.model.gaussians.params
    count = trainer.model.gaussians.num_gaussians
    assert count != 2000  # densification changed the rows
    assert params[WEIGHTS].shape[0] == params[CENTRES].shape[0] == count
    assert params[WEIGHTS].abs().amax() > 0  # the photometric loss reached the curves
