"""HexPlane and Gaussian-basis deformation fields: identity start, gradients, fitting motion,
regularisers, per-Gaussian attributes through densification, checkpoints."""

import math

import pytest
import torch

from surgsplat.errors import SurgsplatError
from surgsplat.fields.deformation import Deformation
from surgsplat.fields.gaussian_basis import GaussianBasisConfig, GaussianBasisField, basis_values
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.model.gaussians import GEOMETRY_KEYS, GaussianConfig, GaussianModel
from surgsplat.train.per_gaussian import append_gaussians, keep_gaussians

SMALL_HEXPLANE = dict(base_resolution=8, multires=(1, 2), max_resolution=16, time_resolution=9,
                      feature_dim=8, mlp_width=32)


def make_field(kind: str, deform_color: bool = False, **overrides):
    if kind == "hexplane":
        config = HexPlaneConfig(**{**SMALL_HEXPLANE, **overrides}, deform_color=deform_color)
    else:
        config = GaussianBasisConfig(**overrides, deform_color=deform_color)
    field = config.build()
    field.set_bounds(torch.tensor([-2.0, 0.0, 10.0]), torch.tensor([2.0, 3.0, 14.0]))
    return field


def random_means(n: int, generator: torch.Generator) -> torch.Tensor:
    lo, hi = torch.tensor([-2.0, 0.0, 10.0]), torch.tensor([2.0, 3.0, 14.0])
    return lo + (hi - lo) * torch.rand(n, 3, generator=generator)


def leaves(field, attributes):
    """Every learnable tensor: the field's parameters and the per-Gaussian attributes."""
    return {**dict(field.named_parameters()), **attributes}


def offsets(delta: Deformation) -> torch.Tensor:
    parts = [delta.d_means, delta.d_log_scales, delta.d_quats]
    if delta.d_colors is not None:
        parts.append(delta.d_colors)
    return torch.cat(parts, dim=1)


@pytest.mark.parametrize("kind", ["hexplane", "gaussian_basis"])
@pytest.mark.parametrize("deform_color", [False, True])
def test_field_starts_as_identity(kind, deform_color):
    torch.manual_seed(0)
    field = make_field(kind, deform_color)
    means = random_means(50, torch.Generator().manual_seed(1))
    attributes = field.per_gaussian_attributes(50)
    assert not set(attributes) & set(GEOMETRY_KEYS)
    for t in (0.0, 0.37, 1.0):
        delta = field(means, attributes, t)
        assert delta.d_means.shape == (50, 3) and delta.d_log_scales.shape == (50, 3)
        assert delta.d_quats.shape == (50, 4)
        assert (delta.d_colors is not None) == deform_color
        assert torch.count_nonzero(offsets(delta)) == 0


@pytest.mark.parametrize("kind", ["hexplane", "gaussian_basis"])
def test_gradients_reach_every_parameter_attribute_and_mean(kind):
    torch.manual_seed(0)
    field = make_field(kind, deform_color=True)
    means = random_means(40, torch.Generator().manual_seed(2)).requires_grad_(True)
    attributes = {k: v.requires_grad_(True) for k, v in field.per_gaussian_attributes(40).items()}
    learnable = leaves(field, attributes)
    optimizer = torch.optim.Adam(learnable.values(), lr=1e-2)
    target = torch.randn(40, 13)
    for _ in range(2):  # the first step leaves the zero-initialised output layer non-zero
        optimizer.zero_grad()
        means.grad = None
        loss = (offsets(field(means, attributes, 0.3)) - target).square().sum()
        loss.backward()
        optimizer.step()
    for name, tensor in learnable.items():
        assert tensor.grad is not None and tensor.grad.abs().sum() > 0, name
    if kind == "hexplane":  # the canonical means are an input of the planes
        assert means.grad.abs().sum() > 0


