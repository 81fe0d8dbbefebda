"""Rendering-core benchmark: forward and forward+backward rasterisation at 640x512 for 10k, 100k
and 300k tissue-like Gaussians (C = 3 and 8 channels), the speed-up over the PyTorch reference,
and one full static training step at 100k Gaussians.

    python benchmarks/bench_render.py [--json] [--repeats N]

evals_per_s counts (Gaussian, pixel) pairs in the 16x16 tiles each Gaussian is binned to, per
second of forward rasterisation (an upper bound of the per-pixel Gaussian evaluations).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from surface_scene import surface_gaussians  # noqa: E402

from surgsplat.render.native import native_module  # noqa: E402
from surgsplat.render.project import project  # noqa: E402
from surgsplat.render.rasterize import rasterize  # noqa: E402
from surgsplat.render.render import render  # noqa: E402

WIDTH, HEIGHT = 640, 512


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def best_time(fn, repeats: int) -> float:
    """Seconds of the fastest of `repeats` calls after one warm-up (least disturbed by noise)."""
    fn()
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        fn()
        times.append(time.perf_counter() - started)
    return min(times)


def screen_inputs(num: int, channels: int, width: int = WIDTH, height: int = HEIGHT):
    scene = surface_gaussians(num, channels, width, height, focal=569.4682 * width / WIDTH)
    proj = project(scene.means, scene.scales, scene.quats, scene.K, width, height)
    leaves = [t.detach().clone().requires_grad_() for t in
              (proj.means2d, proj.conics, scene.opacities, scene.features)]
    return leaves, proj.depths.detach(), proj.radii


def raster_times(num: int, channels: int, backend: str, repeats: int,
                 width: int = WIDTH, height: int = HEIGHT) -> tuple[float, float]:
    leaves, depths, radii = screen_inputs(num, channels, width, height)

    def forward():
        with torch.no_grad():
            rasterize(*leaves, depths, radii, width, height, backend=backend)

    def forward_backward():
        image, alpha = rasterize(*leaves, depths, radii, width, height, backend=backend)
        (image.sum() + alpha.sum()).backward()

    return best_time(forward, repeats), best_time(forward_backward, repeats)


def tile_pairs(num: int, channels: int) -> int:
    leaves, depths, radii = screen_inputs(num, channels)
    arrays = [t.detach().contiguous().numpy() for t in leaves]
    bins = native_module().rasterize_forward(
        *arrays, depths.contiguous().numpy(), radii.numpy(), WIDTH, HEIGHT,
        torch.empty(HEIGHT, WIDTH, channels).numpy(), torch.empty(HEIGHT, WIDTH).numpy(),
        torch.empty(HEIGHT, WIDTH, dtype=torch.int32).numpy())
    return bins.num_overlaps * 256


def reference_speedup(repeats: int) -> tuple[dict, float]:
    """Native vs reference forward+backward at a size the dense reference can do."""
    num, width, height = 2000, 160, 128
    _, ref = raster_times(num, 3, "reference", max(1, repeats // 3), width, height)
    _, nat = raster_times(num, 3, "native", repeats, width, height)
    return {"gaussians": num, "width": width, "height": height,
            "reference_fwdbwd_ms": ref * 1e3, "native_fwdbwd_ms": nat * 1e3}, ref / nat


def training_step_ms(num: int, repeats: int) -> float:
    """Projection + rasterisation forward and backward + Adam over all Gaussian parameters."""
    scene = surface_gaussians(num, 3)
    params = {
        "means": scene.means.clone().requires_grad_(),
        "log_scales": scene.scales.log().requires_grad_(),
        "quats": scene.quats.clone().requires_grad_(),
        "opacity_logits": torch.logit(scene.opacities).requires_grad_(),
        "colors": scene.features.clone().requires_grad_(),
    }
    optimizer = torch.optim.Adam(params.values(), lr=1e-3, fused=True)
    target = torch.rand(HEIGHT, WIDTH, 3)

    def step():
        out = render(params["means"], params["log_scales"].exp(), params["quats"],
                     torch.sigmoid(params["opacity_logits"]), params["colors"], scene.K,
                     WIDTH, HEIGHT, absgrad=torch.zeros(num))
        loss = (out.rgb - target).abs().mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()

    return best_time(step, repeats) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", action="store_true", help="one JSON object per configuration")
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    if native_module() is None:
        sys.exit("the native module is not built: run `make install` first")
    torch.set_num_threads(2)
    comparison, speedup = reference_speedup(args.repeats)
    rows = []
    for num in (10_000, 100_000, 300_000):
        for channels in (3, 8):
            fwd, fwdbwd = raster_times(num, channels, "native", args.repeats)
            rows.append({"gaussians": num, "channels": channels, "width": WIDTH,
                         "height": HEIGHT, "fwd_ms": fwd * 1e3, "fwdbwd_ms": fwdbwd * 1e3,
                         "fps": 1.0 / fwd, "evals_per_s": tile_pairs(num, channels) / fwd,
                         "peak_rss_mb": peak_rss_mb()})
    rows[0]["speedup_vs_reference"] = speedup
    rows[0]["reference_comparison"] = comparison
    rows.append({"gaussians": 100_000, "channels": 3, "width": WIDTH, "height": HEIGHT,
                 "step_ms": training_step_ms(100_000, args.repeats), "peak_rss_mb": peak_rss_mb()})
    if args.json:
        for row in rows:
            print(json.dumps(row))
        return
    print(f"{'gaussians':>9} {'C':>2} {'fwd ms':>8} {'fps':>6} {'fwd+bwd ms':>10} "
          f"{'evals/s':>9} {'RSS MB':>7}")
    for row in rows[:-1]:
        print(f"{row['gaussians']:>9} {row['channels']:>2} {row['fwd_ms']:>8.1f} {row['fps']:>6.1f} "
              f"{row['fwdbwd_ms']:>10.1f} {row['evals_per_s']:>9.2e} {row['peak_rss_mb']:>7.0f}")
    print(f"training step (100k Gaussians, project + raster fwd/bwd + Adam): "
          f"{rows[-1]['step_ms']:.1f} ms")
    print(f"native vs PyTorch reference, fwd+bwd, {comparison['gaussians']} Gaussians at "
          f"{comparison['width']}x{comparison['height']}: {comparison['reference_fwdbwd_ms']:.0f} ms "
          f"vs {comparison['native_fwdbwd_ms']:.2f} ms = {speedup:.0f}x")


if __name__ == "__main__":
    main()
