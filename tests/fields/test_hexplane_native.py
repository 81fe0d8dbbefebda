"""The native HexPlane sampler (csrc/hexplane) against the grid_sample reference: forward values,
gradients of every plane and of the coordinates, border clamping, determinism, input checks."""

import pytest
import torch

from surgsplat.fields.hexplane import HexPlaneConfig, plane_features
from surgsplat.render.native import native_module

needs_native = pytest.mark.skipif(
    native_module() is None or not hasattr(native_module(), "hexplane_forward"),
    reason="native module with the hexplane kernel not built")

FORWARD_ATOL = 2e-5  # features are products of six values in [0.5, 1.5]: up to ~11, float32
GRAD_RTOL = 1e-5  # max abs error relative to the largest reference gradient entry


def make_planes(features: int, resolutions: list[int], time_resolution: int, seed: int):
    """Per scale a spatial [3, C, R, R] and a temporal [3, C, T, R] stack, values in [0.5, 1.5]."""
    generator = torch.Generator().manual_seed(seed)
    spatial = [0.5 + torch.rand(3, features, r, r, generator=generator) for r in resolutions]
    temporal = [0.5 + torch.rand(3, features, time_resolution, r, generator=generator)
                for r in resolutions]
    return spatial, temporal


def make_coords(num: int, resolutions: list[int], seed: int) -> torch.Tensor:
    """Random points in [-1.3, 1.3]^3 (some outside the box), points on the faces and corners of
    [-1, 1]^3 and points on grid nodes of the first scale."""
    generator = torch.Generator().manual_seed(seed)
    inside = torch.rand(num, 3, generator=generator) * 2.6 - 1.3
    corners = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [-1.0, 1.0, 0.3],
                            [0.2, -1.0, 1.0], [1.0, 0.0, -1.0], [-1.5, 2.0, 1.0]])
    nodes = torch.randint(0, resolutions[0], (20, 3), generator=generator)
    on_nodes = nodes / (resolutions[0] - 1) * 2 - 1
    return torch.cat([inside, corners, on_nodes])


def run(coords, time, spatial, temporal, backend, upstream=None):
    """Features [C x scales, N] and, given an upstream gradient, the gradients of the coordinates
    and of every plane stack."""
    coords = coords.clone().requires_grad_(True)
    spatial = [p.clone().requires_grad_(True) for p in spatial]
    temporal = [p.clone().requires_grad_(True) for p in temporal]
    features = plane_features(coords, time, spatial, temporal, backend=backend)
    if upstream is None:
        return features.detach(), None
    grads = torch.autograd.grad((features * upstream).sum(), [coords, *spatial, *temporal])
    return features.detach(), grads


def relative_error(value: torch.Tensor, reference: torch.Tensor) -> float:
    return float((value - reference).abs().max() / reference.abs().max())


CASES = [  # (features, spatial resolution per scale, time resolution)
    (8, [4], 3),
    (16, [5, 9], 7),
    (20, [6, 11], 4),
    (32, [8, 16, 32], 9),
]


@pytest.mark.parametrize("features,resolutions,time_resolution", CASES)
@pytest.mark.parametrize("time", [-1.0, -0.35, 1.0])
def test_forward_matches_reference(native_isa, features, resolutions, time_resolution, time):
    spatial, temporal = make_planes(features, resolutions, time_resolution, seed=0)
    coords = make_coords(500, resolutions, seed=1)
    native, _ = run(coords, time, spatial, temporal, "native")
    reference, _ = run(coords, time, spatial, temporal, "reference")
    assert native.shape == reference.shape == (features * len(resolutions), len(coords))
    assert (native - reference).abs().max() < FORWARD_ATOL


@pytest.mark.parametrize("features,resolutions,time_resolution", CASES)
def test_gradients_match_reference(native_isa, features, resolutions, time_resolution):
    spatial, temporal = make_planes(features, resolutions, time_resolution, seed=2)
    # no points on interior grid nodes: there the coordinate derivative is one-sided and the
    # side depends on the last bit of the unnormalised coordinate
    coords = make_coords(500, resolutions, seed=3)[:-20]
    upstream = torch.randn(features * len(resolutions), len(coords),
                           generator=torch.Generator().manual_seed(4))
    _, native = run(coords, 0.4, spatial, temporal, "native", upstream)
    _, reference = run(coords, 0.4, spatial, temporal, "reference", upstream)
    names = (["coords"] + [f"spatial[{s}]" for s in range(len(spatial))]
             + [f"temporal[{s}]" for s in range(len(temporal))])
    for name, value, expected in zip(names, native, reference):
        assert value.shape == expected.shape, name
        assert relative_error(value, expected) < GRAD_RTOL, name


