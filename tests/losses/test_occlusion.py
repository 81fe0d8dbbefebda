"""Endo-GSG's occlusion importance map (Eq. 11) and the losses it weights (Eq. 12)."""

from types import SimpleNamespace

import pytest
import torch

from surgsplat.losses.depth import depth_l1
from surgsplat.losses.occlusion import OcclusionImportance, occlusion_frequency
from surgsplat.losses.photometric import masked_l1


def frames_with_tools():
    """Three 4x4 frames: pixel (0, 0) is tool in all three, (0, 1) in one, the rest never."""
    masks = [torch.zeros(4, 4, dtype=torch.bool) for _ in range(3)]
    for mask in masks:
        mask[0, 0] = True
    masks[0][0, 1] = True
    return [SimpleNamespace(tool=mask, tissue=~mask) for mask in masks]


def test_frequency_is_the_mask_sum_over_its_frobenius_norm():
    frequency = occlusion_frequency([frame.tool for frame in frames_with_tools()])
    norm = (3 ** 2 + 1 ** 2) ** 0.5
    assert float(frequency[0, 0]) == pytest.approx(3 / norm)
    assert float(frequency[0, 1]) == pytest.approx(1 / norm)
    assert float(frequency[3, 3]) == 0.0
    assert torch.equal(occlusion_frequency([torch.zeros(2, 2, dtype=torch.bool)]),
                       torch.zeros(2, 2))


def test_importance_is_zero_on_the_frames_tool_and_grows_with_how_often_tissue_is_hidden():
    frames = frames_with_tools()
    importance = OcclusionImportance(gamma=10.0)
    importance.observe(frames)
    weights = importance.weights(frames[1])  # frame 1: only (0, 0) is tool
    assert float(weights[0, 0]) == 0.0
    # V on tissue: 1 + 10 / sqrt(10) at (0, 1), 1 on the 14 others; normalised by their mean
    mean = (1 + 10 / 10 ** 0.5 + 14) / 15
    assert float(weights[0, 1]) == pytest.approx((1 + 10 / 10 ** 0.5) / mean, rel=1e-6)
    assert float(weights[3, 3]) == pytest.approx(1 / mean, rel=1e-6)
    with pytest.raises(ValueError):
        OcclusionImportance(gamma=-1.0)


def test_weighted_losses_multiply_each_pixels_error():
    mask = torch.ones(2, 2, dtype=torch.bool)
    weights = torch.tensor([[1.0, 3.0], [1.0, 1.0]])
    pred, gt = torch.zeros(2, 2, 3), torch.zeros(2, 2, 3)
    pred[0, 1] = 1.0  # the only error, on the pixel weighted 3
    assert float(masked_l1(pred, gt, mask, weights)) == pytest.approx(3 * 3 / (4 * 3))
    depth, truth = torch.full((2, 2), 5.0), torch.full((2, 2), 5.0)
    depth[0, 1] = 7.0
    # depth L1 is relative: divided by the median measured depth, 5
    assert float(depth_l1(depth, truth, mask, weights)) == pytest.approx(3 * 2 / 4 / 5)
    assert float(depth_l1(depth, truth, mask)) == pytest.approx(2 / 4 / 5)


@pytest.mark.parametrize("gamma", [0.0, 10.0, 1000.0])
def test_importance_re_weights_tissue_pixels_without_rescaling_the_loss(gamma):
    """Mean of the map over each frame's tissue pixels is 1 (tolerance 1e-6), so a uniform error
    gives the same weighted loss as the unweighted one, whatever gamma."""
    frames = frames_with_tools()
    importance = OcclusionImportance(gamma=gamma)
    importance.observe(frames)
    for frame in frames:
        weights = importance.weights(frame)
        assert float(weights[frame.tissue].mean()) == pytest.approx(1.0, abs=1e-6)
        pred, gt = torch.full((4, 4, 3), 0.5), torch.zeros(4, 4, 3)
        assert float(masked_l1(pred, gt, frame.tissue, weights)) == pytest.approx(
            float(masked_l1(pred, gt, frame.tissue)), abs=1e-6)
    no_tissue = SimpleNamespace(tool=torch.ones(4, 4, dtype=torch.bool),
                                tissue=torch.zeros(4, 4, dtype=torch.bool))
    assert torch.equal(importance.weights(no_tissue), torch.zeros(4, 4))


def test_the_map_is_restored_from_its_loss_components_state():
    """What `setup` computed must come back from a checkpoint: a resumed run's fresh component
    has seen no frame (issue 30, class 6)."""
    from surgsplat.losses.photometric import PhotometricConfig

    frames = frames_with_tools()
    trained = PhotometricConfig(occlusion_gamma=10.0).build()
    trained.importance.observe(frames)
    resumed = PhotometricConfig(occlusion_gamma=10.0).build()
    resumed.load_state_dict(trained.state_dict())
    assert torch.equal(resumed.importance.weights(frames[1]), trained.importance.weights(frames[1]))
    without_map = PhotometricConfig(occlusion_gamma=10.0).build()
    without_map.load_state_dict({})  # a checkpoint from before the map was kept loads (eval)
    off = PhotometricConfig(occlusion_gamma=0.0).build()
    off.importance.observe(frames)
    assert off.state_dict() == {}  # gamma 0: no map, the weights are the tissue mask
    assert torch.equal(off.importance.weights(frames[1]), frames[1].tissue.float())
