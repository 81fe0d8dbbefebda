"""Rendering-core benchmark: forward and forward+backward rasterisation at 640x512 of 10k, 100k
and 300k tissue-like Gaussians, and one static training step at 100k, for every ISA variant of
the native kernels this machine runs, each against an in-process limit probe.

    python benchmarks/bench_render.py [--isa avx2 ...] [--repeats 5] [--out FILE] [--json]

Every case runs in its own process (so one case's allocations and threads do not disturb the
next) and alternates, `repeats` times, a call of the native module's composite_probe (a plain
16-lane compositing loop compiled with the same flags as the kernels: the limit of its ISA on
this machine now) with the measured call; medians are reported. Since shared machines run the
same command at different speeds from hour to hour, the figure that holds across runs and
machines is the efficiency: evals_per_s / probe_evals_per_s, where evals_per_s counts the
(Gaussian, pixel) pairs of the 16x16 tiles each Gaussian's alpha box touches, per second (for
fwd+bwd, per second of forward plus backward). Results go to
benchmarks/results/bench_render-<cpu>-<best ISA>.json, which benchmarks/readme_tables.py turns
into the README's table.
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import statistics
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

import surgsplat  # noqa: F401  (before torch: sets surgsplat's OpenMP wait policy)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from surface_scene import surface_gaussians  # noqa: E402

from surgsplat.atomic import write_text_atomic  # noqa: E402
from surgsplat.data.phantom import PhantomConfig, generate_phantom  # noqa: E402
from surgsplat.render import native  # noqa: E402
from surgsplat.render.project import project  # noqa: E402
from surgsplat.render.rasterize import rasterize  # noqa: E402
from surgsplat.render.render import render  # noqa: E402

WIDTH, HEIGHT = 640, 512
RESULTS = Path(__file__).resolve().parent / "results"
RASTER_CASES = [(10_000, 3), (100_000, 3), (100_000, 8), (300_000, 3)]
STEP_GAUSSIANS = 100_000
PROBE_TILES, PROBE_GAUSSIANS = 512, 256  # about 34M evaluations per probe call


def peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def seconds(fn) -> float:
    started = time.perf_counter()
    fn()
    return time.perf_counter() - started


def interleaved(cases: dict, channels: int, repeats: int) -> dict[str, float]:
    """Median seconds of each callable in `cases` and median probe evaluations per second, the
    probe run before each round of the cases (after one warm-up round)."""
    module = native.native_module()

    def probe():
        module.composite_probe(PROBE_TILES, PROBE_GAUSSIANS, channels)

    for fn in (probe, *cases.values()):
        fn()
    times: dict[str, list[float]] = {name: [] for name in ("probe", *cases)}
    for _ in range(repeats):
        times["probe"].append(seconds(probe))
        for name, fn in cases.items():
            times[name].append(seconds(fn))
    medians = {name: statistics.median(t) for name, t in times.items()}
    medians["probe_evals_per_s"] = PROBE_TILES * PROBE_GAUSSIANS * 256 / medians.pop("probe")
    return medians


def screen_inputs(num: int, channels: int):
    scene = surface_gaussians(num, channels, WIDTH, HEIGHT)
    proj = project(scene.means, scene.scales, scene.quats, scene.K, WIDTH, HEIGHT)
    leaves = [t.detach().clone().requires_grad_() for t in
              (proj.means2d, proj.conics, scene.opacities, scene.features)]
    return leaves, proj.depths.detach(), proj.radii


def tile_pairs(leaves, depths, radii) -> int:
    """(Gaussian, pixel) pairs of the tiles the Gaussians' alpha >= 1/255 boxes touch: a
    measure of the scene's work that does not change with the binning (which leaves out the
    tiles a box touches but its ellipse misses)."""
    channels = leaves[3].shape[1]
    bins = native.native_module().rasterize_forward(
        *(t.detach().contiguous().numpy() for t in leaves), depths.contiguous().numpy(),
        radii.numpy(), torch.zeros(channels).numpy(), WIDTH, HEIGHT,
        torch.empty(HEIGHT, WIDTH, channels).numpy(),
        torch.empty(HEIGHT, WIDTH).numpy(), torch.empty(HEIGHT, WIDTH, dtype=torch.int32).numpy())
    return bins.box_overlaps * 256


def raster_case(num: int, channels: int, repeats: int) -> dict:
    leaves, depths, radii = screen_inputs(num, channels)

    def forward():
        with torch.no_grad():
            rasterize(*leaves, depths, radii, WIDTH, HEIGHT, backend="native")

    def forward_backward():
        image, alpha = rasterize(*leaves, depths, radii, WIDTH, HEIGHT, backend="native")
        (image.sum() + alpha.sum()).backward()

    t = interleaved({"fwd": forward, "fwdbwd": forward_backward}, channels, repeats)
    pairs = tile_pairs(leaves, depths, radii)
    return {"gaussians": num, "channels": channels, "fwd_ms": t["fwd"] * 1e3,
            "fwdbwd_ms": t["fwdbwd"] * 1e3, "fps": 1.0 / t["fwd"],
            "evals_per_s": pairs / t["fwd"], "probe_evals_per_s": t["probe_evals_per_s"],
            "efficiency_fwd": pairs / t["fwd"] / t["probe_evals_per_s"],
            "efficiency_fwdbwd": pairs / t["fwdbwd"] / t["probe_evals_per_s"]}


def step_case(num: int, repeats: int) -> dict:
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

    t = interleaved({"step": step}, 3, repeats)
    return {"gaussians": num, "channels": 3, "step_ms": t["step"] * 1e3,
            "probe_evals_per_s": t["probe_evals_per_s"]}


def run_case(case: str, isa: str, repeats: int) -> dict:
    """One case in this process: `raster:N:C` or `step:N`."""
    native.use_isa(isa)
    kind, *numbers = case.split(":")
    sizes = [int(x) for x in numbers]
    row = raster_case(*sizes, repeats) if kind == "raster" else step_case(*sizes, repeats)
    return {"isa": isa, "case": kind, **row, "peak_rss_mb": peak_rss_mb()}


def case_in_subprocess(case: str, isa: str, repeats: int) -> dict:
    command = [sys.executable, __file__, "--case", case, "--isa", isa, "--repeats", str(repeats)]
    done = subprocess.run(command, capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def full_pulling_phantom(folder: Path) -> Path:
    """`folder`, holding the full "pulling" phantom (640x512, 64 frames), generated there unless
    it already holds a scene: the scene of the training benchmarks."""
    if not (folder / "poses_bounds.npy").is_file():
        generate_phantom(PhantomConfig(preset="full", motion="pulling"), folder)
    return folder


def results_path(benchmark: str, info: dict) -> Path:
    """benchmarks/results/<benchmark>-<cpu model>-<best ISA>.json, lower case with dashes, from
    native.system_info(): the best ISA tells apart machines that share a model name (an "AMD
    EPYC" may be a Zen 3 with AVX2 or a Zen 5 with AVX-512)."""
    machine = f"{info['cpu']} {info['available_isas'][0]}"
    slug = re.sub(r"[^a-z0-9]+", "-", machine.lower()).strip("-")
    return RESULTS / f"{benchmark}-{slug}.json"


def write_report(benchmark: str, result: dict, out: Path | None) -> Path:
    """Write `result` with the machine, date and command line as benchmarks/results JSON (to
    `out`, default results_path); returns the file."""
    info = native.system_info()
    report = {"benchmark": benchmark, "cpu": info["cpu"], "system": info,
              "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
              "command": " ".join(["python", f"benchmarks/{benchmark}.py", *sys.argv[1:]]),
              **result}
    out = out or results_path(benchmark, info)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, json.dumps(report, indent=2) + "\n")
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--isa", nargs="*", help="ISA variants (default: every one available)")
    parser.add_argument("--repeats", type=int, default=5, help="measured rounds per case (>= 5 "
                        "for results to keep)")
    parser.add_argument("--out", type=Path, help="JSON file (default: "
                        "benchmarks/results/bench_render-<cpu>-<best ISA>.json)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--case", help=argparse.SUPPRESS)  # one case, in a child process
    args = parser.parse_args()
    if native.native_module() is None:
        sys.exit("the native module is not built: run `make install` first")
    if args.case:
        print(json.dumps(run_case(args.case, args.isa[0], args.repeats)))
        return
    isas = args.isa or native.available_isas()
    cases = [f"raster:{n}:{c}" for n, c in RASTER_CASES] + [f"step:{STEP_GAUSSIANS}"]
    rows = []
    for isa in isas:
        for case in cases:
            rows.append(case_in_subprocess(case, isa, args.repeats))
            print(json.dumps(rows[-1]), file=sys.stderr)
    out = write_report("bench_render", {"width": WIDTH, "height": HEIGHT,
                                        "repeats": args.repeats, "rows": rows}, args.out)
    report = json.loads(out.read_text())
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        from readme_tables import render_table

        print(render_table(report))
        print(f"written to {out}")


if __name__ == "__main__":
    main()
