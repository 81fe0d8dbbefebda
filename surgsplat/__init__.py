"""surgsplat: 4D Gaussian-splat reconstruction of endoscopic surgical video on the CPU."""

__version__ = "0.1.0"
