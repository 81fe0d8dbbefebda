"""LPIPS: architecture, the distance formula against an independent torchvision-layout AlexNet,
weight discovery, and (when the ImageNet weights are on the machine) real-weight behaviour."""

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from surgsplat.errors import DataError
from surgsplat.eval.lpips import (ALEXNET_ENV, ALEXNET_FILENAME, LINEAR_WEIGHTS, LPIPS, load_lpips,
                                  lpips_distance)


def torchvision_layout_alexnet() -> nn.Sequential:
    """AlexNet's `features` trunk numbered as torchvision numbers it (keys features.0 ...)."""
    torch.manual_seed(0)
    return nn.Sequential(
        nn.Conv2d(3, 64, 11, stride=4, padding=2), nn.ReLU(), nn.MaxPool2d(3, 2),
        nn.Conv2d(64, 192, 5, padding=2), nn.ReLU(), nn.MaxPool2d(3, 2),
        nn.Conv2d(192, 384, 3, padding=1), nn.ReLU(),
        nn.Conv2d(384, 256, 3, padding=1), nn.ReLU(),
        nn.Conv2d(256, 256, 3, padding=1), nn.ReLU(), nn.MaxPool2d(3, 2))


@pytest.fixture
def fake_checkpoint(tmp_path):
    """A torchvision-format AlexNet checkpoint with random weights, and the trunk it holds."""
    trunk = torchvision_layout_alexnet()
    state = {f"features.{key}": value for key, value in trunk.state_dict().items()}
    state["classifier.1.weight"] = torch.zeros(4, 4)  # torchvision files also hold the classifier
    path = tmp_path / ALEXNET_FILENAME
    torch.save(state, path)
    return path, trunk


@pytest.fixture
def no_default_weights(tmp_path, monkeypatch):
    monkeypatch.delenv(ALEXNET_ENV, raising=False)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch-home"))


def random_model() -> LPIPS:
    """LPIPS with seeded random weights, the linear ones made >= 0 as in LPIPS v0.1."""
    torch.manual_seed(1)
    model = LPIPS().eval()
    with torch.no_grad():
        for lin in model.lins:
            lin.weight.abs_()
    return model


def images(seed=0, size=(48, 64)):
    gen = torch.Generator().manual_seed(seed)
    return torch.rand(*size, 3, generator=gen), torch.rand(*size, 3, generator=gen)


def test_feature_shapes_with_random_weights():
    model = LPIPS()
    features = model.backbone(torch.rand(2, 3, 64, 64))
    assert [tuple(f.shape) for f in features] == [
        (2, 64, 15, 15), (2, 192, 7, 7), (2, 384, 3, 3), (2, 256, 3, 3), (2, 256, 3, 3)]
    assert all((f >= 0).all() for f in features)  # taken after the ReLUs
    assert model(torch.rand(2, 3, 64, 64), torch.rand(2, 3, 64, 64)).shape == (2,)
    with pytest.raises(ValueError, match="at least"):
        model(torch.rand(1, 3, 30, 64), torch.rand(1, 3, 30, 64))


def test_identical_images_give_zero_and_different_ones_do_not():
    model = random_model()
    a, b = images()
    assert lpips_distance(model, a, a) == 0.0
    d_ab, d_ba = lpips_distance(model, a, b), lpips_distance(model, b, a)
    assert d_ab > 0
    assert d_ab == pytest.approx(d_ba, rel=1e-5)


def test_shipped_linear_weights():
    state = torch.load(LINEAR_WEIGHTS, weights_only=True)
    assert {k: tuple(v.shape) for k, v in state.items()} == {
        "lin0": (1, 64, 1, 1), "lin1": (1, 192, 1, 1), "lin2": (1, 384, 1, 1),
        "lin3": (1, 256, 1, 1), "lin4": (1, 256, 1, 1)}
    assert all((v >= 0).all() and v.max() > 0.1 for v in state.values())  # v0.1 weights are >= 0
    assert (LINEAR_WEIGHTS.parent / "LICENSE-lpips.txt").is_file()


