"""SSIM against a direct SciPy reference, masks, gradients, and a real frame pair."""

import imageio.v3 as iio
import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter

from surgsplat.eval.ssim import ssim, ssim_map


def reference_ssim_map(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Wang et al. SSIM per channel; 11x11 Gaussian window (sigma 1.5, radius 5), mirror borders."""
    def blur(a):
        return gaussian_filter(a, sigma=1.5, truncate=5 / 1.5, mode="mirror")

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


def test_rejects_mismatched_or_tiny_images():
    with pytest.raises(ValueError, match="one shape"):
        ssim(torch.zeros(10, 10, 3), torch.zeros(10, 11, 3))
    with pytest.raises(ValueError, match="too small"):
        ssim(torch.zeros(5, 10, 3), torch.zeros(5, 10, 3))


def test_differentiable_gradcheck():
    pred, gt = noisy_pair(height=6, width=7, seed=2)
    pred_t = torch.tensor(pred[..., :1], requires_grad=True)
    gt_t = torch.tensor(gt[..., :1])
    assert torch.autograd.gradcheck(lambda a: ssim(a, gt_t), (pred_t,), eps=1e-6, atol=1e-6)


def test_real_frame_pair_matches_reference(shared_data):
    clip = shared_data / "cholecseg8k-clip"
    a = iio.imread(clip / "frame_561_endo.png")[..., :3].astype(np.float64) / 255
    b = iio.imread(clip / "frame_562_endo.png")[..., :3].astype(np.float64) / 255
    got = ssim(torch.tensor(a, dtype=torch.float32), torch.tensor(b, dtype=torch.float32)).item()
    expected = reference_ssim_map(a, b).mean()
    assert got == pytest.approx(expected, abs=1e-5)
    assert 0.3 < got < 1.0  # consecutive frames of a moving camera: similar, not identical
