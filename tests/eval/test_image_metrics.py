"""PSNR / SSIM in the "zeroed" (all pixels) and "tissue" (tissue pixels only) conventions."""

import math

import pytest
import torch

from surgsplat.eval.image_metrics import psnr_tissue, psnr_zeroed, ssim_tissue, ssim_zeroed
from surgsplat.image.ssim import ssim


def scene(seed=0):
    """gt, a prediction off by exactly 0.1 on tissue and wildly wrong on the tool, and tissue."""
    gen = torch.Generator().manual_seed(seed)
    gt = torch.rand(32, 40, 3, generator=gen) * 0.8
    tissue = torch.ones(32, 40, dtype=torch.bool)
    tissue[8:20, 5:30] = False  # 300 tool pixels of 1280
    pred = gt + 0.1
    pred[~tissue] = torch.rand(int((~tissue).sum()), 3, generator=gen)
    return pred, gt, tissue


def test_psnr_conventions_on_known_errors():
    pred, gt, tissue = scene()
    share = tissue.float().mean().item()  # 980 / 1280
    assert psnr_tissue(pred, gt, tissue) == pytest.approx(20.0, abs=1e-4)  # MSE 0.01
    assert psnr_zeroed(pred, gt, tissue) == pytest.approx(-10 * math.log10(0.01 * share), abs=1e-4)
    assert psnr_zeroed(pred, gt, tissue) > psnr_tissue(pred, gt, tissue)


def test_identical_tissue_gives_infinite_psnr_and_unit_ssim():
    pred, gt, tissue = scene(seed=1)
    pred = torch.where(tissue[..., None], gt, pred)  # only the tool pixels differ
    assert psnr_zeroed(pred, gt, tissue) == math.inf
    assert psnr_tissue(pred, gt, tissue) == math.inf
    assert ssim_zeroed(pred, gt, tissue) == pytest.approx(1.0, abs=1e-6)
    assert ssim_tissue(pred, gt, tissue) < 1.0  # windows at the tool border see the wrong pixels


def test_ssim_variants_are_the_documented_ssim_calls():
    pred, gt, tissue = scene(seed=2)
    pred, gt = pred.double(), gt.double()
    keep = tissue[..., None].double()
    zeroed = ssim(pred * keep, gt * keep).item()
    assert ssim_zeroed(pred, gt, tissue) == pytest.approx(zeroed, abs=1e-12)
    tissue_only = ssim(pred, gt, mask=tissue).item()
    assert ssim_tissue(pred, gt, tissue) == pytest.approx(tissue_only, abs=1e-12)


def test_rejects_bad_masks():
    pred, gt, tissue = scene()
    with pytest.raises(ValueError, match="bool tissue mask"):
        psnr_tissue(pred, gt, tissue.float())
    with pytest.raises(ValueError, match="no pixel"):
        psnr_zeroed(pred, gt, torch.zeros_like(tissue))
