"""The component contract stays small: at most CONTRACT_LIMIT hooks, each implemented by at least
two of surgsplat's components; what only some components offer is a capability protocol
(`model.capabilities`), declared in `Component.provides` and implemented by the component
itself, which the model finds by protocol."""

from __future__ import annotations

import pytest
import torch

from surgsplat.errors import SurgsplatError
from surgsplat.methods.registry import PRESETS  # noqa: F401  (imports every method's components)
from surgsplat.model import capabilities
from surgsplat.model.camera_refine import CameraRefine, CameraRefineConfig
from surgsplat.model.capabilities import CameraCorrection, HeldOutPoses, OpacityFactor
from surgsplat.model.component import Component, provider, providers
from surgsplat.model.phases import Phase

CONTRACT_LIMIT = 14


def hooks() -> list[str]:
    return sorted(name for name, value in vars(Component).items()
                  if callable(value) and not name.startswith("_"))


def component_classes() -> list[type[Component]]:
    """Every Component subclass defined in surgsplat."""
    found, pending = [], list(Component.__subclasses__())
    while pending:
        cls = pending.pop()
        pending += cls.__subclasses__()
        if cls.__module__.startswith("surgsplat."):
            found.append(cls)
    return found


def protocol_methods(protocol: type) -> list[str]:
    return [name for name, value in vars(protocol).items()
            if callable(value) and not name.startswith("_")]


def test_the_contract_has_at_most_the_limit_of_hooks():
    assert 0 < len(hooks()) <= CONTRACT_LIMIT, hooks()


def test_every_hook_has_two_implementers():
    classes = component_classes()
    assert len(classes) >= 10  # the methods' packages were imported
    lonely = {hook: [cls.__name__ for cls in classes if hook in vars(cls)] for hook in hooks()}
    assert not {hook: names for hook, names in lonely.items() if len(names) < 2}


def declared(cls: type[Component]) -> tuple[type, ...]:
    """What a component class provides; a property is read off an instance of the class with
    every capability switched on."""
    if isinstance(cls.__dict__.get("provides"), property):
        assert cls is CameraRefine, cls
        return CameraRefineConfig(num_frames=2, test_time_steps=1).build().provides
    return cls.provides


def test_every_declared_capability_is_a_protocol_the_component_implements():
    protocols = {value for value in vars(capabilities).values()
                 if isinstance(value, type) and getattr(value, "_is_protocol", False)}
    offered = {cls: declared(cls) for cls in component_classes() if declared(cls)}
    assert len(offered) >= 5
    for cls, provided in offered.items():
        for protocol in provided:
            assert protocol in protocols, (cls.__name__, protocol)
            missing = [name for name in protocol_methods(protocol) if not hasattr(cls, name)]
            assert not missing, (cls.__name__, protocol.__name__, missing)


class Factor(Component):
    phase = Phase.OPACITY
    provides = (OpacityFactor,)

    def opacity_factor(self, gaussians):
        return torch.ones(1)


def test_the_model_finds_a_capability_by_protocol_and_refuses_two_of_one():
    plain, first, second = Component(), Factor(), Factor()
    assert providers([plain, first, second], OpacityFactor) == [first, second]
    assert provider([plain, first], OpacityFactor) is first
    assert provider([plain], OpacityFactor) is None
    with pytest.raises(SurgsplatError, match="components Factor, Factor each provide "
                                             "OpacityFactor; a method may have one"):
        provider([first, second], OpacityFactor)


def test_a_capability_can_depend_on_the_config():
    fitting = CameraRefineConfig(num_frames=2, test_time_steps=1).build()
    fixed = CameraRefineConfig(num_frames=2, test_time_steps=0).build()
    assert provider([fitting], HeldOutPoses) is fitting
    assert provider([fixed], HeldOutPoses) is None
    assert provider([fixed], CameraCorrection) is fixed