def fit_sinusoid(field, attributes: dict, means: torch.Tensor, amplitude: torch.Tensor,
                 phase: torch.Tensor, lr: float, steps: int) -> float:
    """Fit d_means(t) = amplitude * sin(2 pi t + phase) per point with Adam, 8 random times per
    step; returns the worst error over the points and a grid of 21 times."""
    learnable = leaves(field, attributes)
    optimizer = torch.optim.Adam(learnable.values(), lr=lr)
    generator = torch.Generator().manual_seed(3)

    def target(t: float) -> torch.Tensor:
        return amplitude * torch.sin(2 * math.pi * t + phase)[:, None]  # [N, 3]

    for _ in range(steps):
        optimizer.zero_grad()
        for t in torch.rand(8, generator=generator).tolist():
            (field(means, attributes, t).d_means - target(t)).square().mean().backward()
        optimizer.step()
    with torch.no_grad():
        return max(float((field(means, attributes, t).d_means - target(t)).abs().max())
                   for t in torch.linspace(0, 1, 21).tolist())


def test_gaussian_basis_fits_sinusoidal_motion():
    torch.manual_seed(0)
    field = make_field("gaussian_basis")
    means = random_means(6, torch.Generator().manual_seed(4))
    attributes = {k: v.requires_grad_(True) for k, v in field.per_gaussian_attributes(6).items()}
    amplitude = torch.tensor([0.3, -0.2, 0.1])  # scene units, per axis
    phase = torch.linspace(0, math.pi, 6)
    error = fit_sinusoid(field, attributes, means, amplitude, phase, lr=3e-3, steps=600)
    assert error < 0.03  # 10% of the largest amplitude


def test_hexplane_fits_sinusoidal_motion():
    torch.manual_seed(0)
    field = make_field("hexplane")
    means = random_means(6, torch.Generator().manual_seed(4))
    amplitude = torch.tensor([0.3, -0.2, 0.1])
    phase = torch.linspace(0, math.pi, 6)
    error = fit_sinusoid(field, {}, means, amplitude, phase, lr=1e-2, steps=200)
    assert error < 0.03  # 10% of the largest amplitude


def test_hexplane_regularisers_decrease_when_optimised():
    torch.manual_seed(0)
    field = make_field("hexplane")
    with torch.no_grad():
        for plane in field.time_planes:
            plane.add_(0.1 * torch.randn_like(plane))
    before = {k: float(v.detach()) for k, v in field.regularisation().items()}
    assert set(before) == {"plane_tv", "time_smoothness"} and min(before.values()) > 0
    optimizer = torch.optim.Adam(field.parameters(), lr=1e-2)
    for _ in range(5):
        optimizer.zero_grad()
        sum(field.regularisation().values()).backward()
        optimizer.step()
    after = {k: float(v.detach()) for k, v in field.regularisation().items()}
    for name in before:
        assert after[name] < 0.9 * before[name], name


def test_hexplane_regularisers_vanish_on_smooth_planes():
    field = make_field("hexplane")
    with torch.no_grad():
        for plane in field.spatial_planes:
            plane.fill_(0.3)
        for plane in field.time_planes:  # linear in time: zero second difference
            steps = torch.arange(plane.shape[2], dtype=plane.dtype)
            plane.copy_(1.0 + 0.1 * steps[None, None, :, None].expand_as(plane))
    values = field.regularisation()
    assert float(values["plane_tv"].detach()) == 0.0
    assert float(values["time_smoothness"].detach()) == pytest.approx(0.0, abs=1e-12)


def test_hexplane_of_one_frame_has_a_finite_time_smoothness():
    """One frame gives a time axis of 2 cells, which has no second difference: the smoothness
    is 0 (it was the mean of nothing, NaN, and stopped every run on a single stereo pair)."""
    field = make_field("hexplane", time_resolution=2)
    with torch.no_grad():
        for plane in field.time_planes:
            plane.add_(torch.randn_like(plane))
    values = field.regularisation()
    assert float(values["time_smoothness"].detach()) == 0.0
    assert math.isfinite(float(values["plane_tv"].detach()))
    sum(values.values()).backward()
    assert all(torch.isfinite(plane.grad).all() for plane in field.time_planes)


