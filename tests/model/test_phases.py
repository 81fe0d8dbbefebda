"""Components are applied in the order of their phases, whatever the order of the config; an
order that cannot be decided is refused in one line."""

from __future__ import annotations

import copy

import pytest
import torch

from surgsplat.data.scene import load_scene
from surgsplat.errors import SurgsplatError
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.model.component import Component, FrameTime, SceneInfo
from surgsplat.model.dynamic import SplatModel
from surgsplat.model.gaussians import GaussianConfig, GaussianModel
from surgsplat.model.phases import PHASES, Phase, declare_phase, order_by_phase, phase_order
from surgsplat.train.checkpoint import build_components
from surgsplat.train.trainer import Trainer

SCENE = SceneInfo(num_frames=16, width=160, height=128, train_indices=tuple(range(0, 16, 2)))


class Stage(Component):
    """A component of a given phase whose transform maps each opacity o to p o + p, p its own
    prime: the composition shows the order the stages were applied in."""

    def __init__(self, phase: Phase | str | None, prime: float):
        super().__init__()
        self.phase = phase
        self.prime = prime

    def transform(self, state, gaussians, when):
        return state.replace(opacities=state.opacities * self.prime + self.prime)


def test_components_are_ordered_by_phase_and_shared_phases_keep_the_given_order():
    stages = {"loss_b": Stage(Phase.LOSS, 2.0), "tool": Stage("tool", 3.0),
              "loss_a": Stage(Phase.LOSS, 5.0), "anchor": Stage(Phase.ANCHOR, 7.0),
              "deformation": Stage(Phase.DEFORMATION, 11.0)}
    assert list(order_by_phase(stages)) == ["anchor", "deformation", "tool", "loss_b", "loss_a"]
    gaussians = GaussianModel.from_points(torch.rand(3, 3), torch.rand(3, 3), GaussianConfig())
    model = SplatModel(gaussians, stages)
    opacity = torch.sigmoid(gaussians.params["opacity_logits"].detach())
    for name in ("anchor", "deformation", "tool", "loss_b", "loss_a"):
        opacity = opacity * stages[name].prime + stages[name].prime
    torch.testing.assert_close(model.state_at(FrameTime(0, 0.0)).opacities.detach(), opacity)


@pytest.mark.parametrize("name", list(PRESETS))
def test_every_preset_lists_its_components_in_phase_order(name):
    """The presets list their components in the order they act, the order every run saved
    before components had phases holds in its config.json: such a run loads to the model it
    was trained as."""
    config = method_config(name).resolved(SCENE)
    assert list(build_components(config)) == list(config.components)


def tiny(config, iterations: int = 6):
    config.train.iterations = iterations
    config.train.checkpoint_every = 1000
    config.init.max_points = 600
    config.densify.start, config.densify.every = 0.0, 3
    return config


def test_the_phase_not_the_config_decides_the_order(small_phantom, tmp_path):
    """deform3dgs with its components listed out of phase order trains to exactly the preset's
    numbers (its two losses keep their order: photometric, then depth)."""
    scene = load_scene(small_phantom)
    preset = tiny(method_config("deform3dgs"))
    scrambled = copy.deepcopy(preset)
    scrambled.components = {name: scrambled.components[name]
                            for name in ("exposure", "photometric", "color_curves",
                                         "deformation", "depth")}
    runs = [Trainer(config, scene, tmp_path / str(number))
            for number, config in enumerate((preset, scrambled))]
    for run in runs:
        run.fit()
    assert list(runs[1].model.components) == list(preset.components)
    for name, value in runs[0].model.gaussians.params.items():
        assert torch.equal(runs[1].model.gaussians.params[name], value), name


def test_two_components_of_a_phase_that_takes_one_are_refused_in_one_line():
    config = method_config("deform3dgs")
    config.components["second"] = HexPlaneConfig()
    with pytest.raises(SurgsplatError) as refused:
        build_components(config.resolved(SCENE))
    message = str(refused.value)
    assert "\n" not in message
    assert "'deformation' and 'second' both have the phase deformation" in message
    with pytest.raises(SurgsplatError, match=r"^component 'odd' \(Stage\) declares the phase "
                                             r"None; .* a declared phase: anchor, deformation, "
                                             r"appearance, tool"):
        order_by_phase({"odd": Stage(None, 1.0)})


@pytest.fixture
def declared_phases():
    """The declared phases, restored after the test."""
    saved = dict(PHASES)
    yield PHASES
    PHASES.clear()
    PHASES.update(saved)


def test_a_phase_declared_between_two_orders_its_component_there(declared_phases):
    declare_phase("glaze", after=(Phase.SHADING,), before=(Phase.LOSS,))
    order = phase_order()
    assert order.index("shading") < order.index("glaze") < order.index("loss")
    stages = {"loss": Stage(Phase.LOSS, 2.0), "glaze": Stage("glaze", 3.0),
              "shade": Stage(Phase.SHADING, 5.0)}
    assert list(order_by_phase(stages)) == ["shade", "glaze", "loss"]


def test_a_phase_that_cannot_be_placed_is_refused_and_not_kept(declared_phases):
    with pytest.raises(SurgsplatError, match="undeclared phase 'nowhere'"):
        declare_phase("lost", after=("nowhere",))
    with pytest.raises(SurgsplatError, match="circular"):
        declare_phase("loop", after=(Phase.LOSS,), before=(Phase.ANCHOR,))
    with pytest.raises(SurgsplatError, match="'tool' is declared already"):
        declare_phase("tool")
    assert "lost" not in PHASES and "loop" not in PHASES
    assert phase_order() == tuple(Phase)


@pytest.mark.slow
def test_the_cli_refuses_an_impossible_order_in_one_line(small_phantom, tmp_path, cli,
                                                         one_error_line):
    line = one_error_line(cli("train", "--method", "deform3dgs", "--data", str(small_phantom),
                              "--out", str(tmp_path / "run"), "--iters", "1", "--set",
                              'components.second={"kind": "hexplane"}'))
    assert "both have the phase deformation" in line
