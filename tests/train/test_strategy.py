"""Densification: clone small, split large, prune transparent, reset opacity."""

import dataclasses
import math

import pytest
import torch
from torch import Tensor

from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.methods.settings import DensifyConfig
from surgsplat.render.rotation import quaternion_to_matrix
from surgsplat.train.strategy import BudgetStrategy, DensifyStrategy, build_strategy


def setup(log_scales: list[float], opacities: list[float], buffers: dict | None = None):
    n = len(log_scales)
    model = GaussianModel.from_points(torch.arange(3 * n, dtype=torch.float32).reshape(n, 3),
                                      torch.rand(n, 3), GaussianConfig(), buffers=buffers)
    with torch.no_grad():
        model.params["log_scales"][:] = torch.tensor(log_scales)[:, None]
        model.params["opacity_logits"][:] = torch.logit(torch.tensor(opacities))
    optimizer = torch.optim.Adam([{"name": k, "params": [v], "lr": 0.0}
                                  for k, v in model.params.items()])
    return model, optimizer


CONFIG = DensifyConfig(start=0.0, stop=1.0, every=1, grad_threshold=0.5,
                       percent_dense=0.01, opacity_reset_every=0)
ITERATIONS = 100
"""Length of the runs the strategies of these tests are built for."""
UNIT = 2
"""Image size (px) at which the strategy's NDC scale, half the size, leaves a gradient as given."""


def test_clone_small_and_split_large_high_gradient_gaussians():
    # extent 100 (split above scale 1, prune above 10): Gaussian 0 (scale 0.5) is small,
    # 1 (scale 2) is large, 2 has a low gradient.
    model, optimizer = setup([math.log(0.5), math.log(2.0), math.log(0.5)], [0.9, 0.9, 0.9])
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=100,
                               iterations=ITERATIONS)
    grads = torch.tensor([1.0, 1.0, 0.1])
    strategy.step_post_backward(1, model, optimizer, grads, UNIT, torch.tensor([5, 5, 5]))
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


def test_buffers_follow_their_rows_through_clone_split_and_prune():
    """A per-Gaussian buffer (each Gaussian's origin: the row it started in) is copied to clones
    and split children and dropped with pruned rows, and has no optimiser group: every row's
    colour, which densification leaves alone, is still its origin's."""
    # 0 small (cloned), 1 large (split), 2 transparent (pruned), 3 low gradient (kept)
    model, optimizer = setup([math.log(0.5), math.log(2.0), math.log(0.5), math.log(0.5)],
                             [0.9, 0.9, 0.001, 0.9], buffers={"origin": torch.arange(4)})
    colours = model.params["sh_dc"].detach().clone()
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=100,
                               iterations=ITERATIONS)
    strategy.step_post_backward(1, model, optimizer, torch.tensor([1.0, 1.0, 0.1, 0.1]),
                                UNIT, torch.ones(4))
    origin = model.buffer_dict["origin"]
    assert origin.dtype == torch.int64 and sorted(origin.tolist()) == [0, 0, 1, 1, 3]
    assert torch.equal(model.params["sh_dc"].detach(), colours[origin])
    assert "origin" not in [group["name"] for group in optimizer.param_groups]


def test_prune_transparent_and_oversized():
    model, optimizer = setup([0.0, 0.0, math.log(20.0)], [0.001, 0.9, 0.9])
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=100,
                               iterations=ITERATIONS)
    strategy.step_post_backward(1, model, optimizer, torch.zeros(3), UNIT, torch.tensor([1, 1, 1]))
    assert model.num_gaussians == 1
    assert torch.sigmoid(model.params["opacity_logits"][0]) > 0.5


def test_cap_limits_growth():
    model, optimizer = setup([math.log(0.1)] * 4, [0.9] * 4)
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=6,
                               iterations=ITERATIONS)
    strategy.step_post_backward(1, model, optimizer, torch.ones(4), UNIT,
                                torch.ones(4, dtype=torch.int32))
    assert model.num_gaussians == 6


