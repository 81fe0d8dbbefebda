"""The tool's edge and the tissue beside it (ToolEdgeFamily): the rendered tool probability over
the mask and on rings of tissue at 3 and 10 px from it, and the depth bias of the tissue within
10 px of the tool against the tissue beyond. Exact values on a synthetic frame."""

from types import SimpleNamespace

import pytest
import torch

from surgsplat.data.scene import Frame
from surgsplat.eval.render_families import ToolEdgeFamily

H, W = 40, 60


def frame_with_tool(depth: torch.Tensor | None) -> Frame:
    """A frame whose tool is the columns 0..9 (the whole height), all in the field of view."""
    tool = torch.zeros(H, W, dtype=torch.bool)
    tool[:, :10] = True
    return Frame(index=1, time=0.5, image=torch.zeros(H, W, 3), depth=depth, is_test=True,
                 camera=None, tool=tool, fov=torch.ones(H, W, dtype=torch.bool))


def view(frame: Frame, probability: torch.Tensor | None, depth: torch.Tensor):
    extras = {} if probability is None else {"tool_probability": probability[..., None]}
    return SimpleNamespace(frame=frame, render=SimpleNamespace(extras=extras, depth=depth))


def family() -> ToolEdgeFamily:
    return ToolEdgeFamily(run=None, options=None)


def test_tool_probability_is_read_inside_the_mask_and_on_the_rings():
    columns = torch.arange(W, dtype=torch.float32).expand(H, W)
    # 0.8 on the tool; beside it, a value that names the column: column 12 is 3 px from the tool
    # (the last tool column is 9), column 19 is 10 px
    probability = torch.where(columns < 10, torch.tensor(0.8), columns / 100.0)
    row = family().score(view(frame_with_tool(None), probability, torch.zeros(H, W)))
    assert row["tool_probability_inside"] == pytest.approx(0.8, abs=1e-6)
    assert row["tool_probability_3px"] == pytest.approx(0.12, abs=1e-6)
    assert row["tool_probability_10px"] == pytest.approx(0.19, abs=1e-6)
    assert not any(key.startswith("depth_bias") for key in row)  # no depth in the scene


def test_depth_bias_tells_the_tissue_beside_the_tool_from_the_rest():
    truth = torch.full((H, W), 50.0)
    rendered = truth.clone()
    rendered[:, 10:20] += 0.5  # columns 10..19: within 10 px of the tool
    rendered[:, 20:] -= 0.1
    row = family().score(view(frame_with_tool(truth), None, rendered))
    assert row["depth_bias_near_tool"] == pytest.approx(0.5, abs=1e-5)
    assert row["depth_bias_away_from_tool"] == pytest.approx(-0.1, abs=1e-5)
    assert not any(key.startswith("tool_probability") for key in row)  # no tool channel


def test_a_frame_without_tool_pixels_is_not_scored():
    frame = Frame(index=1, time=0.5, image=torch.zeros(H, W, 3), depth=None, is_test=True,
                  camera=None, tool=torch.zeros(H, W, dtype=torch.bool),
                  fov=torch.ones(H, W, dtype=torch.bool))
    assert family().score(view(frame, torch.zeros(H, W), torch.zeros(H, W))) == {}
