"""Lazy access to the compiled kernels (`surgsplat/render/_native*.so`, built from csrc/).

`import surgsplat` never fails because of them: when the module is missing, `native_module()`
returns None after one clear warning, and the rasterizer falls back to the PyTorch reference.
"""

from __future__ import annotations

import functools
import warnings
from types import ModuleType


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
