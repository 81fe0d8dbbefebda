"""ONNX models through `surgsplat import`: seconds per 854x480 frame of a ~1M-parameter
segmentation network exported to ONNX (issue 31's target: <= 0.1 s on 2 cores).

    python benchmarks/bench_onnx_models.py [--frames N] [--repeats R] [--out FILE]

The network (`SegNet`: a UNet whose five encoder stages each halve the size, a decoder with skip
connections and bilinear upsampling, and a one-channel logit head at half the input size, as
many segmenters give; random weights, since the time does not depend on them) is exported with
`torch.onnx.export` into a temporary folder. Each case runs in its own process, on
`torch.get_num_threads()` threads: the importer's whole path (`model_tool_masks`: resize to the
model's input, normalise, ONNX Runtime, resize back to 854x480, threshold inside the field of
view) over N synthetic frames, R rounds, median seconds per frame; the reference measured in the
same run is the same network's PyTorch forward at the same input size (`torch_seconds_per_frame`
and the ratio). The machine is shared: the load average at the start and end is recorded too,
and so is the CPU time per frame of the importer's path (summed over its threads; ONNX Runtime's
idle threads sleep), which other processes' load changes far less than the wall time.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import write_report  # noqa: E402  (imports surgsplat before torch)

import torch  # noqa: E402
from torch import nn  # noqa: E402
from torch.nn import functional  # noqa: E402

from surgsplat.data.learned_priors import ToolSegmenterConfig, model_tool_masks  # noqa: E402
from surgsplat.data.onnx_models import ModelInput, OnnxModel  # noqa: E402

WIDTH, HEIGHT = 854, 480
WIDTHS = (16, 24, 48, 96, 176)
"""Channels of SegNet's five encoder stages (1.0M parameters)."""
MULTIPLE = 32
"""SegNet halves the size five times: both input sides are rounded to a multiple of 32."""
CASES = {"frame-batch4": (None, 4), "frame-batch1": (None, 1), "short256-batch4": (256, 4)}
"""Case name: (input short side, None = the frame's own size; frames per run)."""


def conv_block(inputs: int, outputs: int, stride: int = 1) -> nn.Sequential:
    """Two 3x3 convolutions with batch norm and ReLU, the first with `stride`."""
    return nn.Sequential(
        nn.Conv2d(inputs, outputs, 3, stride, 1, bias=False), nn.BatchNorm2d(outputs),
        nn.ReLU(), nn.Conv2d(outputs, outputs, 3, 1, 1, bias=False), nn.BatchNorm2d(outputs),
        nn.ReLU())


class SegNet(nn.Module):
    """A small UNet: float32 [N, 3, h, w] -> tool logits [N, 1, h / 2, w / 2]."""

    def __init__(self, widths: tuple[int, ...] = WIDTHS):
        super().__init__()
        self.down = nn.ModuleList(conv_block(a, b, 2) for a, b in zip((3, *widths), widths))
        self.up = nn.ModuleList(conv_block(widths[i + 1] + widths[i], widths[i])
                                for i in reversed(range(len(widths) - 1)))
        self.head = nn.Conv2d(widths[0], 1, 1)

    def forward(self, x):
        skips = []
        for stage in self.down:
            x = stage(x)
            skips.append(x)
        x = skips.pop()
        for stage in self.up:
            skip = skips.pop()
            x = functional.interpolate(x, size=skip.shape[-2:], mode="bilinear",
                                       align_corners=False)
            x = stage(torch.cat([x, skip], 1))
        return self.head(x)


def export(path: Path) -> int:
    """SegNet (seed 0) as an ONNX model with free batch and size at `path`; its parameters."""
    torch.manual_seed(0)
    net = SegNet().eval()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notice
        torch.onnx.export(net, (torch.zeros(1, 3, 64, 64),), str(path), dynamo=False,
                          input_names=["image"], output_names=["logits"],
                          dynamic_axes={"image": {0: "n", 2: "h", 3: "w"},
                                        "logits": {0: "n", 2: "h", 3: "w"}})
    return sum(p.numel() for p in net.parameters())


