"""Lazy access to the compiled kernels (`surgsplat/render/_native_<isa>*.so`, built from csrc/).

The kernels are built once per instruction set (CMakeLists.txt): `avx512` (x86-64-v4), `avx2`
(x86-64-v3), `baseline` (x86-64, SSE2) on x86-64 and `neon` on aarch64. `native_module()` gives
the variant in use: the one the environment variable SURGSPLAT_ISA names, else the fastest the
CPU runs (asked of the portable variant, `baseline` or `neon`, which runs everywhere).
`use_isa()` switches variants at run time (the tests run every kernel on every variant).

`import surgsplat` never fails because of them: when no variant is built, `native_module()`
returns None after one clear warning, and every op falls back to its PyTorch reference.
"""

from __future__ import annotations

import functools
import importlib
import os
import platform
import warnings
from types import ModuleType
from typing import Literal

import torch
from torch import Tensor

import surgsplat

Backend = Literal["auto", "native", "reference"]
"""Which implementation of an op runs: `auto` is native when it can run the inputs."""

ISAS = ("avx512", "avx2", "baseline", "neon")
"""The ISA variants of the native module, fastest first."""

ISA_ENV = "SURGSPLAT_ISA"
"""Environment variable naming the ISA variant to use instead of the fastest available."""

_PORTABLE = {"x86_64": "baseline", "amd64": "baseline", "aarch64": "neon", "arm64": "neon"}

_chosen: str | None = None  # set by use_isa(); None: SURGSPLAT_ISA or the fastest


def _import_variant(isa: str) -> ModuleType:
    return importlib.import_module(f"surgsplat.render._native_{isa}")


@functools.cache
def _portable() -> tuple[ModuleType | None, str]:
    """The portable variant of this architecture, or None and why it is missing."""
    isa = _PORTABLE.get(platform.machine().lower())
    if isa is None:
        return None, f"no native kernels for the {platform.machine()} architecture"
    try:
        return _import_variant(isa), ""
    except ImportError as err:
        return None, str(err)


@functools.cache
def isa_unavailable(isa: str) -> str | None:
    """Why ISA variant `isa` cannot run here (not built, or the CPU lacks it), or None."""
    if isa not in ISAS:
        raise ValueError(f"unknown ISA {isa!r}: expected one of {', '.join(ISAS)}")
    portable, why = _portable()
    if portable is None:
        return f"the native module is not built ({why})"
    if isa not in portable.cpu_isas():
        return f"this CPU ({cpu_model()}) cannot run the {isa} variant"
    try:
        _import_variant(isa)
    except ImportError as err:
        return f"the {isa} variant is not built ({err})"
    return None


def available_isas() -> list[str]:
    """The ISA variants that are built and that this CPU runs, fastest first."""
    return [isa for isa in ISAS if isa_unavailable(isa) is None]


def variant_module(isa: str) -> ModuleType:
    """The compiled module of ISA variant `isa`, whichever variant is in use (ValueError when
    this machine cannot run it): for measuring one variant beside another."""
    if (reason := isa_unavailable(isa)) is not None:
        raise ValueError(reason)
    return _import_variant(isa)


def use_isa(isa: str | None) -> None:
    """Run the native kernels of ISA variant `isa` from now on (None: back to SURGSPLAT_ISA or
    the fastest). ValueError when this machine cannot run it."""
    global _chosen
    if isa is not None and (reason := isa_unavailable(isa)) is not None:
        raise ValueError(reason)
    _chosen = isa
    native_module.cache_clear()


def active_isa() -> str | None:
    """The ISA variant `native_module()` returns, or None when none is built."""
    native = native_module()
    return None if native is None else native.isa


def _requested_isa() -> str | None:
    """The variant asked for by use_isa() or SURGSPLAT_ISA (warning when it cannot run)."""
    if _chosen is not None:
        return _chosen
    requested = os.environ.get(ISA_ENV, "").strip().lower()
    if not requested:
        return None
    reason = isa_unavailable(requested) if requested in ISAS else f"expected one of {ISAS}"
    if reason is None:
        return requested
    warnings.warn(f"surgsplat: {ISA_ENV}={requested} ignored: {reason}", RuntimeWarning,
                  stacklevel=3)
    return None


@functools.cache
def native_module() -> ModuleType | None:
    """The compiled module of the ISA variant in use, or None (with one warning) when it is not
    built. Loading it flushes subnormal floats to zero, for good, in the calling thread and the
    kernels' threads (`flush_subnormals` in csrc/module.cpp says why): the process's float
    arithmetic then treats values below 1.2e-38 as 0."""
    portable, why = _portable()
    if portable is None:
        warnings.warn(f"surgsplat: the native CPU kernels are not available ({why}); using the "
                      "PyTorch reference, which is orders of magnitude slower. Reinstall with "
                      "`make install` to build them.", RuntimeWarning, stacklevel=2)
        return None
    isa = _requested_isa() or available_isas()[0]
    module = _import_variant(isa)
    module.flush_subnormals()
    return module


@functools.cache
def cpu_model() -> str:
    """The CPU's model name (from /proc/cpuinfo on Linux, else the platform's processor)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as info:
            for line in info:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def system_info() -> dict[str, object]:
    """What runs the kernels: CPU model, ISA variant in use and those available, threads of
    torch and of the native kernels, and the OpenMP wait policy."""
    native = native_module()
    return {
        "cpu": cpu_model(),
        "machine": platform.machine(),
        "logical_cpus": os.cpu_count(),
        "isa": None if native is None else native.isa,
        "available_isas": available_isas(),
        "torch_threads": torch.get_num_threads(),
        "native_threads": None if native is None else native.max_threads(),
        "omp_wait_policy": surgsplat.OPENMP_WAIT_POLICY,
    }


def set_threads(threads: int) -> None:
    """Use `threads` threads in torch and in the native kernels."""
    if threads < 1:
        raise ValueError(f"threads: expected at least 1, got {threads}")
    torch.set_num_threads(threads)
    native = native_module()
    if native is not None:
        native.set_threads(threads)


def resolve_backend(op: str, backend: Backend, tensors: list[Tensor]) -> Literal["native",
                                                                              "reference"]:
    """The implementation of `op` that runs `tensors`: native when they are float32 CPU tensors
    and the module has `{op}_forward`, else the reference; errors when `native` was asked for
    and cannot run."""
    if backend == "reference":
        return "reference"
    if any(t.dtype != torch.float32 or t.device.type != "cpu" for t in tensors):
        if backend == "native":
            raise ValueError(f"{op}: the native backend takes float32 CPU tensors")
        return "reference"
    native = native_module()
    if native is None or not hasattr(native, f"{op}_forward"):
        if backend == "native":
            raise RuntimeError(f"{op}: the native module is not built")
        return "reference"
    return "native"


def dense_grad(grad: Tensor | None, shape: tuple[int, ...]) -> Tensor:
    """An upstream gradient as the kernels take it: float32, contiguous, zeros when None."""
    return torch.zeros(shape) if grad is None else grad.contiguous().to(torch.float32)
