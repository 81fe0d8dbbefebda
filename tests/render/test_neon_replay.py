"""The NEON build of the native module, executed on an x86-64 host: it is cross-compiled from
CMakeLists.txt (aarch64-linux-gnu-g++), and the calls that a render with its backward, D-SSIM,
the blur, the Gaussian-basis and the HexPlane fields and the normal consistency make of the
baseline module are recorded, replayed on the NEON module by native_replay.py in Debian's arm64 Python and NumPy under
qemu-aarch64, and every output is compared with the baseline's.

The baseline variant is checked against the PyTorch references by the other tests. baseline and
NEON hold the 16 lanes in four 4-lane registers alike, so the same source adds in the same
order on both; only the fused multiply-adds that the aarch64 compiler forms (x86-64 baseline has
no FMA) round differently. Tolerance: max |NEON - baseline| <= 3e-5 of the output's largest
magnitude (the largest seen is 3.7e-6, in the SSIM map), integer and boolean outputs (radii, last
contributors) equal.

Needs Debian's g++-aarch64-linux-gnu and qemu-user, cmake, and the arm64 sysroot that
`make aarch64-sysroot` unpacks into build/aarch64-sysroot (.ci/run does all three); skipped
without them."""

from __future__ import annotations

import json
import os
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from surgsplat.fields.gaussian_basis import deformation_channels
from surgsplat.fields.hexplane import plane_features
from surgsplat.image.blur import gaussian_blur
from surgsplat.image.ssim import ssim, ssim_map
from surgsplat.methods.endoplanar.normal_consistency import normal_consistency
from surgsplat.render import native
from surgsplat.render.render import render

ROOT = Path(__file__).resolve().parents[2]
SYSROOT = ROOT / "build" / "aarch64-sysroot"
REPLAY = Path(__file__).with_name("native_replay.py")
RELATIVE_TOLERANCE = 3e-5


class Recorder:
    """Stands in for a native module: passes every call through and records those with array
    arguments (the arrays as before the call, to replay; as after it, to compare)."""

    def __init__(self, module, folder: Path):
        self.module, self.folder = module, folder
        self.calls: list[dict] = []
        self.after: dict[str, np.ndarray] = {}
        self.returns: dict[str, list[float]] = {}
        self.result_index: dict[int, int] = {}  # id of a returned object -> its call

    def __getattr__(self, name: str):
        attribute = getattr(self.module, name)
        if not callable(attribute) or isinstance(attribute, type):
            return attribute

        def recorded(*args):
            index = len(self.calls)
            arrays: dict[str, np.ndarray] = {}
            specs = [self._spec(arg, f"c{index}_a{j}", arrays) for j, arg in enumerate(args)]
            result = attribute(*args)
            if arrays:
                self.calls.append({"function": name, "args": specs})
                self.after.update({file: array.copy() for file, array in arrays.items()})
                numbers = result if isinstance(result, tuple) else (result,)
                if all(isinstance(number, (int, float)) for number in numbers):
                    self.returns[str(index)] = list(numbers)
                elif result is not None:
                    self.result_index[id(result)] = index
            return result

        return recorded

    def _spec(self, arg, stem: str, arrays: dict[str, np.ndarray]) -> list:
        if isinstance(arg, np.ndarray):
            file = f"{stem}.npy"
            np.save(self.folder / file, arg)
            arrays[file] = arg
            return ["array", file]
        if isinstance(arg, (list, tuple)):
            return ["list", [self._spec(a, f"{stem}_{i}", arrays) for i, a in enumerate(arg)]]
        if id(arg) in self.result_index:
            return ["result", self.result_index[id(arg)]]
        if arg is None or isinstance(arg, (bool, int, float, str)):
            return ["scalar", arg]
        raise TypeError(f"cannot record a {type(arg).__name__} argument")


def exercise_every_kernel() -> None:
    """Forward and backward of every native op, at sizes that keep the emulation short."""
    generator = torch.Generator().manual_seed(3)

    def rand(*shape):
        return torch.rand(*shape, generator=generator)

    n, width, height = 400, 70, 45
    means = (torch.randn(n, 3, generator=generator) * 0.5 + torch.tensor([0.0, 0.0, 3.0]))
    leaves = [means, rand(n, 3) * 0.15 + 0.02, torch.randn(n, 4, generator=generator),
              rand(n) * 0.9 + 0.05, rand(n, 4, 3) - 0.5, torch.randn(n, 3, generator=generator)]
    leaves = [leaf.requires_grad_() for leaf in leaves]
    means, scales, quats, opacities, sh, normals = leaves
    K = torch.tensor([[60.0, 0, width / 2], [0, 60.0, height / 2], [0, 0, 1]])
    world_to_camera = torch.eye(4)
    world_to_camera[:3, 3] = torch.tensor([0.05, -0.02, 0.1])
    out = render(means, scales, quats, opacities, sh, K, width, height, world_to_camera,
                 sh_degree=1, extras={"normal": normals}, background=torch.tensor([0.2, 0.1, 0]),
                 backend="native")
    target = rand(height, width, 3)
    tissue = rand(height, width) > 0.2
    loss = (1 - ssim(out.rgb.contiguous(), target, tissue, zero_unmasked=True)
            + (out.depth * rand(height, width)).sum() + (out.extras["normal"] ** 2).sum()
            + ssim_map(out.rgb.contiguous(), target).square().sum())
    loss.backward()

    planes = rand(3, height, width).requires_grad_()
    (gaussian_blur(planes) * rand(3, height, width)).sum().backward()

    weights, centres, log_widths = rand(300, 10, 8), rand(300, 8), rand(300, 8) - 2.0
    for leaf in (weights, centres, log_widths):
        leaf.requires_grad_()
    channels = deformation_channels(weights, centres, log_widths, 0.37, backend="native")
    (channels * rand(300, 10)).sum().backward()

    spatial = [(0.5 + rand(3, 8, r, r)).requires_grad_() for r in (5, 9)]
    temporal = [(0.5 + rand(3, 8, 6, r)).requires_grad_() for r in (5, 9)]
    coords = (rand(200, 3) * 2.4 - 1.2).requires_grad_()
    features = plane_features(coords, 0.3, spatial, temporal, backend="native")
    (features * rand(*features.shape)).sum().backward()

    depth = (2.0 + 0.3 * rand(height, width)).requires_grad_()
    rendered_normals = (rand(height, width, 3) - torch.tensor([0.5, 0.5, 0.0])).requires_grad_()
    total, _ = normal_consistency(depth, rendered_normals, K, tissue, rand(height, width),
                                  backend="native")
    total.backward()


