"""The native projection's camera gradients (issue 32): what a pose and intrinsics with
gradients cost against the same projection without them, and how far the native gradients are
from the float64 PyTorch reference.

    python benchmarks/bench_camera_grads.py [--gaussians 100000 ...] [--repeats 15] [--out FILE]

For each Gaussian count: `project` forward and backward (an L1 of the 2D means, conics and
depths) of tissue-like Gaussians at 640x512 (`surface_scene`), once with only the Gaussians
requiring gradients and once with world_to_camera and K requiring them too. The two run
alternately, `repeats` times each, in one process, and the ratio of the medians is the figure
(the shared machine's speed changes between runs, not within one alternation). The accuracy
check compares the native float32 camera gradients with the float64 reference's on 2000
Gaussians: the largest error relative to the largest gradient entry. Results go to
benchmarks/results/bench_camera_grads-<cpu>-<best ISA>.json and the README's table.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import surgsplat  # noqa: F401  (before torch: sets surgsplat's OpenMP wait policy)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import write_report  # noqa: E402
from surface_scene import surface_gaussians  # noqa: E402

from surgsplat.render import native  # noqa: E402
from surgsplat.render.project import project  # noqa: E402

WIDTH, HEIGHT = 640, 512


def camera_pose(angle: float = 0.05) -> torch.Tensor:
    """A world_to_camera a little off the identity: `angle` radians about x, and a shift."""
    cos, sin = math.cos(angle), math.sin(angle)
    pose = torch.eye(4)
    pose[1:3, 1:3] = torch.tensor([[cos, -sin], [sin, cos]])
    pose[:3, 3] = torch.tensor([0.5, -0.3, 1.0])
    return pose


def projection_loss(means, scales, quats, K, pose, backend: str = "auto") -> torch.Tensor:
    """An L1 of everything the projection returns that carries a gradient."""
    out = project(means, scales, quats, K, WIDTH, HEIGHT, world_to_camera=pose, backend=backend)
    return out.means2d.abs().sum() + out.conics.abs().sum() + out.depths.abs().sum()


def timing_case(num: int, repeats: int) -> dict:
    scene = surface_gaussians(num, 3, WIDTH, HEIGHT)
    gaussians = [scene.means.clone().requires_grad_(), scene.scales.clone().requires_grad_(),
                 scene.quats.clone().requires_grad_()]

    def step(with_camera: bool) -> float:
        K = scene.K.clone().requires_grad_(with_camera)
        pose = camera_pose().requires_grad_(with_camera)
        started = time.perf_counter()
        projection_loss(*gaussians, K, pose).backward()
        elapsed = time.perf_counter() - started
        for tensor in gaussians:
            tensor.grad = None
        return elapsed

    step(False), step(True)  # warm-up
    times = {False: [], True: []}
    for _ in range(repeats):
        for with_camera in (False, True):
            times[with_camera].append(step(with_camera))
    without, with_camera = statistics.median(times[False]), statistics.median(times[True])
    return {"gaussians": num, "without_camera_ms": without * 1e3,
            "with_camera_ms": with_camera * 1e3, "ratio": with_camera / without}


def accuracy_case(num: int = 2000) -> dict:
    """Largest native-vs-reference error of the camera gradients, relative to the largest
    reference entry, for K and world_to_camera."""
    scene = surface_gaussians(num, 3, WIDTH, HEIGHT, seed=1)
    gradients = {}
    for backend, dtype in (("native", torch.float32), ("reference", torch.float64)):
        K = scene.K.to(dtype).requires_grad_()
        pose = camera_pose().to(dtype).requires_grad_()
        loss = projection_loss(scene.means.to(dtype), scene.scales.to(dtype),
                               scene.quats.to(dtype), K, pose, backend=backend)
        gradients[backend] = torch.autograd.grad(loss, [K, pose])
    errors = {}
    for name, native_grad, reference in zip(("K", "world_to_camera"), gradients["native"],
                                            gradients["reference"]):
        scale = float(reference.abs().max())
        errors[f"{name}_relative_error"] = float((native_grad.double() - reference).abs().max()
                                                 / scale)
    return {"gaussians": num, **errors}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gaussians", type=int, nargs="+", default=[100_000, 300_000])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--out", type=Path, help="JSON file (default: "
                        "benchmarks/results/bench_camera_grads-<cpu>-<best ISA>.json)")
    args = parser.parse_args()
    if native.native_module() is None:
        sys.exit("the native module is not built: run `make install` first")
    result = {"width": WIDTH, "height": HEIGHT, "repeats": args.repeats,
              "threads": torch.get_num_threads(),
              "timing": [timing_case(num, args.repeats) for num in args.gaussians],
              "accuracy": accuracy_case()}
    for row in result["timing"]:
        print(f"{row['gaussians']} Gaussians: {row['without_camera_ms']:.1f} ms without camera "
              f"gradients, {row['with_camera_ms']:.1f} ms with ({row['ratio']:.3f}x)")
    print(f"written to {write_report('bench_camera_grads', result, args.out)}")


if __name__ == "__main__":
    main()
