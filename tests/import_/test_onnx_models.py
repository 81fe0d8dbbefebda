"""ONNX tool segmenters and depth networks (`surgsplat import --tool-segmenter MODEL.onnx`,
`--depth MODEL.onnx`): tiny PyTorch networks exported with `torch.onnx.export` into tmp_path,
whose outputs are known, checked through the whole path: preprocessing (colour order, mean and
std, resizing), batching, resizing back, the threshold, the depth's scale, and the one-line
errors for models outside the contract.

Tolerances: ONNX Runtime against the exporting network, 1e-6 on outputs in 0..1; a tool mask
may differ from the network's own only where its probability is within 1e-4 of the threshold;
stored depth within half a 16-bit step (+ 1e-4) of the network's, rescaled; a resize round trip
of a smooth frame within 0.02 (0.03 for the odd sizes) of it, four pixels in from the border."""

import json
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from torch import nn

from surgsplat.data.importer import NETWORK_DEPTH_UNIT, ImportConfig, import_scene
from surgsplat.data.layout import natural_key
from surgsplat.data.learned_priors import (DepthNetworkConfig, ToolSegmenterConfig,
                                           model_tool_masks, network_depth)
from surgsplat.data.onnx_models import IMAGENET_MEAN, IMAGENET_STD, ModelInput, OnnxModel
from surgsplat.data.scene import load_scene
from surgsplat.errors import DataError, SurgsplatError
from surgsplat.losses.depth import scale_invariant_depth_l1

from .conftest import HEIGHT, WIDTH

pytest.importorskip("onnxruntime")

MEAN = torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1)
STD = torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)


def export(net: nn.Module, path: Path, shape: tuple[int, ...] = (1, 3, HEIGHT, WIDTH),
           free: tuple[int, ...] = (0,)) -> Path:
    """`net` as an ONNX file at `path`, its input of `shape` with the axes `free` dynamic."""
    inputs = tuple(torch.zeros(shape) for _ in range(getattr(net, "inputs", 1)))
    names = [f"x{i}" for i in range(len(inputs))]
    axes = {name: {axis: f"d{axis}" for axis in free} for name in names}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(net.eval(), inputs, str(path), dynamo=False, input_names=names,
                          output_names=["y"], dynamic_axes=axes)
    return path


class Red(nn.Module):
    """The red channel as the model saw it, in 0..1: (x_R * std_R + mean_R), averaged over
    `stride` x `stride` cells (a stride-s head)."""

    def __init__(self, stride: int = 1):
        super().__init__()
        self.stride = stride

    def forward(self, x):
        red = x[:, :1] * STD[:, :1] + MEAN[:, :1]
        return nn.functional.avg_pool2d(red, self.stride) if self.stride > 1 else red


class Convs(nn.Module):
    """Two seeded 3x3 convolutions: a small network with outputs of both signs; `positive`
    makes them positive (softplus + 0.05), as an inverse depth."""

    def __init__(self, seed: int, positive: bool = False):
        super().__init__()
        torch.manual_seed(seed)
        self.body = nn.Sequential(nn.Conv2d(3, 6, 3, padding=1), nn.ReLU(),
                                  nn.Conv2d(6, 1, 3, padding=1))
        self.positive = positive

    def forward(self, x):
        y = self.body(x)
        return nn.functional.softplus(y) + 0.05 if self.positive else y


class Raw(nn.Module):
    """A network of another shape: `fn(x)` of its inputs."""

    def __init__(self, fn, inputs: int = 1):
        super().__init__()
        self.fn, self.inputs = fn, inputs

    def forward(self, *x):
        return self.fn(*x)


def torch_output(net: nn.Module, frame: np.ndarray) -> np.ndarray:
    """The exporting network's own output [h, w] on a uint8 RGB frame, preprocessed here with
    torch as the contract states (RGB, pixel / 255, ImageNet mean and std, NCHW)."""
    x = torch.from_numpy(frame).permute(2, 0, 1)[None].float() / 255
    with torch.no_grad():
        return net.eval()((x - MEAN) / STD)[0, 0].numpy()


def gradient_frame(seed: int = 0) -> np.ndarray:
    """uint8 RGB [H, W, 3]: red rising to the right and down, green constant, blue falling,
    plus a little noise; smooth enough to survive a resize round trip."""
    ys, xs = np.mgrid[0:HEIGHT, 0:WIDTH]
    noise = np.random.default_rng(seed).normal(0, 1, (HEIGHT, WIDTH))
    red = 20 + 200 * xs / WIDTH + 30 * ys / HEIGHT + noise
    return np.clip(np.stack([red, np.full_like(red, 90), 240 - red], -1), 0, 255).astype(np.uint8)