def test_points_outside_are_clamped_to_the_border(native_isa):
    spatial, temporal = make_planes(8, [5], 4, seed=5)
    inside = torch.tensor([[1.0, -1.0, 0.25], [-1.0, 0.5, 1.0]])
    outside = torch.tensor([[3.0, -7.0, 0.25], [-1.01, 0.5, 40.0]])
    upstream = torch.ones(8, 2)
    at_border, border_grads = run(inside, 0.0, spatial, temporal, "native", upstream)
    beyond, beyond_grads = run(outside, 0.0, spatial, temporal, "native", upstream)
    torch.testing.assert_close(beyond, at_border, rtol=0, atol=0)
    # beyond the border the clamped axes have no gradient; the free axes do
    clamped = torch.tensor([[True, True, False], [True, False, True]])
    assert torch.all(beyond_grads[0][clamped] == 0)
    assert torch.all(beyond_grads[0][~clamped] != 0)
    for value, expected in zip(beyond_grads[1:], border_grads[1:]):
        torch.testing.assert_close(value, expected, rtol=0, atol=0)


def test_backward_is_deterministic(native_isa):
    spatial, temporal = make_planes(32, [16, 32], 9, seed=6)
    coords = make_coords(20_000, [16, 32], seed=7)  # many points per plane node
    upstream = torch.randn(64, len(coords), generator=torch.Generator().manual_seed(8))
    first = run(coords, 0.1, spatial, temporal, "native", upstream)
    second = run(coords, 0.1, spatial, temporal, "native", upstream)
    assert torch.equal(first[0], second[0])
    for a, b in zip(first[1], second[1]):
        assert torch.equal(a, b)


@needs_native
def test_field_uses_the_native_kernel_for_float32():
    torch.manual_seed(0)
    field = HexPlaneConfig(base_resolution=8, multires=(1, 2), max_resolution=16,
                           time_resolution=5, feature_dim=16).build()
    with torch.no_grad():
        for plane in field.time_planes:
            plane.uniform_(0.5, 1.5)
    field.set_bounds(torch.tensor([-2.0, 0.0, 10.0]), torch.tensor([2.0, 3.0, 14.0]))
    means = torch.tensor([-2.0, 0.0, 10.0]) + torch.rand(300, 3) * torch.tensor([4.0, 3.0, 4.0])
    features = field.features(means, 0.6)
    reference = plane_features(field.normalise(means), 0.2, list(field.spatial_planes),
                               list(field.time_planes), backend="reference")
    assert (features - reference).abs().max() < FORWARD_ATOL
    # features is the transpose of the native Function's output
    assert "_NativePlaneFeaturesBackward" in str(features.grad_fn.next_functions)


@needs_native
def test_native_backend_rejects_what_it_cannot_run():
    spatial, temporal = make_planes(8, [4], 3, seed=9)
    coords = make_coords(10, [4], seed=10)
    with pytest.raises(ValueError, match="float32"):
        plane_features(coords.double(), 0.0, [p.double() for p in spatial],
                       [p.double() for p in temporal], backend="native")
    wrong_time = [torch.rand(3, 8, 3, 5)]  # width 5 along x, but the spatial planes have 4
    with pytest.raises(ValueError, match="nodes along axis x"):
        plane_features(coords, 0.0, spatial, wrong_time, backend="native")


def test_auto_backend_falls_back_to_the_reference_for_float64():
    spatial, temporal = make_planes(8, [4], 3, seed=11)
    coords = make_coords(10, [4], seed=12).double()
    spatial, temporal = [p.double() for p in spatial], [p.double() for p in temporal]
    auto = plane_features(coords, 0.5, spatial, temporal)
    reference = plane_features(coords, 0.5, spatial, temporal, backend="reference")
    assert auto.dtype == torch.float64
    torch.testing.assert_close(auto, reference, rtol=0, atol=0)
