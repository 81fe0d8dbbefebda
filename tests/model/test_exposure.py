"""The exposure component scales the rendered colour of the Gaussians by its gain, exactly."""

import torch

from surgsplat.model.component import FrameTime
from surgsplat.model.exposure import ExposureConfig
from surgsplat.model.state import GaussianState
from surgsplat.render.sh import eval_sh


def test_gain_in_sh_space_equals_gain_on_the_colour():
    generator = torch.Generator().manual_seed(0)
    n = 50
    state = GaussianState(means=torch.zeros(n, 3), scales=torch.ones(n, 3),
                          quats=torch.tensor([1.0, 0, 0, 0]).repeat(n, 1),
                          opacities=torch.full((n,), 0.5),
                          sh=torch.randn(n, 9, 3, generator=generator), sh_degree=2)
    exposure = ExposureConfig(knots=4).build()
    with torch.no_grad():
        exposure.log_gains.copy_(torch.randn(4, 3, generator=generator) * 0.3)
    when = FrameTime(3, 0.37)
    dirs = torch.nn.functional.normalize(torch.randn(n, 3, generator=generator), dim=-1)
    scaled = exposure.transform(state, None, when)
    expected = eval_sh(2, state.sh, dirs) * exposure.gain(when.time)
    torch.testing.assert_close(eval_sh(2, scaled.sh, dirs), expected, rtol=1e-5, atol=1e-6)


def test_the_gains_rate_decays_to_lr_decay_of_its_start():
    (group,) = ExposureConfig(knots=4, lr=0.01, lr_decay=0.2).build().param_groups()
    assert group.lr == 0.01 and abs(group.lr_final - 0.002) < 1e-15