def test_opacity_reset_caps_opacity():
    model, optimizer = setup([0.0, 0.0], [0.9, 0.005])
    config = DensifyConfig(start=0.5, stop=1.0, opacity_reset_every=0.05, reset_opacity=0.01)
    strategy = DensifyStrategy(config, scene_extent=10.0, max_gaussians=100,
                               iterations=ITERATIONS)
    for iteration in range(1, 6):
        strategy.step_post_backward(iteration, model, optimizer, torch.zeros(2), UNIT,
                                    torch.ones(2))
    opacity = torch.sigmoid(model.params["opacity_logits"])
    assert torch.allclose(opacity, torch.tensor([0.01, 0.005]), atol=1e-6)


@pytest.mark.parametrize("iterations", [300, 3000])
def test_opacity_resets_fire_at_their_fraction_of_the_run_and_only_while_densifying(iterations):
    """The reset period and the densification window are fractions of the run: a reset every
    0.3 of it with densification up to 2/3 fires at 0.3 and 0.6 of any length, never after."""
    config = DensifyConfig(start=0.1, stop=2 / 3, every=10**9, opacity_reset_every=0.3,
                           grad_threshold=1e9, min_opacity=0.0)
    model, optimizer = setup([0.0], [0.9])
    strategy = DensifyStrategy(config, scene_extent=10.0, max_gaussians=100,
                               iterations=iterations)
    fired = []
    for iteration in range(1, iterations + 1):
        model.params["opacity_logits"].data.fill_(2.0)  # sigmoid 0.88: a reset caps it at 0.01
        strategy.step_post_backward(iteration, model, optimizer, torch.zeros(1), UNIT,
                                    torch.ones(1))
        if torch.sigmoid(model.params["opacity_logits"][0]) < 0.02:
            fired.append(iteration)
    assert fired == [round(0.3 * iterations), 2 * round(0.3 * iterations)]


def test_prune_and_clone_act_on_the_rendered_opacity_with_a_factor():
    # Gaussian 0 has logit opacity 0.9 but a component factor of 0.001: rendered 0.0009 -> pruned.
    # Gaussian 1 (factor 0.5, rendered 0.45) is cloned: the pair composites to 0.45 rendered.
    model, optimizer = setup([math.log(0.5), math.log(0.5)], [0.9, 0.9])
    strategy = DensifyStrategy(CONFIG, scene_extent=100.0, max_gaussians=100,
                               iterations=ITERATIONS)
    # the factor of the Gaussians present when asked (a clone is appended with its parent's 0.5)
    strategy.step_post_backward(
        1, model, optimizer, torch.tensor([0.0, 1.0]), UNIT, torch.ones(2),
        opacity_factor=lambda: torch.tensor([0.001] + [0.5] * (model.num_gaussians - 1)))
    assert model.num_gaussians == 2  # 0 pruned; 1 and its clone remain
    rendered = torch.sigmoid(model.params["opacity_logits"]) * 0.5
    assert torch.allclose(1 - (1 - rendered[0]) * (1 - rendered[1]), torch.tensor(0.45),
                          atol=1e-5)


def split_one(scales: list[float], quat: list[float],
              split: str) -> tuple[GaussianModel, Tensor]:
    """Split the single Gaussian of a model (extent 100: scale above 1 is large); returns the
    model, now its two children, and the parent's covariance [3, 3]."""
    model, optimizer = setup([0.0], [0.9])
    with torch.no_grad():
        model.params["log_scales"][0] = torch.tensor(scales).log()
        model.params["quats"][0] = torch.tensor(quat)
    rotation = quaternion_to_matrix(model.params["quats"][0].detach())
    covariance = rotation @ torch.diag(torch.tensor(scales) ** 2) @ rotation.T
    config = dataclasses.replace(CONFIG, split=split)
    strategy = DensifyStrategy(config, scene_extent=100.0, max_gaussians=100,
                               iterations=ITERATIONS)
    strategy.step_post_backward(1, model, optimizer, torch.ones(1), UNIT, torch.ones(1))
    assert model.num_gaussians == 2
    return model, covariance