def test_distance_matches_formula_on_torchvision_trunk(fake_checkpoint):
    path, trunk = fake_checkpoint
    model, reason = load_lpips(path)
    assert reason is None and not model.training
    assert not any(p.requires_grad for p in model.parameters())
    lins = torch.load(LINEAR_WEIGHTS, weights_only=True)
    a, b = images(seed=3)
    tissue = torch.ones(48, 64, dtype=torch.bool)
    tissue[10:30, 20:50] = False

    def features(img):  # [H, W, 3] in [0, 1] -> the five post-ReLU maps of the reference trunk
        x = img.permute(2, 0, 1)[None] * 2 - 1
        x = (x - torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1)) / torch.tensor(
            [0.458, 0.448, 0.450]).view(1, 3, 1, 1)
        out = []
        for index, layer in enumerate(trunk[:12]):  # the final max-pool feeds no LPIPS layer
            x = layer(x)
            if index in (1, 4, 7, 9, 11):
                out.append(x)
        return out

    keep = tissue[..., None].float()
    expected = 0.0
    with torch.no_grad():
        for index, (fa, fb) in enumerate(zip(features(a * keep), features(b * keep))):
            na = fa / (fa.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            nb = fb / (fb.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            expected += F.conv2d((na - nb) ** 2, lins[f"lin{index}"]).mean().item()
    assert lpips_distance(model, a, b, tissue) == pytest.approx(expected, rel=1e-5)
    assert lpips_distance(model, a, b) != pytest.approx(expected, rel=1e-3)


def test_tool_pixels_do_not_count():
    model = random_model()
    a, b = images(seed=4)
    tissue = torch.zeros(48, 64, dtype=torch.bool)
    tissue[:, :32] = True
    b = torch.where(tissue[..., None], a, b)  # differ only on tool pixels
    assert lpips_distance(model, a, b, tissue) == 0.0
    assert lpips_distance(model, a, b) > 0


def test_weight_discovery(fake_checkpoint, no_default_weights, monkeypatch, tmp_path):
    model, reason = load_lpips()
    assert model is None
    assert ALEXNET_FILENAME in reason and str(tmp_path / "torch-home") in reason
    path, _ = fake_checkpoint
    monkeypatch.setenv(ALEXNET_ENV, str(path))
    assert isinstance(load_lpips()[0], LPIPS)
    monkeypatch.delenv(ALEXNET_ENV)
    cache = tmp_path / "torch-home" / "hub" / "checkpoints"
    cache.mkdir(parents=True)
    (cache / ALEXNET_FILENAME).write_bytes(path.read_bytes())
    assert isinstance(load_lpips()[0], LPIPS)


def test_bad_weight_files_raise(tmp_path, no_default_weights, monkeypatch):
    with pytest.raises(DataError, match="not found"):
        load_lpips(tmp_path / "missing.pth")
    monkeypatch.setenv(ALEXNET_ENV, str(tmp_path / "missing.pth"))
    with pytest.raises(DataError, match=ALEXNET_ENV):
        load_lpips()
    garbage = tmp_path / "garbage.pth"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match="cannot be read"):
        load_lpips(garbage)
    wrong = tmp_path / "wrong.pth"
    torch.save({"features.0.weight": torch.zeros(64, 3, 5, 5)}, wrong)
    with pytest.raises(DataError, match="features.0.weight"):
        load_lpips(wrong)


def test_real_imagenet_weights():
    model, reason = load_lpips()
    if model is None:
        pytest.skip(reason)
    gen = torch.Generator().manual_seed(5)
    base = torch.nn.functional.avg_pool2d(torch.rand(1, 3, 96, 128, generator=gen), 5, 1, 2)
    base = base[0].permute(1, 2, 0)
    assert lpips_distance(model, base, base) == 0.0
    noise = torch.randn(base.shape, generator=gen)
    slight = lpips_distance(model, base, (base + 0.02 * noise).clamp(0, 1))
    strong = lpips_distance(model, base, (base + 0.2 * noise).clamp(0, 1))
    assert 0 < slight < strong < 2
