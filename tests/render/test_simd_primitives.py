"""csrc/simd.h, where all of the kernels' ISA-specific code lives, checked operation by operation
on every ISA variant: simd_check.cpp is compiled with each variant's flags from CMakeLists.txt
and run. Variants this CPU executes run directly; the NEON build runs under qemu-aarch64 on an
x86-64 host (Debian's g++-aarch64-linux-gnu and qemu-user, which .ci/run installs), so the ARM
code paths are executed here, not only compiled. The tolerances are in simd_check.cpp: pow2
within 3e-7 relative, reciprocal within 2.5e-7 (about 2 ulp), sums within 1e-6, the rest exact."""

from __future__ import annotations

import platform
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from surgsplat.render import native

ROOT = Path(__file__).resolve().parents[2]
SOURCE = Path(__file__).with_name("simd_check.cpp")
# As CMakeLists.txt compiles the module, besides each variant's own flags.
COMMON_FLAGS = ["-std=c++17", "-O3", "-fno-math-errno", "-Wall", "-Wextra"]


def variant_flags() -> dict[str, list[str]]:
    """Each ISA variant's compiler flags, read from CMakeLists.txt (set(SURGSPLAT_FLAGS_<isa>))."""
    text = (ROOT / "CMakeLists.txt").read_text()
    return {isa: flags.split() for isa, flags in
            re.findall(r"set\(SURGSPLAT_FLAGS_(\w+) ([^)]*)\)", text)}


def build_and_run_command(isa: str, binary: Path) -> tuple[list[str], list[str]]:
    """The compile command of `isa`'s check and the command that runs it; skips the test when
    this machine has no way to build or execute that variant."""
    host = platform.machine().lower()
    if isa == "neon" and host not in ("aarch64", "arm64"):
        compiler, runner = shutil.which("aarch64-linux-gnu-g++"), shutil.which("qemu-aarch64")
        if compiler is None or runner is None:
            pytest.skip("the NEON check needs aarch64-linux-gnu-g++ and qemu-aarch64 "
                        "(Debian: g++-aarch64-linux-gnu, qemu-user)")
        return [compiler, "-static"], [runner, str(binary)]
    reason = native.isa_unavailable(isa)
    if reason is not None:
        pytest.skip(reason)
    compiler = shutil.which("g++") or shutil.which("c++")
    if compiler is None:
        pytest.skip("no C++ compiler")
    return [compiler], [str(binary)]


def test_every_variant_has_flags_in_cmakelists():
    assert set(variant_flags()) == set(native.ISAS)


@pytest.mark.parametrize("isa", native.ISAS)
def test_simd_operations_match_scalar_arithmetic(isa, tmp_path):
    binary = tmp_path / f"simd_check_{isa}"
    compile_prefix, run = build_and_run_command(isa, binary)
    compiled = subprocess.run(
        [*compile_prefix, *COMMON_FLAGS, *variant_flags()[isa], f'-DSIMD_CHECK_ISA="{isa}"',
         f"-I{ROOT / 'csrc'}", str(SOURCE), "-o", str(binary)],
        capture_output=True, text=True, timeout=300)
    assert compiled.returncode == 0, compiled.stderr
    assert "warning" not in compiled.stderr, compiled.stderr
    result = subprocess.run(run, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    summary = result.stdout.strip().splitlines()[-1]
    assert summary.startswith(f"{isa}: ") and summary.endswith(" 0 failed"), result.stdout
