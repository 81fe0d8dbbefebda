"""`surgsplat import`'s options and ImportConfig have one source of truth: the options' defaults
are read from the config dataclasses, so the command with no option builds ImportConfig()."""

from __future__ import annotations

import inspect

from surgsplat.cli.import_cmd import import_command, import_config
from surgsplat.data.importer import ImportConfig


def option_defaults() -> dict:
    return {name: parameter.default
            for name, parameter in inspect.signature(import_command).parameters.items()
            if name not in ("source", "out")}


def test_no_option_builds_the_configs_defaults():
    assert import_config(option_defaults()) == ImportConfig()


def test_an_option_reaches_its_field():
    options = {**option_defaults(), "hfov": 80.0, "shading_gamma": 1.0,
               "depth_model_input": "518", "tool_labels": "31,32"}
    config = import_config(options)
    assert config.assumed_hfov_deg == 80.0 and config.shading.gamma == 1.0
    assert config.depth_network.input.short_side == 518 and config.tool_labels == (31, 32)
    assert config.sfm == ImportConfig().sfm
