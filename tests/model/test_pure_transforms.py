"""`Component.transform` is pure for every component of every preset: asked twice on the same
Gaussians it gives the same Gaussians, and it changes no parameter, buffer or attribute of the
model (state changes belong to `before_render` and `after_step`). Checked in a training step
(training mode, gradients on, a training frame) and in an evaluation render."""

from __future__ import annotations

import dataclasses
from itertools import chain

import pytest
import torch

from surgsplat.data.scene import load_scene
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.model.component import FrameTime
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.state import GaussianState
from surgsplat.train.trainer import Trainer

MODULE_STATE = {"_parameters", "_buffers", "_modules"}
"""A module's own dicts of tensors and submodules: compared through their tensors' values."""


def tiny_trainer(name: str, scene, run_dir) -> Trainer:
    config = method_config(name)
    config.init.max_points = 300
    for key, value in (("sdf", {"fit_steps": 30}), ("anchor", {"resolution": 16}),
                       ("tool", {"icp_iterations": 2, "max_points": 200})):
        if key in config.components:
            config.components[key] = dataclasses.replace(config.components[key], **value)
    return Trainer(config, scene, run_dir)


def snapshot(model: SplatModel) -> tuple[dict, dict]:
    """Copies of every tensor of the model (the Gaussians' parameters and buffers, each
    component's) and the identity of every other attribute of each component."""
    tensors = {name: value.detach().clone()
               for name, value in chain(model.named_parameters(), model.named_buffers())}
    attributes = {(name, key): id(value) for name, component in model.components.items()
                  for key, value in vars(component).items()
                  if key not in MODULE_STATE}
    return tensors, attributes


def assert_same_state(first: GaussianState, second: GaussianState, where: str) -> None:
    assert first.sh_degree == second.sh_degree, where
    for field in ("means", "scales", "quats", "opacities", "sh"):
        assert torch.equal(getattr(first, field), getattr(second, field)), f"{where}: {field}"


def assert_transforms_pure(model: SplatModel, when: FrameTime) -> None:
    model.before_render(when)
    state = model.canonical_state()
    for name, component in model.components.items():
        tensors, attributes = snapshot(model)
        first = component.transform(state, model.gaussians, when)
        second = component.transform(state, model.gaussians, when)
        assert_same_state(first, second, name)
        after_tensors, after_attributes = snapshot(model)
        assert after_attributes == attributes, f"{name} replaced an attribute"
        assert after_tensors.keys() == tensors.keys(), f"{name} added or removed a tensor"
        changed = [key for key, value in tensors.items()
                   if not torch.equal(after_tensors[key], value)]
        assert not changed, f"{name}'s transform changed {changed}"
        state = first


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_transform_is_pure(name, small_phantom, tmp_path):
    scene = load_scene(small_phantom)
    model = tiny_trainer(name, scene, tmp_path).model
    train, test = scene.train_frames[1], scene.test_frames[0]
    with torch.enable_grad():
        assert_transforms_pure(model.train(), FrameTime(train.index, train.time))
    with torch.no_grad():
        assert_transforms_pure(model.eval(), FrameTime(test.index, test.time, tissue_only=True))