def test_hexplane_lookup_at_grid_nodes_multiplies_the_six_cells():
    torch.manual_seed(0)
    field = make_field("hexplane", multires=(1,))
    with torch.no_grad():
        field.spatial_planes[0].uniform_(0.5, 1.5)
        field.time_planes[0].uniform_(0.5, 1.5)
    resolution, steps = 8, 9  # spatial cells per axis and time cells of the small config
    cell = torch.tensor([2, 5, 7])  # node index along x, y, z
    lo, hi = field.bounds_lo, field.bounds_hi
    mean = lo + (hi - lo) * cell / (resolution - 1)
    row = 3
    features = field.features(mean[None], row / (steps - 1))[:, 0]  # [C]
    spatial, temporal = field.spatial_planes[0], field.time_planes[0]
    x, y, z = cell.tolist()
    # Plane (a, b) is indexed [height = b, width = a]; time planes [height = t, width = axis].
    expected = (spatial[0, :, y, x] * spatial[1, :, z, x] * spatial[2, :, z, y]
                * temporal[0, :, row, x] * temporal[1, :, row, y] * temporal[2, :, row, z])
    torch.testing.assert_close(features, expected, rtol=1e-5, atol=1e-6)


def test_hexplane_param_groups_cover_all_parameters_once():
    field = make_field("hexplane")
    groups = field.param_groups()
    grouped = [p for group in groups for p in group.params]
    assert len(grouped) == len(set(map(id, grouped))) == len(list(field.parameters()))
    assert {g.name for g in groups} == {"hexplane_grid", "hexplane_time_grid", "hexplane_mlp"}
    rates = {g.name: g.lr for g in groups}
    assert rates["hexplane_time_grid"] == field.config.time_grid_lr
    assert set(field.loss_names()) == set(field.regularisation())
    assert field.per_gaussian_attributes(5) == {} and field.attribute_lrs() == {}


def test_hexplane_rates_decay_to_lr_decay_of_their_start():
    field = make_field("hexplane")
    for group in field.param_groups():
        assert group.lr_final == pytest.approx(group.lr * field.config.lr_decay, rel=1e-12)


def test_gaussian_basis_attribute_rates_decay_to_lr_decay_of_their_start():
    field = GaussianBasisConfig(lr_decay=0.25).build()
    for initial, final in field.attribute_lrs().values():
        assert final == pytest.approx(0.25 * initial, rel=1e-12)


def test_mean_offsets_scale_with_the_bounds():
    """The same weights give mean offsets proportional to the bounds' half-diagonal."""
    field = GaussianBasisConfig().build()
    attributes = field.per_gaussian_attributes(3)
    attributes["basis_weights"].normal_()
    means = torch.zeros(3, 3)
    field.set_bounds(torch.zeros(3), torch.ones(3))
    small = field(means, attributes, 0.5)
    field.set_bounds(torch.zeros(3), torch.full((3,), 10.0))
    large = field(means, attributes, 0.5)
    torch.testing.assert_close(large.d_means, 10 * small.d_means)
    torch.testing.assert_close(large.d_quats, small.d_quats)


def test_gaussian_basis_matches_the_paper_formula():
    torch.manual_seed(0)
    field = make_field("gaussian_basis", num_basis=5)
    attributes = field.per_gaussian_attributes(4)
    attributes["basis_weights"].normal_()
    attributes["basis_centres"].uniform_(0, 1)
    attributes["basis_log_widths"].uniform_(-3, -1)
    t = 0.42
    sigma = attributes["basis_log_widths"].exp()
    b = torch.exp(-(t - attributes["basis_centres"]) ** 2 / (2 * sigma ** 2))  # [N, B]
    psi = (attributes["basis_weights"] * b[:, None, :]).sum(-1)  # [N, D]
    delta = field(torch.zeros(4, 3), attributes, t)
    torch.testing.assert_close(delta.d_means, psi[:, :3] * field.position_scale())
    torch.testing.assert_close(delta.d_log_scales, psi[:, 3:6])
    torch.testing.assert_close(delta.d_quats, psi[:, 6:10])