def test_colour_order_and_normalisation_reach_the_model_as_stated(tmp_path: Path):
    model = OnnxModel(export(Red(), tmp_path / "red.onnx"), ModelInput(), (HEIGHT, WIDTH))
    frame = gradient_frame()
    (output,) = model.run([frame])
    np.testing.assert_allclose(output, frame[..., 0] / 255.0, atol=1e-6)  # red, not blue
    zero_one = ModelInput(mean=(0.0, 0.0, 0.0), std=(1.0, 1.0, 1.0))
    (shifted,) = OnnxModel(model.path, zero_one, (HEIGHT, WIDTH)).run([frame])
    # The model undoes ImageNet's normalisation: fed 0..1 values, it sees them so transformed.
    np.testing.assert_allclose(shifted, frame[..., 0] / 255.0 * IMAGENET_STD[0]
                               + IMAGENET_MEAN[0], atol=1e-6)


def test_input_is_resized_to_the_model_and_the_output_back_to_the_frame(tmp_path: Path):
    frame = gradient_frame()
    fixed = export(Red(stride=2), tmp_path / "fixed.onnx", (1, 3, 32, 48))
    model = OnnxModel(fixed, ModelInput(), (HEIGHT, WIDTH))
    assert model.input_size == (32, 48)
    (output,) = model.run([frame])  # 96x64 -> 48x32 in, 24x16 out -> 96x64
    assert output.shape == (HEIGHT, WIDTH)
    error = np.abs(output - frame[..., 0] / 255.0)
    assert error[4:-4, 4:-4].max() < 0.02 and error.mean() < 0.01  # no flip, shift or transpose
    free = export(Red(), tmp_path / "free.onnx", free=(0, 2, 3))
    for fit, size in ((ModelInput(short_side=40, multiple=8), (40, 64)),
                      (ModelInput(size=(50, 30)), (30, 50)), (ModelInput(multiple=14), (70, 98))):
        model = OnnxModel(free, fit, (HEIGHT, WIDTH))
        assert model.input_size == size
        (output,) = model.run([frame])
        assert np.abs(output - frame[..., 0] / 255.0)[4:-4, 4:-4].max() < 0.03


def test_frames_go_through_in_batches(tmp_path: Path):
    frames = [gradient_frame(seed) for seed in range(7)]
    expected = [frame[..., 0] / 255.0 for frame in frames]
    pair = (2, 3, HEIGHT, WIDTH)  # a model whose batch is fixed at 2: the last one is filled up
    cases = ((export(Red(), tmp_path / "free.onnx"), 3, [3, 6, 7]),
             (export(Red(), tmp_path / "two.onnx", pair, free=()), 5, [2, 4, 6, 7]),
             (export(Red(), tmp_path / "one.onnx", free=()), 3, list(range(1, 8))))
    for path, batch, calls in cases:
        model = OnnxModel(path, ModelInput(batch=batch), (HEIGHT, WIDTH))
        seen: list[int] = []
        outputs = list(model.run(frames, seen.append))
        assert seen == calls, path.name
        for output, truth in zip(outputs, expected, strict=True):
            np.testing.assert_allclose(output, truth, atol=1e-6)


def test_threshold_of_a_probability_output_inside_the_field_of_view(tmp_path: Path):
    model = OnnxModel(export(Red(), tmp_path / "red.onnx"), ModelInput(), (HEIGHT, WIDTH))
    frame = gradient_frame()
    fov = np.zeros((HEIGHT, WIDTH), bool)
    fov[5:-5, 5:-5] = True
    for threshold in (0.3, 0.5, 0.7):
        config = ToolSegmenterConfig(output="probability", threshold=threshold)
        (mask,) = model_tool_masks(model, [frame], fov, config)
        np.testing.assert_array_equal(mask, (frame[..., 0] / 255.0 >= threshold) & fov)
    # logits: probability = sigmoid(output), so the red share r is tool where sigmoid(r) >= t.
    (mask,) = model_tool_masks(model, [frame], None, ToolSegmenterConfig(threshold=0.6))
    np.testing.assert_array_equal(mask, frame[..., 0] / 255.0 >= np.log(0.6 / 0.4))


