"""surgsplat: 4D Gaussian-splat reconstruction of endoscopic surgical video on the CPU."""

import os as _os

# Torch and the native kernels share one OpenMP runtime (libgomp), whose idle threads spin for a
# while after each parallel region. On a machine shared with other work, spinning threads take
# the cores that the main thread and the other work need (on 2 cores, a training run with a
# competing process took 14.1 s instead of about 10 s). Passive waiting makes idle threads sleep.
# libgomp reads this once, when it is loaded: it must be set before torch is imported (the
# `surgsplat` command does so); a user's own OMP_WAIT_POLICY or GOMP_SPINCOUNT is kept.
if "OMP_WAIT_POLICY" not in _os.environ and "GOMP_SPINCOUNT" not in _os.environ:
    _os.environ["OMP_WAIT_POLICY"] = "PASSIVE"

__version__ = "0.1.0"
