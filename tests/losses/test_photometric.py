"""Masked L1, D-SSIM and the photometric blend: values, masks and gradients."""

import pytest
import torch

from surgsplat.image.ssim import ssim
from surgsplat.losses.photometric import d_ssim, masked_l1, photometric_loss


def images(h: int = 12, w: int = 14, seed: int = 0, dtype=torch.float32):
    generator = torch.Generator().manual_seed(seed)
    pred = torch.rand(h, w, 3, generator=generator, dtype=dtype)
    gt = torch.rand(h, w, 3, generator=generator, dtype=dtype)
    mask = torch.ones(h, w, dtype=torch.bool)
    mask[3:6, 4:7] = False  # a "tool"
    return pred, gt, mask


def test_losses_are_zero_on_identical_images():
    pred, _, mask = images()
    assert float(masked_l1(pred, pred.clone(), mask)) == 0.0
    assert float(d_ssim(pred, pred.clone(), mask)) == pytest.approx(0.0, abs=1e-6)
    assert float(photometric_loss(pred, pred.clone(), mask, 0.2)) == pytest.approx(0.0, abs=1e-6)


def test_masked_l1_is_the_mean_over_masked_pixels_and_channels():
    pred, gt, mask = images()
    expected = (pred - gt).abs()[mask].mean()
    torch.testing.assert_close(masked_l1(pred, gt, mask), expected)


def test_d_ssim_is_one_minus_ssim_of_the_tool_zeroed_images():
    pred, gt, mask = images()
    m = mask[..., None].float()
    torch.testing.assert_close(d_ssim(pred, gt, mask), 1 - ssim(pred * m, gt * m, mask))
    full = torch.ones_like(mask)
    torch.testing.assert_close(d_ssim(pred, gt, full), 1 - ssim(pred, gt))


def test_blend_weights_l1_and_d_ssim():
    pred, gt, mask = images()
    l1, ds = masked_l1(pred, gt, mask), d_ssim(pred, gt, mask)
    torch.testing.assert_close(photometric_loss(pred, gt, mask, 0.2), 0.8 * l1 + 0.2 * ds)
    torch.testing.assert_close(photometric_loss(pred, gt, mask, 0.0), l1)


def test_masked_out_pixels_do_not_change_any_loss():
    pred, gt, mask = images()
    reference = [f(pred, gt, mask) for f in (masked_l1, d_ssim)]
    pred2, gt2 = pred.clone(), gt.clone()
    pred2[~mask] = torch.rand(int((~mask).sum()), 3)
    gt2[4, 5] = torch.tensor([1.0, 0.0, 1.0])  # inside the tool
    changed = [f(pred2, gt2, mask) for f in (masked_l1, d_ssim)]
    for before, after in zip(reference, changed):
        assert float(before) == float(after)
    # ... while changing a counted pixel does change them
    pred2[0, 0] += 0.5
    assert float(masked_l1(pred2, gt2, mask)) != float(reference[0])
    assert float(d_ssim(pred2, gt2, mask)) != float(reference[1])


def test_no_gradient_reaches_masked_out_pixels():
    pred, gt, mask = images()
    pred.requires_grad_(True)
    photometric_loss(pred, gt, mask, 0.2).backward()
    assert torch.count_nonzero(pred.grad[~mask]) == 0
    assert torch.count_nonzero(pred.grad[mask]) > 0


def test_gradcheck_in_float64():
    """Covers both terms of the blend; images barely larger than the SSIM window's padding."""
    pred, gt, mask = images(h=7, w=8, dtype=torch.float64)
    pred.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: photometric_loss(p, gt, mask, 0.5), (pred,))


def test_empty_mask_gives_zero_and_bad_shapes_raise():
    pred, gt, mask = images()
    empty = torch.zeros_like(mask)
    assert float(masked_l1(pred, gt, empty)) == 0.0
    assert float(photometric_loss(pred, gt, empty, 0.2)) == 0.0
    with pytest.raises(ValueError):
        masked_l1(pred, gt[:-1], mask)
    with pytest.raises(ValueError):
        d_ssim(pred, gt, mask.float())


def test_masked_l1_gradient_matches_autograd_of_the_plain_formula():
    """The written-out gradient equals autograd's through |pred - gt| * weights (float64,
    exact to 1e-12), and passes gradcheck; gt requiring a gradient is refused."""
    pred, gt, mask = images(dtype=torch.float64)
    weights = torch.rand(mask.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    pred.requires_grad_()
    masked_l1(pred, gt, mask, weights).backward()
    written = pred.grad.clone()
    pred.grad = None
    count = mask.sum() * 3
    (((pred - gt).abs() * (weights * mask)[..., None]).sum() / count).backward()
    torch.testing.assert_close(written, pred.grad, rtol=0, atol=1e-12)
    assert torch.autograd.gradcheck(lambda p: masked_l1(p, gt, mask, weights), (pred,))
    with pytest.raises(ValueError, match="must not require gradients"):
        masked_l1(pred, gt.clone().requires_grad_(), mask)