def test_network_depth_scale_and_unknown_pixels():
    inverse = np.array([[1.0, 2.0, 4.0], [0.5, -1.0, np.inf], [np.nan, 0.0, 1.0]], np.float32)
    exclude = np.zeros(inverse.shape, bool)
    exclude[0, 0] = True
    depth = network_depth(inverse, exclude, DepthNetworkConfig(median_depth=10.0))
    known = np.array([[0, 1, 1], [1, 0, 0], [0, 0, 1]], bool)
    np.testing.assert_array_equal(depth > 0, known)  # excluded, not positive, not finite: 0
    np.testing.assert_allclose(np.median(depth[known]), 10.0)
    product = depth[known] * inverse[known]
    np.testing.assert_allclose(product, product[0], rtol=1e-6)  # depth proportional to 1/x
    direct = network_depth(inverse, None, DepthNetworkConfig(output="depth", median_depth=10.0))
    np.testing.assert_allclose(direct[direct > 0] / inverse[direct > 0], 10.0)
    assert not network_depth(-np.abs(inverse), None, DepthNetworkConfig()).any()


def scene_images(scene: Path) -> list[np.ndarray]:
    """The uint8 RGB frames an import wrote."""
    files = sorted((scene / "images").glob("*.png"), key=natural_key)
    return [cv2.imread(str(path))[..., ::-1].copy() for path in files]


def test_import_masks_and_depth_equal_the_exporting_networks_outputs(video: Path, tmp_path: Path):
    segmenter, depth_net = Convs(seed=1), Convs(seed=2, positive=True)
    config = ImportConfig(tool_segmenter=export(segmenter, tmp_path / "seg.onnx", free=(0, 2, 3)),
                          depth=str(export(depth_net, tmp_path / "depth.onnx")),
                          segmenter=ToolSegmenterConfig(input=ModelInput(batch=3)))
    progress: list[tuple[str, int, int]] = []
    out = import_scene(video, tmp_path / "scene", config,
                       lambda *call: progress.append(call))
    assert [call for call in progress if call[0] == "tool segmenter"] == [
        ("tool segmenter", done, 10) for done in (3, 6, 9, 10)]  # batches of 3
    assert ("depth network", 10, 10) in progress
    scene = load_scene(out)
    assert scene.has_masks and scene.has_depth and scene.depth_unit == NETWORK_DEPTH_UNIT
    meta = json.loads((out / "scene.json").read_text())
    step = meta["depth_scale"]  # 16-bit storage: 4 x median depth / 65535 per step
    extra = meta["extra"]
    assert extra["masks"]["segmenter"] == "onnx" and extra["masks"]["input_size_wh"] == [96, 64]
    assert extra["depth"]["source"] == "onnx" and "scale_invariant" in extra["depth"]["scale"]
    tool_pixels = 0
    for frame, image in zip(scene.frames, scene_images(out), strict=True):
        fov, tool = frame.fov.numpy(), frame.tool.numpy()
        probability = 1 / (1 + np.exp(-torch_output(segmenter, image)))
        expected = (probability >= 0.5) & fov
        differ = tool != expected
        assert np.all(np.abs(probability[differ] - 0.5) < 1e-4)  # only float rounding at 0.5
        tool_pixels += tool.sum()
        inverse = torch_output(depth_net, image)
        keep = fov & ~tool
        truth = np.where(keep, 1 / inverse, 0.0)
        truth *= 50.0 / np.median(truth[keep])
        np.testing.assert_allclose(frame.depth.numpy(), truth, atol=step / 2 + 1e-4)
        # The training form: blind to the scale, the stored depth is the true relative depth.
        loss = scale_invariant_depth_l1(torch.from_numpy(truth * 7.3).float(), frame.depth,
                                        torch.from_numpy(keep))
        assert float(loss) < 1e-4
    inside = sum(frame.fov.numpy().sum() for frame in scene.frames)
    assert 0.05 < tool_pixels / inside < 0.95  # the network marks some tool, not all


