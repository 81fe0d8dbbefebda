"""Lazy access to the compiled kernels (`surgsplat/render/_native*.so`, built from csrc/).

`import surgsplat` never fails because of them: when the module is missing, `native_module()`
returns None after one clear warning, and every op falls back to its PyTorch reference.
"""

from __future__ import annotations

import functools
import warnings
from types import ModuleType
from typing import Literal

import torch
from torch import Tensor

Backend = Literal["auto", "native", "reference"]
"""Which implementation of an op runs: `auto` is native when it can run the inputs."""


@functools.cache
def native_module() -> ModuleType | None:
    """The compiled module, or None (with one warning) when it is not built."""
    try:
        from surgsplat.render import _native
    except ImportError as err:
        warnings.warn(f"surgsplat: the native CPU rasterizer is not available ({err}); using the "
                      "PyTorch reference, which is orders of magnitude slower. Reinstall with "
                      "`make install` to build it.", RuntimeWarning, stacklevel=2)
        return None
    return _native


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
