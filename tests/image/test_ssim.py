"""SSIM against a direct SciPy reference, native kernels against the PyTorch composition, masks,
gradients, and a real frame pair."""

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from surgsplat.image.blur import native_blur_module
from surgsplat.image.ssim import ssim, ssim_map, ssim_map_reference

needs_native = pytest.mark.skipif(native_blur_module() is None, reason="native module not built")


def reference_ssim_map(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Wang et al. SSIM per channel; 11x11 Gaussian window (sigma 1.5, radius 5), zero padding."""
    def blur(a):
        return gaussian_filter(a, sigma=1.5, truncate=5 / 1.5, mode="constant", cval=0)

    out = np.empty_like(x)
    for ch in range(x.shape[2]):
        a, b = x[..., ch], y[..., ch]
        mu_a, mu_b = blur(a), blur(b)
        var_a = blur(a * a) - mu_a ** 2
        var_b = blur(b * b) - mu_b ** 2
        cov = blur(a * b) - mu_a * mu_b
        c1, c2 = 0.01 ** 2, 0.03 ** 2
        out[..., ch] = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)
                        / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2)))
    return out


def noisy_pair(height=37, width=45, seed=0):
    rng = np.random.default_rng(seed)
    gt = gaussian_filter(rng.random((height, width, 3)), sigma=(2, 2, 0))
    pred = np.clip(gt + rng.normal(0, 0.05, gt.shape), 0, 1)
    return pred, gt


def test_map_matches_scipy_reference():
    pred, gt = noisy_pair()
    expected = reference_ssim_map(pred, gt)
    got = ssim_map(torch.tensor(pred), torch.tensor(gt))  # float64
    assert got.shape == pred.shape
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-5, rtol=0)
    score = ssim(torch.tensor(pred), torch.tensor(gt)).item()
    assert score == pytest.approx(expected.mean(), abs=1e-5)
    # float32 (training): E[x^2] - E[x]^2 loses digits per pixel, the mean stays within 1e-5
    pred32, gt32 = torch.tensor(pred, dtype=torch.float32), torch.tensor(gt, dtype=torch.float32)
    np.testing.assert_allclose(ssim_map(pred32, gt32).double().numpy(), expected, atol=2e-4, rtol=0)
    assert ssim(pred32, gt32).item() == pytest.approx(expected.mean(), abs=1e-5)


def test_identical_images_score_one_and_noise_lowers_it():
    pred, gt = noisy_pair()
    gt_t = torch.tensor(gt, dtype=torch.float32)
    assert ssim(gt_t, gt_t).item() == pytest.approx(1.0, abs=1e-6)
    assert ssim(torch.tensor(pred, dtype=torch.float32), gt_t).item() < 0.95


def test_mask_averages_the_map_over_selected_pixels():
    pred, gt = noisy_pair(seed=1)
    mask = np.zeros(gt.shape[:2], dtype=bool)
    mask[5:20, 10:40] = True
    expected = reference_ssim_map(pred, gt)[mask].mean()
    got = ssim(torch.tensor(pred), torch.tensor(gt), mask=torch.tensor(mask)).item()
    assert got == pytest.approx(expected, abs=1e-5)
    with pytest.raises(ValueError, match="no pixel"):
        ssim(torch.tensor(pred), torch.tensor(gt), mask=torch.zeros(mask.shape, dtype=torch.bool))


@pytest.mark.parametrize("height,width", [(1, 1), (7, 5), (3, 40)])
def test_any_size_matches_scipy_reference(height, width):
    # zero padding: images smaller than the window are fine, in both implementations
    pred, gt = noisy_pair(height, width, seed=3)
    expected = reference_ssim_map(pred, gt)
    got = ssim_map(torch.tensor(pred), torch.tensor(gt))
    np.testing.assert_allclose(got.numpy(), expected, atol=1e-5, rtol=0)
    got32 = ssim_map(torch.tensor(pred, dtype=torch.float32), torch.tensor(gt, dtype=torch.float32))
    np.testing.assert_allclose(got32.double().numpy(), expected, atol=2e-4, rtol=0)


def test_rejects_mismatched_images():
    with pytest.raises(ValueError, match="one shape"):
        ssim(torch.zeros(10, 10, 3), torch.zeros(10, 11, 3))
    with pytest.raises(ValueError, match="one shape"):
        ssim(torch.zeros(10, 10), torch.zeros(10, 10))


def test_differentiable_gradcheck():
    pred, gt = noisy_pair(height=6, width=7, seed=2)
    pred_t = torch.tensor(pred[..., :1], requires_grad=True)
    gt_t = torch.tensor(gt[..., :1], requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: ssim(a, b), (pred_t, gt_t), eps=1e-6, atol=1e-6)
    mask = torch.zeros(6, 7, dtype=torch.bool)
    mask[1:4, 2:6] = True
    assert torch.autograd.gradcheck(lambda a: ssim(a, gt_t.detach(), mask), (pred_t,), eps=1e-6,
                                    atol=1e-6)


@pytest.mark.parametrize("height,width,channels", [(1, 1, 1), (7, 5, 3), (37, 45, 3), (20, 70, 1)])
def test_native_matches_reference_map_and_gradients(native_isa, height, width, channels):
    generator = torch.Generator().manual_seed(4)
    gt = torch.rand(height, width, channels, generator=generator)
    pred = (gt + 0.1 * torch.randn(gt.shape, generator=generator)).clamp(0, 1)
    upstream = torch.randn(gt.shape, generator=generator)
    inputs = [t.clone().requires_grad_() for t in (pred, gt)]  # float32: native kernels
    reference = [t.double().requires_grad_() for t in (pred, gt)]  # float64: PyTorch ops
    values, expected = ssim_map(*inputs), ssim_map_reference(*reference)
    assert values.shape == (height, width, channels) and values.dtype == torch.float32
    assert type(values.grad_fn).__name__ == "_NativeSSIMMapBackward"
    assert (values.double() - expected).abs().max().item() < 1e-5
    (values * upstream).sum().backward()
    (expected * upstream.double()).sum().backward()
    for got, want in zip(inputs, reference):
        scale = want.grad.abs().max().item()
        assert (got.grad.double() - want.grad).abs().max().item() < 1e-5 * max(scale, 1.0)


@pytest.mark.parametrize("zero_unmasked", [False, True])
def test_native_backward_computes_only_the_gradients_asked_for(native_isa, zero_unmasked):
    """One image without requires_grad gets no gradient; the other's is the same as when both
    are asked for (the kernel skips the unwanted image's chain rule)."""
    generator = torch.Generator().manual_seed(9)
    gt = torch.rand(23, 41, 3, generator=generator)
    pred = (gt + 0.1 * torch.randn(gt.shape, generator=generator)).clamp(0, 1)
    mask = torch.rand(23, 41, generator=generator) > 0.3

    def gradients(wanted: tuple[bool, bool]) -> list:
        images = [t.clone().requires_grad_(w) for t, w in zip((pred, gt), wanted)]
        ssim(*images, mask, zero_unmasked=zero_unmasked).backward()
        return [image.grad for image in images]

    both = gradients((True, True))
    assert all(g is not None and g.abs().max() > 0 for g in both)
    only_pred, only_gt = gradients((True, False)), gradients((False, True))
    assert only_pred[1] is None and torch.equal(only_pred[0], both[0])
    assert only_gt[0] is None and torch.equal(only_gt[1], both[1])


@pytest.mark.parametrize("masked", [False, True])
def test_native_score_matches_reference_value_and_gradients(native_isa, masked):
    # the native score sums the (masked) map inside the kernel; the reference takes its mean
    pred, gt = noisy_pair(seed=6)
    mask = np.ones(gt.shape[:2], dtype=bool)
    if masked:
        mask[5:20, 10:40] = False
    mask_t = torch.tensor(mask) if masked else None
    inputs = [torch.tensor(a, dtype=torch.float32, requires_grad=True) for a in (pred, gt)]
    reference = [torch.tensor(a, requires_grad=True) for a in (pred, gt)]
    score = ssim(*inputs, mask=mask_t)
    assert type(score.grad_fn.next_functions[0][0]).__name__ == "_NativeSSIMScoreBackward"
    values = ssim_map_reference(*reference)
    expected = values[torch.tensor(mask)].mean()
    assert score.item() == pytest.approx(expected.item(), abs=1e-5)
    (3.0 * score).backward()
    (3.0 * expected).backward()
    for got, want in zip(inputs, reference):
        assert (got.grad.double() - want.grad).abs().max().item() < 1e-6
        assert want.grad.abs().max().item() > 1e-4  # not vacuous


def test_zero_unmasked_native_matches_masked_images(native_isa):
    # zero_unmasked masks both images inside the kernel: the same score and gradients (float64
    # reference, 1e-5 and 1e-6) as the reference SSIM of the images multiplied by the mask, and
    # no gradient reaches the unmasked pixels
    pred, gt = noisy_pair(seed=7)
    mask = np.ones(gt.shape[:2], dtype=bool)
    mask[8:25, 5:30] = False
    mask_t = torch.tensor(mask)
    inputs = [torch.tensor(a, dtype=torch.float32, requires_grad=True) for a in (pred, gt)]
    reference = [torch.tensor(a, requires_grad=True) for a in (pred, gt)]
    score = ssim(*inputs, mask=mask_t, zero_unmasked=True)
    assert type(score.grad_fn.next_functions[0][0]).__name__ == "_NativeSSIMScoreBackward"
    weights = mask_t.to(torch.float64).unsqueeze(-1)
    values = ssim_map_reference(reference[0] * weights, reference[1] * weights)
    expected = values[mask_t].mean()
    assert score.item() == pytest.approx(expected.item(), abs=1e-5)
    assert abs(score.item() - ssim(*[t.detach() for t in inputs], mask=mask_t).item()) > 1e-3
    (2.0 * score).backward()
    (2.0 * expected).backward()
    for got, want in zip(inputs, reference):
        assert (got.grad.double() - want.grad).abs().max().item() < 1e-6
        assert got.grad[~mask_t].abs().max().item() == 0.0
        assert want.grad.abs().max().item() > 1e-4
    with pytest.raises(ValueError, match="needs a mask"):
        ssim(*inputs, zero_unmasked=True)

def test_native_gradient_only_for_inputs_that_need_it(native_isa):
    pred, gt = noisy_pair(seed=5)
    pred_t = torch.tensor(pred, dtype=torch.float32, requires_grad=True)
    gt_t = torch.tensor(gt, dtype=torch.float32)
    ssim(pred_t, gt_t).backward()
    assert gt_t.grad is None and pred_t.grad is not None
    assert pred_t.grad.abs().max().item() > 0


def test_real_frame_pair_matches_reference(shared_data):
    clip = shared_data / "cholecseg8k-clip"
    a = iio.imread(clip / "frame_561_endo.png")[..., :3].astype(np.float64) / 255
    b = iio.imread(clip / "frame_562_endo.png")[..., :3].astype(np.float64) / 255
    got = ssim(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32)).item()
    expected = reference_ssim_map(a, b).mean()
    assert got == pytest.approx(expected, abs=1e-5)
    assert 0.3 < got < 1.0  # consecutive frames of a moving camera: similar, not identical