def test_long_axis_split_keeps_the_parents_mean_and_covariance():
    # scales 3, 1.5, 2 rotated: the children sit along the rotated x axis, only that axis shrinks,
    # and their equal mixture has the parent's mean and covariance (tolerance 1e-4 relative)
    quat = [0.9, 0.2, -0.3, 0.25]
    model, parent_covariance = split_one([3.0, 1.5, 2.0], quat, "long_axis")
    means = model.params["means"].detach()
    assert torch.allclose(means.mean(dim=0), torch.tensor([0.0, 1.0, 2.0]), atol=1e-5)
    scales = model.params["log_scales"].detach().exp()
    assert torch.allclose(scales, torch.tensor([[3.0 / 1.6, 1.5, 2.0]] * 2), rtol=1e-5)
    rotation = quaternion_to_matrix(model.params["quats"][0].detach())
    offset = means[0] - means.mean(dim=0)
    assert torch.allclose(offset, rotation[:, 0] * 3.0 * math.sqrt(1 - 1 / 1.6 ** 2), atol=1e-5)
    child_covariance = rotation @ torch.diag(scales[0] ** 2) @ rotation.T
    mixture = child_covariance + torch.outer(offset, offset)
    assert torch.allclose(mixture, parent_covariance, rtol=1e-4, atol=1e-4)


def test_sample_split_shrinks_every_axis_around_random_points():
    torch.manual_seed(0)
    model, _ = split_one([3.0, 1.5, 2.0], [1.0, 0.0, 0.0, 0.0], "sample")
    scales = model.params["log_scales"].detach().exp()
    assert torch.allclose(scales, torch.tensor([[3.0, 1.5, 2.0]] * 2) / 1.6, rtol=1e-5)
    means = model.params["means"].detach()
    assert not torch.allclose(means[0] + means[1], torch.tensor([0.0, 2.0, 4.0]), atol=1e-3)


def test_the_strategy_scales_gradients_to_ndc_and_weights_them():
    """absgrad in pixels x half the image size, times the components' weights."""
    model, optimizer = setup([-3.0, -3.0], [0.9, 0.9])
    config = dataclasses.replace(CONFIG, every=1000)
    strategy = DensifyStrategy(config, scene_extent=100.0, max_gaussians=100,
                               iterations=ITERATIONS)
    strategy.step_post_backward(1, model, optimizer, torch.tensor([0.01, 0.02]), 200,
                                torch.ones(2), torch.tensor([1.0, 0.5]))
    assert torch.allclose(strategy.grad_sum, torch.tensor([1.0, 1.0]))


def test_the_kind_names_the_strategy():
    for kind, strategy_class in (("threshold", DensifyStrategy), ("budget", BudgetStrategy)):
        config = dataclasses.replace(CONFIG, kind=kind)
        assert type(build_strategy(config, 100.0, 100, ITERATIONS)) is strategy_class


def test_the_budget_adds_what_its_schedule_allows_highest_gradient_first():
    """Ten Gaussians, a window over the whole run of 100 iterations growing the count to 1.5x:
    at iteration 50 the schedule allows 12.5 -> 12, so the two of highest gradient (whatever the
    threshold) are cloned; an unseen Gaussian is never chosen."""
    model, optimizer = setup([-3.0] * 10, [0.9] * 10)
    config = dataclasses.replace(CONFIG, kind="budget", budget_final=1.5, every=50,
                                 grad_threshold=1e9)
    strategy = build_strategy(config, scene_extent=100.0, max_gaussians=100,
                              iterations=ITERATIONS)
    grads = torch.tensor([0.1, 0.9, 0.2, 0.8, 0.3, 0.0, 0.0, 0.0, 0.0, 5.0])
    radii = torch.tensor([1, 1, 1, 1, 1, 1, 1, 1, 1, 0])  # the last one unseen
    first = model.params["means"].detach().clone()
    for iteration in range(1, 51):
        strategy.step_post_backward(iteration, model, optimizer, grads, UNIT, radii)
    assert model.num_gaussians == 12
    added = model.params["means"].detach()[10:]
    assert {tuple(row.tolist()) for row in added} == {tuple(first[1].tolist()),
                                                     tuple(first[3].tolist())}
    assert strategy.state_dict()["start_count"] == 10


def test_the_budget_is_resumed_from_its_state():
    model, optimizer = setup([-3.0] * 4, [0.9] * 4)
    config = dataclasses.replace(CONFIG, kind="budget", budget_final=2.0, every=10)
    strategy = build_strategy(config, 100.0, 100, ITERATIONS)
    strategy.step_post_backward(10, model, optimizer, torch.ones(4), UNIT, torch.ones(4))
    resumed = build_strategy(config, 100.0, 100, ITERATIONS)
    resumed.load_state_dict(strategy.state_dict())
    assert resumed.start_count == 4