def synthetic_frames(count: int) -> list[np.ndarray]:
    """`count` uint8 RGB 854x480 frames of noise (the time does not depend on the content)."""
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (HEIGHT, WIDTH, 3), dtype=np.uint8) for _ in range(count)]


def run_case(name: str, model_path: Path, frames: int, repeats: int) -> dict:
    """Median seconds per frame of the importer's path, and of the PyTorch reference."""
    short_side, batch = CASES[name]
    fit = ModelInput(short_side=short_side, multiple=MULTIPLE, batch=batch)
    model = OnnxModel(model_path, fit, (HEIGHT, WIDTH))
    images = synthetic_frames(frames)
    fov = np.ones((HEIGHT, WIDTH), bool)
    config = ToolSegmenterConfig(input=fit)
    list(model_tool_masks(model, images[:batch], fov, config))  # warm-up
    rounds, cpu_rounds = [], []
    for _ in range(repeats):
        started, cpu_started = time.perf_counter(), time.process_time()
        masks = list(model_tool_masks(model, images, fov, config))
        rounds.append((time.perf_counter() - started) / frames)
        cpu_rounds.append((time.process_time() - cpu_started) / frames)
    assert len(masks) == frames and masks[0].shape == (HEIGHT, WIDTH)
    torch.manual_seed(0)
    net = SegNet().eval()
    inputs = torch.from_numpy(np.stack([model.preprocess(image) for image in images[:batch]]))
    reference = []
    with torch.no_grad():
        net(inputs)  # warm-up
        for _ in range(repeats):
            started = time.perf_counter()
            net(inputs)
            reference.append((time.perf_counter() - started) / batch)
    onnx_seconds, torch_seconds = statistics.median(rounds), statistics.median(reference)
    return {"case": name, "input_size_wh": list(model.input_size[::-1]), "batch": batch,
            "frames": frames, "repeats": repeats, "threads": torch.get_num_threads(),
            "seconds_per_frame": onnx_seconds, "rounds": rounds,
            "cpu_seconds_per_frame": statistics.median(cpu_rounds),
            "torch_seconds_per_frame": torch_seconds,
            "onnx_to_torch_ratio": onnx_seconds / torch_seconds}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16, help="frames per round")
    parser.add_argument("--repeats", type=int, default=5, help="measured rounds per case")
    parser.add_argument("--out", type=Path, default=None, help="result file (default "
                        "benchmarks/results/bench_onnx_models-<cpu>-<best ISA>.json)")
    parser.add_argument("--case", help=argparse.SUPPRESS)  # one case, in a child process
    parser.add_argument("--model", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        print(json.dumps(run_case(args.case, args.model, args.frames, args.repeats)))
        return
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory() as folder:
        model = Path(folder) / "segnet.onnx"
        parameters = export(model)
        rows = []
        for name in CASES:
            child = subprocess.run(
                [sys.executable, __file__, "--case", name, "--model", str(model), "--frames",
                 str(args.frames), "--repeats", str(args.repeats)],
                check=True, capture_output=True, text=True)
            rows.append(json.loads(child.stdout))
            print(f"{name:16s} input {rows[-1]['input_size_wh']}: "
                  f"{rows[-1]['seconds_per_frame']:.3f} s/frame (PyTorch "
                  f"{rows[-1]['torch_seconds_per_frame']:.3f})")
    result = {"network": "SegNet (UNet, logits at half the input size)", "parameters": parameters,
              "frame_size_wh": [WIDTH, HEIGHT], "target_seconds_per_frame": 0.1,
              "load_average_1min": {"start": load_before[0], "end": os.getloadavg()[0]},
              "rows": rows}
    print(f"results: {write_report('bench_onnx_models', result, args.out)}")


if __name__ == "__main__":
    main()
