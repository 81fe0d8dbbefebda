"""surgsplat: 4D Gaussian-splat reconstruction of endoscopic surgical video on the CPU."""

import os as _os
import sys as _sys
import warnings as _warnings

# Torch and the native kernels share one OpenMP runtime (libgomp), whose idle threads spin for a
# while after each parallel region. On a machine shared with other work, spinning threads take
# the cores that the main thread and the other work need (on 2 cores, a training run with a
# competing process took 14.1 s instead of about 10 s). Passive waiting makes idle threads sleep.
# libgomp reads the policy once, when torch loads it: it is set here when surgsplat is imported
# before torch (the `surgsplat` command does so); a user's own OMP_WAIT_POLICY or GOMP_SPINCOUNT
# is kept. OPENMP_WAIT_POLICY is the policy the runtime was started with.
_USER_CHOSE_POLICY = "OMP_WAIT_POLICY" in _os.environ or "GOMP_SPINCOUNT" in _os.environ
if "torch" in _sys.modules:
    OPENMP_WAIT_POLICY = _os.environ.get("OMP_WAIT_POLICY", "(unset: idle threads spin)")
    if not _USER_CHOSE_POLICY:
        _warnings.warn(
            "torch was imported before surgsplat, so OpenMP's idle threads spin after each "
            "parallel region and slow training on a busy machine; import surgsplat first, or set "
            "OMP_WAIT_POLICY=PASSIVE before starting Python", RuntimeWarning, stacklevel=2)
else:
    if not _USER_CHOSE_POLICY:
        _os.environ["OMP_WAIT_POLICY"] = "PASSIVE"
    OPENMP_WAIT_POLICY = _os.environ.get("OMP_WAIT_POLICY", "(unset: GOMP_SPINCOUNT)")

__version__ = "0.1.0"