def test_gaussian_basis_gradcheck():
    generator = torch.Generator().manual_seed(0)
    field = GaussianBasisField(GaussianBasisConfig(num_basis=4, deform_color=True))
    weights = torch.randn(3, 13, 4, dtype=torch.float64, generator=generator, requires_grad=True)
    centres = torch.rand(3, 4, dtype=torch.float64, generator=generator, requires_grad=True)
    log_widths = (torch.rand(3, 4, dtype=torch.float64, generator=generator) - 2).requires_grad_()

    def channels(w, c, lw):
        return offsets(field(torch.zeros(3, 3, dtype=torch.float64),
                             {"basis_weights": w, "basis_centres": c, "basis_log_widths": lw}, 0.3))

    field.double()
    assert torch.autograd.gradcheck(channels, (weights, centres, log_widths))


def test_gaussian_basis_initial_basis_overlaps():
    field = GaussianBasisConfig(num_basis=16).build()
    attributes = field.per_gaussian_attributes(2)
    centres = attributes["basis_centres"]
    assert torch.allclose(centres[0], torch.linspace(0, 1, 16))
    midway = basis_values(centres, attributes["basis_log_widths"], 0.5 / 15)
    # halfway between the first two centres, both bases are exp(-1/8) with sigma = spacing
    torch.testing.assert_close(midway[0, :2], torch.full((2,), math.exp(-1 / 8)))


def test_per_gaussian_attributes_follow_keep_and_append():
    torch.manual_seed(0)
    field = make_field("gaussian_basis")
    n = 8
    means = random_means(n, torch.Generator().manual_seed(5))
    model = GaussianModel.from_points(means, torch.rand(n, 3), GaussianConfig(),
                                      field.per_gaussian_attributes(n))
    assert set(model.attributes) == set(field.attribute_lrs())
    lrs = {**{k: 1e-3 for k in GEOMETRY_KEYS},
           **{k: initial for k, (initial, _) in field.attribute_lrs().items()}}
    optimizer = torch.optim.Adam([{"name": k, "params": [v], "lr": lrs[k]}
                                  for k, v in model.params.items()])
    target = torch.randn(n, 10)
    for _ in range(3):
        optimizer.zero_grad()
        (offsets(field(model.params["means"], model.attributes, 0.6)) - target).square().sum() \
            .backward()
        optimizer.step()
    before = offsets(field(model.params["means"], model.attributes, 0.6)).detach()
    keep = torch.tensor([True, False, True, True, False, True, True, False])
    keep_gaussians(model, optimizer, keep)
    after_keep = offsets(field(model.params["means"], model.attributes, 0.6)).detach()
    torch.testing.assert_close(after_keep, before[keep])
    new_rows = {k: v[:2].detach().clone() for k, v in model.params.items()}
    append_gaussians(model, optimizer, new_rows)
    after_append = offsets(field(model.params["means"], model.attributes, 0.6))
    torch.testing.assert_close(after_append.detach(), torch.cat([before[keep], before[keep][:2]]))
    optimizer.zero_grad()
    after_append.square().sum().backward()
    optimizer.step()  # the optimiser still holds the attributes
    assert model.params["basis_weights"].grad is not None


@pytest.mark.parametrize("kind", ["hexplane", "gaussian_basis"])
def test_state_dict_round_trip_keeps_bounds_and_output(kind):
    torch.manual_seed(0)
    field = make_field(kind)
    attributes = field.per_gaussian_attributes(5)
    with torch.no_grad():
        for p in field.parameters():
            p.normal_()
        for v in attributes.values():
            v.normal_()
    means = random_means(5, torch.Generator().manual_seed(6))
    config = HexPlaneConfig(**SMALL_HEXPLANE) if kind == "hexplane" else GaussianBasisConfig()
    restored = config.build()
    restored.load_state_dict(field.state_dict())
    torch.testing.assert_close(restored.bounds_hi, field.bounds_hi)
    torch.testing.assert_close(offsets(restored(means, attributes, 0.2)),
                               offsets(field(means, attributes, 0.2)))


def test_bad_bounds_and_configs_are_rejected():
    field = GaussianBasisConfig().build()
    with pytest.raises(ValueError):
        field.set_bounds(torch.ones(3), torch.zeros(3))
    with pytest.raises(ValueError):
        field.set_bounds(torch.zeros(2), torch.ones(2))
    with pytest.raises(SurgsplatError):
        GaussianBasisConfig(num_basis=1).build()
    with pytest.raises(SurgsplatError):
        HexPlaneConfig(mlp_depth=0).build()
