"""Ground-truth phantom: a synthetic deforming tissue with a tool, ray-cast in numpy.

An independent renderer (not Gaussian splatting) so that it can judge one: see `generate` for
the files written and `scene` for what is rendered.
"""

from surgsplat.data.phantom.generate import PRESETS, PhantomConfig, generate_phantom
from surgsplat.data.phantom.motion import MOTIONS

__all__ = ["MOTIONS", "PRESETS", "PhantomConfig", "generate_phantom"]
