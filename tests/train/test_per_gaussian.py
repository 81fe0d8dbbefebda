"""Selecting and appending Gaussians keeps parameters, Adam moments and buffers aligned."""

import torch

from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.train.per_gaussian import append_gaussians, keep_gaussians


def model_and_optimizer(n: int = 6):
    model = GaussianModel.from_points(torch.rand(n, 3), torch.rand(n, 3), GaussianConfig(),
                                      {"basis_weights": torch.zeros(n, 4)},
                                      {"origin": torch.arange(n)})
    groups = [{"name": k, "params": [v], "lr": 0.01} for k, v in model.params.items()]
    optimizer = torch.optim.Adam(groups)
    loss = sum((p * torch.arange(p.numel()).reshape(p.shape)).sum() for p in model.parameters())
    loss.backward()
    optimizer.step()
    return model, optimizer


def test_keep_selects_rows_of_parameters_and_moments():
    model, optimizer = model_and_optimizer()
    before = {k: v.detach().clone() for k, v in model.params.items()}
    moments = {k: optimizer.state[v]["exp_avg"].clone() for k, v in model.params.items()}
    keep = torch.tensor([True, False, True, True, False, True])
    keep_gaussians(model, optimizer, keep)
    assert model.num_gaussians == 4
    for name, param in model.params.items():
        assert torch.equal(param.detach(), before[name][keep])
        assert torch.equal(optimizer.state[param]["exp_avg"], moments[name][keep])
        group = next(g for g in optimizer.param_groups if g["name"] == name)
        assert group["params"][0] is param
    assert model.buffer_dict["origin"].tolist() == [0, 2, 3, 5]
    optimizer.step()  # still a consistent optimiser


def test_append_adds_rows_with_zero_moments():
    model, optimizer = model_and_optimizer()
    new = {k: torch.full((2, *v.shape[1:]), 7.0) for k, v in model.per_gaussian().items()}
    append_gaussians(model, optimizer, new)
    assert model.num_gaussians == 8
    for param in model.params.values():
        assert torch.all(param[-2:] == 7.0)
        assert torch.all(optimizer.state[param]["exp_avg"][-2:] == 0)
        assert torch.all(optimizer.state[param]["exp_avg_sq"][-2:] == 0)
    origin = model.buffer_dict["origin"]
    assert origin.dtype == torch.int64 and origin.tolist() == [0, 1, 2, 3, 4, 5, 7, 7]


def test_append_requires_every_parameter_and_buffer():
    model, optimizer = model_and_optimizer()
    try:
        append_gaussians(model, optimizer, {"means": torch.zeros(1, 3)})
    except ValueError as err:
        assert "basis_weights" in str(err) and "origin" in str(err)
    else:
        raise AssertionError("append without all parameters must fail")