@pytest.mark.parametrize("net, shape, free, message", [
    (Raw(lambda x: x[:, :1]), (1, 1, HEIGHT, WIDTH), (0,),
     r"takes tensor\(float\) input \[\?, 1, 64, 96\]; expected float32 \[N, 3, h, w\]"),
    (Raw(lambda x, y: x[:, :1] + y[:, :1], inputs=2), (1, 3, HEIGHT, WIDTH), (0,),
     "has 2 inputs and 1 outputs; expected one input"),
    (Raw(lambda x: x * 2), (1, 3, HEIGHT, WIDTH), (0,),
     r"gives output \[\?, 3, 64, 96\]; expected one map per frame"),
    (Raw(lambda x: x.mean((2, 3))), (1, 3, HEIGHT, WIDTH), (0,),
     r"gives output \[\?, 3\]; expected one map per frame"),
    (Raw(lambda x: x[:, :1].mean(3, keepdim=True)), (1, 3, HEIGHT, WIDTH), (0,),
     "gives a 1x64 .* output for a 96x64 input: it cannot be resized back"),
    (Raw(lambda x: x[:, :1].mean(3, keepdim=True)), (1, 3, HEIGHT, WIDTH), (0, 2, 3),
     "gives a 1x64 .* output for a 96x64 input: it cannot be resized back"),
])
def test_models_outside_the_contract_are_one_clear_error(tmp_path, net, shape, free, message):
    path = export(net, tmp_path / "model.onnx", shape, free)
    with pytest.raises(DataError, match=message) as error:
        list(OnnxModel(path, ModelInput(), (HEIGHT, WIDTH)).run([gradient_frame()]))
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


def test_files_and_sizes_outside_the_contract_are_one_clear_error(tmp_path: Path):
    text = tmp_path / "notes.onnx"
    text.write_text("not a model\n")
    with pytest.raises(DataError, match="notes.onnx: is not an ONNX model that ONNX Runtime can"):
        OnnxModel(text, ModelInput(), (HEIGHT, WIDTH))
    with pytest.raises(DataError, match="missing.onnx: does not exist"):
        OnnxModel(tmp_path / "missing.onnx", ModelInput(), (HEIGHT, WIDTH))
    fixed = export(Red(), tmp_path / "fixed.onnx", (1, 3, 32, 48))
    with pytest.raises(DataError, match=r"takes input \[\?, 3, 32, 48\], not the 60x40 \(WxH\)"):
        OnnxModel(fixed, ModelInput(short_side=40), (HEIGHT, WIDTH))


def test_missing_onnxruntime_says_how_to_install_it(tmp_path: Path, monkeypatch):
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import fails as if not installed
    with pytest.raises(SurgsplatError, match=r"pip install 'surgsplat\[onnx\]'"):
        OnnxModel(tmp_path / "model.onnx", ModelInput(), (HEIGHT, WIDTH))


def test_import_options_are_checked(video: Path, tmp_path: Path):
    cases = ((ImportConfig(tool_segmenter=video, auto_tool_masks=True),
              "give one source of tool masks, not --auto-tool-masks and --tool-segmenter"),
             (ImportConfig(tool_segmenter=video, segmenter=ToolSegmenterConfig(threshold=1.0)),
              r"threshold must be in \(0, 1\)"),
             (ImportConfig(depth="depth.onnx", depth_network=DepthNetworkConfig(output="disp")),
              "output is one of inverse_depth, depth"),
             (ImportConfig(depth="depth.onnx",
                           depth_network=DepthNetworkConfig(ModelInput(std=(1.0, 0.0, 1.0)))),
              "std positive"),
             (ImportConfig(depth="sfm"), "unknown --depth 'sfm'.* or a model file"))
    for config, message in cases:
        with pytest.raises(SurgsplatError, match=message):
            import_scene(video, tmp_path / "scene", config)
    assert not (tmp_path / "scene").exists()


@pytest.mark.slow
def test_cli_imports_with_both_models_and_refuses_a_bad_file_in_one_line(
        video: Path, tmp_path: Path, cli, one_error_line):
    segmenter = export(Convs(seed=1), tmp_path / "seg.onnx")
    depth = export(Convs(seed=2, positive=True), tmp_path / "depth.onnx", free=(0, 2, 3))
    result = cli("import", str(video), "--out", str(tmp_path / "s"), "--tool-segmenter",
                 str(segmenter), "--tool-segmenter-threshold", "0.4", "--depth", str(depth),
                 "--depth-model-input", "32", "--depth-model-multiple", "8")
    assert result.returncode == 0, result.stderr
    assert "ONNX segmenter" in result.stdout and "onnx prior" in result.stdout
    extra = json.loads((tmp_path / "s" / "scene.json").read_text())["extra"]
    assert extra["masks"]["config"]["threshold"] == 0.4
    assert extra["depth"]["input_size_wh"] == [48, 32]
    (tmp_path / "bad.onnx").write_bytes(b"\x00\x01 not protobuf")
    result = cli("import", str(video), "--out", str(tmp_path / "t"), "--depth",
                 str(tmp_path / "bad.onnx"))
    assert "bad.onnx: is not an ONNX model" in one_error_line(result)
    assert not (tmp_path / "t").exists()
    usage = cli("import", "--help").stdout
    assert "NCHW" in usage and "probability" in usage and "inverse_depth" in usage
