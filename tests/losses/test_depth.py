"""Depth L1, (median-scaled) inverse-depth L1 and scale-invariant log-depth L1 over tissue
pixels with a measured depth."""

from types import SimpleNamespace

import pytest
import torch

from surgsplat.losses.depth import (DepthLoss, DepthLossConfig, depth_l1, inverse_depth_l1,
                                   scale_invariant_depth_l1)


def depths(dtype=torch.float32):
    generator = torch.Generator().manual_seed(0)
    pred = 20 + 30 * torch.rand(6, 7, generator=generator, dtype=dtype)  # millimetres
    gt = 20 + 30 * torch.rand(6, 7, generator=generator, dtype=dtype)
    gt[0, :3] = 0.0  # no measurement
    mask = torch.ones(6, 7, dtype=torch.bool)
    mask[4:, 5:] = False  # tool
    return pred, gt, mask


def test_depth_l1_averages_over_measured_tissue_pixels():
    pred, gt, mask = depths()
    valid = mask & (gt > 0)
    expected = (pred - gt).abs()[valid].mean() / gt[valid].median()
    torch.testing.assert_close(depth_l1(pred, gt, mask), expected)
    assert float(depth_l1(gt, gt, mask)) == 0.0


@pytest.mark.parametrize("loss", [depth_l1, inverse_depth_l1, scale_invariant_depth_l1])
def test_every_form_is_unit_free(loss):
    """The same scene in metres (depths / 1000) gives the same loss as in millimetres, so one
    weight suits both (relative tolerance 1e-5, float32)."""
    pred, gt, mask = depths()
    torch.testing.assert_close(loss(pred / 1000, gt / 1000, mask), loss(pred, gt, mask),
                               rtol=1e-5, atol=0)


def test_inverse_depth_l1_skips_unmeasured_and_undrawn_pixels():
    pred, gt, mask = depths()
    pred[2, 2] = 0.0  # nothing rendered there
    valid = mask & (gt > 0) & (pred > 0)
    expected = gt[valid].median() * (1 / pred[valid] - 1 / gt[valid]).abs().mean()
    torch.testing.assert_close(inverse_depth_l1(pred, gt, mask), expected)
    pred.requires_grad_(True)
    inverse_depth_l1(pred, gt, mask).backward()
    assert torch.isfinite(pred.grad).all()
    assert pred.grad[2, 2] == 0 and pred.grad[0, 0] == 0 and pred.grad[5, 6] == 0


@pytest.mark.parametrize("loss", [depth_l1, inverse_depth_l1, scale_invariant_depth_l1])
def test_excluded_pixels_do_not_change_the_loss(loss):
    pred, gt, mask = depths()
    reference = float(loss(pred, gt, mask))
    pred2 = pred.clone()
    pred2[~mask] = 1000.0
    pred2[0, :3] = 5.0  # where gt = 0
    assert float(loss(pred2, gt, mask)) == reference
    pred2[1, 1] += 1.0
    assert float(loss(pred2, gt, mask)) != reference


@pytest.mark.parametrize("loss", [depth_l1, inverse_depth_l1, scale_invariant_depth_l1])
def test_gradcheck_and_empty_and_shapes(loss):
    pred, gt, mask = depths(torch.float64)
    pred.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda p: loss(p, gt, mask), (pred,))
    assert float(loss(pred.detach(), gt, torch.zeros_like(mask))) == 0.0
    with pytest.raises(ValueError):
        loss(pred, gt[:-1], mask[:-1])
    with pytest.raises(ValueError):
        loss(pred, gt, mask.float())


def test_scale_invariant_form_ignores_the_scale_of_the_measured_depth():
    pred, gt, mask = depths()
    valid = mask & (gt > 0)
    log_ratio = pred[valid].log() - gt[valid].log()
    expected = (log_ratio - log_ratio.median()).abs().mean()
    torch.testing.assert_close(scale_invariant_depth_l1(pred, gt, mask), expected)
    torch.testing.assert_close(scale_invariant_depth_l1(pred, 7.5 * gt, mask), expected)
    assert float(scale_invariant_depth_l1(0.02 * gt, gt, mask)) < 1e-6
    assert float(scale_invariant_depth_l1(pred, gt, mask)) > 0.05


def test_a_frame_without_depth_gives_a_constant_zero():
    """Nothing to compare: the term is 0 and not part of the graph, so the backward does not
    run through the depth map."""
    rendered = torch.rand(4, 5, requires_grad=True)
    context = SimpleNamespace(frame=SimpleNamespace(depth=None),
                              output=SimpleNamespace(depth=rendered))
    term = DepthLoss(DepthLossConfig()).losses(context, frozenset({"depth"}))["depth"]
    assert term.item() == 0.0 and not term.requires_grad


@pytest.mark.parametrize("form, loss", [("l1", depth_l1), ("inverse_l1", inverse_depth_l1),
                                        ("scale_invariant", scale_invariant_depth_l1)])
def test_the_component_keeps_each_frames_median_and_gives_the_functions_value(form, loss):
    """The term of a frame seen again equals the function's, computed afresh (the median of the
    measured depth is kept per frame and size, as it is of the data alone)."""
    pred, gt, mask = depths()
    component = DepthLoss(DepthLossConfig(form=form))
    camera = SimpleNamespace(height=6, width=7)
    frame = SimpleNamespace(index=3, depth=gt, tissue=mask, camera=camera)
    for scale in (1.0, 1.1):  # the same frame at two steps, with two renders
        rendered = (pred * scale).requires_grad_()
        context = SimpleNamespace(frame=frame, output=SimpleNamespace(depth=rendered))
        term = component.losses(context, frozenset({"depth"}))["depth"]
        torch.testing.assert_close(term, loss(rendered, gt, mask), rtol=0, atol=0)
    other = SimpleNamespace(index=4, depth=gt * 2, tissue=mask, camera=camera)
    context = SimpleNamespace(frame=other, output=SimpleNamespace(depth=pred))
    torch.testing.assert_close(component.losses(context, frozenset({"depth"}))["depth"],
                               loss(pred, gt * 2, mask), rtol=0, atol=0)


def test_tool_pixels_count_the_tools_measured_depth_in_the_tissues_unit():
    """With `tool_pixels` an error on the tool pixels enters the term (mean over the field of
    view, divided by the tissue's median depth); without, it does not."""
    gt = torch.full((4, 6), 10.0)
    tool = torch.zeros(4, 6, dtype=torch.bool)
    tool[:, :2] = True
    gt[tool] = 5.0  # the tool, nearer than the tissue
    fov = torch.ones(4, 6, dtype=torch.bool)
    frame = SimpleNamespace(index=0, depth=gt, tissue=fov & ~tool, fov=fov,
                            camera=SimpleNamespace(height=4, width=6))
    rendered = gt.clone()
    rendered[tool] = 6.0  # 1 too deep on 8 of the 24 pixels
    context = SimpleNamespace(frame=frame, output=SimpleNamespace(depth=rendered))
    tissue_only = DepthLoss(DepthLossConfig()).losses(context, frozenset({"depth"}))["depth"]
    counted = DepthLoss(DepthLossConfig(tool_pixels=True)).losses(context,
                                                                 frozenset({"depth"}))["depth"]
    assert tissue_only.item() == 0.0
    torch.testing.assert_close(counted, torch.tensor(8 / 24 / 10.0), rtol=1e-6, atol=0)
