"""The phantom's ray caster and motions, without files."""

import numpy as np
import pytest

from surgsplat.data.phantom import PRESETS
from surgsplat.data.phantom.raycast import NEAR_MM
from surgsplat.data.phantom.scene import PhantomScene

SMALL = PRESETS["small"]


@pytest.mark.parametrize("motion", ["pulling", "cutting", "grasping"])
def test_tissue_hit_is_the_first_along_each_ray(motion: str):
    """z - h(z xn, z yn) < 0 at 48 depths in front of every 3rd pixel's hit, and the surface
    faces the camera (the residual increases through the hit) at every pixel of every frame."""
    scene = PhantomScene(SMALL.width, SMALL.height, SMALL.focal, 16, motion, seed=3)
    xn, yn = scene.xn[::3, ::3], scene.yn[::3, ::3]
    directions = np.stack([scene.xn, scene.yn, np.ones_like(scene.xn)], axis=-1)
    for index in range(16):
        frame = scene.render(index)
        assert (np.einsum("hwi,hwi->hw", frame.normals, directions) < 0).all()
        hit = frame.tissue_depth[::3, ::3].astype(np.float64)
        for fraction in np.linspace(0.0, 0.999, 48):
            z = NEAR_MM + fraction * (hit - NEAR_MM)
            t = scene.time(index)
            assert (z - scene.surface.height(z * xn, z * yn, t) < 1e-4).all()


def test_cutting_opens_a_groove():
    scene = PhantomScene(SMALL.width, SMALL.height, SMALL.focal, 16, "cutting", seed=0)
    start, end = scene.render(0), scene.render(15)
    deeper = end.tissue_depth - start.tissue_depth  # mm
    assert deeper.max() > 2.5  # the groove, well beyond breathing
    assert np.median(np.abs(deeper)) < 2.5  # most tissue only breathes
    opened = scene.surface.opening(end.tissue_depth * scene.xn, end.tissue_depth * scene.yn,
                                   scene.time(15))
    assert opened.max() > 0.9 and (opened > 0.5).mean() < 0.2
    green_drop = (start.albedo - end.albedo)[..., 1][opened > 0.5]
    assert green_drop.mean() > 0.05  # cut tissue is a deeper red


def test_tool_enters_then_grasps():
    scene = PhantomScene(SMALL.width, SMALL.height, SMALL.focal, 16, "pulling", seed=0)
    assert not scene.render(0).tool_mask.any()  # still out of view
    assert scene.render(8).tool_mask.any()
    assert scene.tool_pose(0.0).jaw_deg > 20.0 and scene.tool_pose(0.5).jaw_deg == 0.0


def test_grasping_keeps_the_tool_in_view_and_opens_its_jaws_wide():
    """Every frame shows the tool; the jaws open to 60 degrees and close; the same pixels stay
    under the tool in every frame (tissue that is never seen)."""
    scene = PhantomScene(SMALL.width, SMALL.height, SMALL.focal, 32, "grasping", seed=0)
    frames = [scene.render(index) for index in range(32)]
    tool = np.stack([frame.tool_mask for frame in frames])
    assert tool.any(axis=(1, 2)).all()
    assert tool.all(axis=0).any()
    openings = [scene.tool_pose(scene.time(index)).jaw_deg for index in range(32)]
    assert max(openings) > 55 and min(openings) < 5
