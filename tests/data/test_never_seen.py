"""Tissue no frame shows: found for a static camera, refused for a moving one, and filled with
the depth and colour continued from around it (a plane and a colour ramp filled within stated
tolerances)."""

import torch

from surgsplat.data.never_seen import fill_never_seen, never_seen_pixels
from surgsplat.data.scene import Camera, Frame

H, W = 32, 48


def frame(index: int, tool_columns: tuple[int, int], shift: float = 0.0) -> Frame:
    """A frame of a tilted plane (depth 50 + 0.2 x column) with a colour ramp along the columns
    and a tool over `tool_columns` (first, last + 1), its camera shifted by `shift` along x."""
    columns = torch.arange(W, dtype=torch.float32).expand(H, W)
    image = torch.stack([columns / W, 0.5 * torch.ones(H, W), 1 - columns / W], dim=-1)
    tool = torch.zeros(H, W, dtype=torch.bool)
    tool[:, tool_columns[0]:tool_columns[1]] = True
    pose = torch.eye(4)
    pose[0, 3] = shift
    camera = Camera(K=torch.eye(3), world_to_camera=pose, width=W, height=H)
    return Frame(index=index, time=index / 3, image=image, depth=50 + 0.2 * columns,
                 is_test=False, camera=camera, tool=tool, fov=torch.ones(H, W, dtype=torch.bool))


def test_the_pixels_under_the_tool_in_every_frame_are_never_seen():
    frames = [frame(0, (20, 30)), frame(1, (22, 34)), frame(2, (18, 28))]
    region = never_seen_pixels(frames)
    assert region[:, 22:28].all() and region.sum() == 6 * H
    assert never_seen_pixels([frame(0, (20, 30)), frame(1, (20, 30), shift=2.0)]) is None
    assert never_seen_pixels([]) is None


def test_the_hole_is_filled_with_the_plane_and_the_ramp_around_it():
    """Tolerances: depth within 0.6 (the plane varies by 1.2 across the 6-column hole), colour
    within 0.08 (the ramp by 0.125 across it)."""
    frames = [frame(0, (20, 30)), frame(1, (22, 34)), frame(2, (18, 28))]
    filled = fill_never_seen(frames, {f.index: f.depth for f in frames})
    hole = filled.never_seen
    truth = frames[0]
    assert (filled.depth[hole] - truth.depth[hole]).abs().max() < 0.6
    assert (filled.colour[hole] - truth.image[hole]).abs().max() < 0.08
    seen = ~hole
    torch.testing.assert_close(filled.depth[seen], truth.depth[seen])
    torch.testing.assert_close(filled.colour[seen], truth.image[seen], atol=1 / 255, rtol=0)
    assert fill_never_seen([frame(0, (0, 0))], {0: truth.depth}) is None  # nothing hidden
