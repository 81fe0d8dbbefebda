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


def view(frame: Frame, probability: torch.Tensor | None, depth: torch.Tensor,
         tissue_depth: torch.Tensor | None = None):
    """A FrameView's parts the family reads; `tissue_depth`, when given, is the depth of the
    render of a model that separates the tool with the tool left out."""
    extras = {} if probability is None else {"tool_probability": probability[..., None]}
    model = SimpleNamespace(separates_tool=tissue_depth is not None)
    return SimpleNamespace(frame=frame, run=SimpleNamespace(model=model),
                           render=SimpleNamespace(extras=extras, depth=depth),
                           tissue_render=SimpleNamespace(depth=tissue_depth))


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
    assert "tissue_depth_bias_near_tool" not in row  # the model does not separate the tool


def test_the_tissue_alone_has_its_own_bias_beside_the_tool():
    truth = torch.full((H, W), 50.0)
    rendered, tissue = truth - 0.8, truth.clone()
    tissue[:, 10:20] += 0.3  # hidden under the rendered tool's rim: pushed deeper
    row = family().score(view(frame_with_tool(truth), None, rendered, tissue_depth=tissue))
    assert row["depth_bias_near_tool"] == pytest.approx(-0.8, abs=1e-5)
    assert row["tissue_depth_bias_near_tool"] == pytest.approx(0.3, abs=1e-5)


def test_a_frame_without_tool_pixels_is_not_scored():
    frame = Frame(index=1, time=0.5, image=torch.zeros(H, W, 3), depth=None, is_test=True,
                  camera=None, tool=torch.zeros(H, W, dtype=torch.bool),
                  fov=torch.ones(H, W, dtype=torch.bool))
    assert family().score(view(frame, torch.zeros(H, W), torch.zeros(H, W))) == {}