def cross_toolchain_missing() -> str | None:
    if platform.machine().lower() not in ("x86_64", "amd64"):
        return "runs on x86-64 hosts (an aarch64 host runs the NEON variant directly)"
    for tool, package in (("aarch64-linux-gnu-g++", "g++-aarch64-linux-gnu"),
                          ("qemu-aarch64", "qemu-user"), ("cmake", "cmake")):
        if shutil.which(tool) is None:
            return f"{tool} not found (Debian: {package})"
    if not (SYSROOT / "usr" / "bin" / "python3.11").exists():
        return f"no arm64 sysroot at {SYSROOT} (make aarch64-sysroot)"
    return None


pytestmark = pytest.mark.slow  # a cross-build of the module and a replay under emulation


@pytest.fixture(scope="module")
def neon_module(tmp_path_factory) -> Path:
    """The NEON variant cross-compiled from CMakeLists.txt with the sysroot's Python headers."""
    reason = cross_toolchain_missing()
    if reason is not None:
        pytest.skip(reason)
    build = tmp_path_factory.mktemp("neon-build")
    toolchain = build / "aarch64.cmake"
    include = SYSROOT / "usr" / "include"  # its pyconfig.h includes <aarch64-linux-gnu/...>
    toolchain.write_text("set(CMAKE_SYSTEM_NAME Linux)\nset(CMAKE_SYSTEM_PROCESSOR aarch64)\n"
                         "set(CMAKE_CXX_COMPILER aarch64-linux-gnu-g++)\n"
                         f'set(CMAKE_CXX_FLAGS_INIT "-isystem {include}")\n')
    configure = [
        "cmake", "-S", str(ROOT), "-B", str(build), f"-DCMAKE_TOOLCHAIN_FILE={toolchain}",
        "-DCMAKE_BUILD_TYPE=Release", f"-DPython_EXECUTABLE={sys.executable}",
        f"-DPython_INCLUDE_DIR={include / 'python3.11'}",
        "-DSURGSPLAT_ISA_TARGETS=neon"]
    for command in (configure, ["cmake", "--build", str(build), f"-j{os.cpu_count() or 1}"]):
        done = subprocess.run(command, capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    (module,) = build.glob("_native_neon*.so")
    return module


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Recorder:
    """The calls of exercise_every_kernel() on the baseline variant."""
    if native.isa_unavailable("baseline") is not None:
        pytest.skip(native.isa_unavailable("baseline"))
    folder = tmp_path_factory.mktemp("calls")
    native.use_isa("baseline")
    recorder = Recorder(native.native_module(), folder)
    try:
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(native, "_import_variant", lambda isa: recorder)
            native.native_module.cache_clear()
            exercise_every_kernel()
    finally:
        native.use_isa(None)
    (folder / "calls.json").write_text(json.dumps(recorder.calls))
    return recorder


def test_neon_build_matches_the_baseline_on_every_kernel(neon_module, recording, tmp_path):
    functions = {call["function"] for call in recording.calls}
    assert {f"{op}_{way}" for op in ("project", "sh", "rasterize", "ssim", "gaussian_basis",
                                     "hexplane", "normal_consistency") for way in ("forward", "backward")} | {"blur"} \
        <= functions
    replayed = subprocess.run(
        ["qemu-aarch64", "-L", str(SYSROOT), "-E",
         "LD_LIBRARY_PATH=/usr/lib/aarch64-linux-gnu/blas:/usr/lib/aarch64-linux-gnu/lapack",
         "-E", "PYTHONPATH=/usr/lib/python3/dist-packages",
         str(SYSROOT / "usr" / "bin" / "python3.11"), str(REPLAY), str(neon_module),
         str(recording.folder), str(tmp_path)],
        capture_output=True, text=True, timeout=900)
    assert replayed.returncode == 0, replayed.stderr[-3000:]
    failures = []
    for file, expected in recording.after.items():
        got = np.load(tmp_path / file)
        call = recording.calls[int(file[1:].split("_")[0])]["function"]
        if np.issubdtype(expected.dtype, np.integer) or expected.dtype == np.bool_:
            if not np.array_equal(got, expected):
                differ = int((got != expected).sum())
                failures.append(f"{call} {file}: {differ} of {got.size} differ")
            continue
        scale = max(float(np.abs(expected).max(initial=0.0)), 1e-30)
        error = float(np.abs(got - expected).max(initial=0.0)) / scale
        if not error <= RELATIVE_TOLERANCE:
            failures.append(f"{call} {file}: relative error {error:.2e}")
    returns = json.loads((tmp_path / "returns.json").read_text())
    for index, expected in recording.returns.items():
        if any(abs(got - want) > RELATIVE_TOLERANCE * max(abs(want), 1.0)
               for got, want in zip(returns[index], expected, strict=True)):
            failures.append(f"call {index} returned {returns[index]}, expected {expected}")
    assert not failures, "\n".join(failures)
