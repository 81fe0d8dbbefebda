"""Densification: clone small, split large, prune transparent, reset opacity."""

import math

import torch

from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.methods.settings import DensifyConfig
from surgsplat.train.strategy import DensifyStrategy


def setup(log_scales: list[float], opacities: list[float]):
    n = len(log_scales)
    model = GaussianModel.from_points(torch.arange(3 * n, dtype=torch.float32).reshape(n, 3),
                                      torch.rand(n, 3), GaussianConfig())
    with torch.no_grad():
        model.params["log_scales"][:] = torch.tensor(log_scales)[:, None]
        model.params["opacity_logits"][:] = torch.logit(torch.tensor(opacities))
    optimizer = torch.optim.Adam([{"name": k, "params": [v], "lr": 0.0}
                                  for k, v in model.params.items()])
    return model, optimizer


CONFIG = DensifyConfig(start_iter=1, stop_iter=100, every=1, grad_threshold=0.5,
                       percent_dense=0.01, opacity_reset_every=0)


def test_clone_small_and_split_large_high_gradient_gaussians():
    # extent 100 (split above scale 1, prune above 10): Gaussian 0 (scale 0.5) is small,
    # 1 (scale 2) is large, 2 has a low gradient.
    model, optimizer = setup([math.log(0.5), math.log(2.0), math.log(0.5)], [0.9, 0.9, 0.9])
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=100)
    grads = torch.tensor([1.0, 1.0, 0.1])
    strategy.step_post_backward(1, model, optimizer, grads, torch.tensor([5, 5, 5]))
    # 0 and 2 stay, 0 gains a clone, 1 is replaced by two children of scale 2 / 1.6.
    assert model.num_gaussians == 5
    scales = model.params["log_scales"].exp()[:, 0]
    assert torch.allclose(scales.sort().values,
                          torch.tensor([0.5, 0.5, 0.5, 2 / 1.6, 2 / 1.6]), atol=1e-5)
    clone_means = model.params["means"][2]  # the clone is appended after the survivors
    assert torch.equal(clone_means, model.params["means"][0])
    # the original and its clone composite to the original opacity 0.9
    shared = torch.sigmoid(model.params["opacity_logits"][[0, 2]])
    assert torch.allclose(1 - (1 - shared[0]) * (1 - shared[1]), torch.tensor(0.9), atol=1e-5)


def test_prune_transparent_and_oversized():
    model, optimizer = setup([0.0, 0.0, math.log(20.0)], [0.001, 0.9, 0.9])
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=100)
    strategy.step_post_backward(1, model, optimizer, torch.zeros(3), torch.tensor([1, 1, 1]))
    assert model.num_gaussians == 1
    assert torch.sigmoid(model.params["opacity_logits"][0]) > 0.5


def test_cap_limits_growth():
    model, optimizer = setup([math.log(0.1)] * 4, [0.9] * 4)
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=6)
    strategy.step_post_backward(1, model, optimizer, torch.ones(4), torch.ones(4, dtype=torch.int32))
    assert model.num_gaussians == 6


def test_opacity_reset_caps_opacity():
    model, optimizer = setup([0.0, 0.0], [0.9, 0.005])
    config = DensifyConfig(start_iter=1000, stop_iter=2000, opacity_reset_every=5,
                           reset_opacity=0.01)
    strategy = DensifyStrategy(config, scene_extent=10.0, max_gaussians=100)
    for iteration in range(1, 6):
        strategy.step_post_backward(iteration, model, optimizer, torch.zeros(2), torch.ones(2))
    opacity = torch.sigmoid(model.params["opacity_logits"])
    assert torch.allclose(opacity, torch.tensor([0.01, 0.005]), atol=1e-6)


def test_prune_and_clone_act_on_the_rendered_opacity_with_a_factor():
    # Gaussian 0 has logit opacity 0.9 but a component factor of 0.001: rendered 0.0009 -> pruned.
    # Gaussian 1 (factor 0.5, rendered 0.45) is cloned: the pair composites to 0.45 rendered.
    model, optimizer = setup([math.log(0.5), math.log(0.5)], [0.9, 0.9])
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=100)
    # the factor of the Gaussians present when asked (a clone is appended with its parent's 0.5)
    strategy.step_post_backward(
        1, model, optimizer, torch.tensor([0.0, 1.0]), torch.ones(2),
        opacity_factor=lambda: torch.tensor([0.001] + [0.5] * (model.num_gaussians - 1)))
    assert model.num_gaussians == 2  # 0 pruned; 1 and its clone remain
    rendered = torch.sigmoid(model.params["opacity_logits"]) * 0.5
    assert torch.allclose(1 - (1 - rendered[0]) * (1 - rendered[1]), torch.tensor(0.45),
                          atol=1e-5)
