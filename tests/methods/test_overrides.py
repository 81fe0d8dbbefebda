"""Method configs: presets, type-checked overrides, config files, and the config.json round trip."""

from __future__ import annotations

import json

import pytest

from surgsplat.errors import DataError, SurgsplatError
from surgsplat.fields.hexplane import HexPlaneConfig
from surgsplat.methods.config import to_dict
from surgsplat.methods.overrides import (apply_values, method_from_values, parse_assignment,
                                         read_config_file)
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.model.component import SceneInfo

SCENE = SceneInfo(num_frames=10, width=160, height=128, train_indices=tuple(range(8)))


def test_every_preset_has_a_description_and_round_trips_through_json():
    for name, preset in PRESETS.items():
        assert preset.description
        config = preset.build()
        saved = json.loads(json.dumps(to_dict(config)))
        assert method_from_values(saved, method_config(name), "saved") == config


def test_assignments_are_parsed_as_json_and_typed():
    config = method_config("endoplanar")
    config = apply_values(config, parse_assignment("losses.normal.weight=0.1"), "--set")
    config = apply_values(config, parse_assignment("train.iterations=5000"), "--set")
    config = apply_values(config, parse_assignment("init.fusion=mapf"), "--set")
    config = apply_values(config, parse_assignment("train.background=[1, 0, 0.5]"), "--set")
    assert config.losses["normal"].weight == 0.1 and isinstance(config.losses["normal"].weight, float)
    assert config.train.iterations == 5000 and config.init.fusion == "mapf"
    assert config.train.background == (1.0, 0.0, 0.5)


@pytest.mark.parametrize("text, message", [
    ("train.iteration=5", r"--set.train: unknown setting 'iteration'"),
    ("train.iterations=5.5", r"--set.train.iterations: expected an integer"),
    ("train.iterations=many", r"--set.train.iterations: expected an integer"),
    ("losses.normal.weight=true", r"--set.losses.normal.weight: expected a number"),
    ("init.fusion=magic", r"--set.init.fusion: expected one of"),
    ("train.background=[1, 0]", r"--set.train.background: expected 3 values"),
    ("components.planar.edge_aware=1", r"--set.components.planar.edge_aware: expected true"),
    ("components.extra.weight=1", r"--set.components.extra: a new component needs a 'kind'"),
    ("novalue", r"expected KEY=VALUE"),
])
def test_bad_overrides_name_the_key(text, message):
    with pytest.raises(SurgsplatError, match=message):
        apply_values(method_config("endoplanar"), parse_assignment(text), "--set")


def test_components_can_be_added_swapped_and_removed():
    config = method_config("deform3dgs")
    swapped = apply_values(config, {"components": {"deformation": {"kind": "hexplane",
                                                                   "feature_dim": 8}}}, "f")
    assert isinstance(swapped.components["deformation"], HexPlaneConfig)
    assert swapped.components["deformation"].feature_dim == 8
    removed = apply_values(config, parse_assignment("components.exposure=null"), "--set")
    assert "exposure" not in removed.components
    added = apply_values(config, {"components": {"planar": {"kind": "planar"}},
                                  "losses": {"normal": {"weight": 0.2}}}, "f")
    assert added.components["planar"].kind == "planar"
    assert added.losses["normal"].weight == 0.2 and added.losses["normal"].start == 0
    with pytest.raises(SurgsplatError, match="unknown component kind 'nope'"):
        apply_values(config, {"components": {"x": {"kind": "nope"}}}, "f")


def test_resolving_is_a_copy_and_idempotent():
    config = method_config("deform3dgs")
    resolved = config.resolved(SCENE)
    assert config.components["deformation"].num_basis == 8  # the input is unchanged
    assert resolved.components["deformation"].num_basis == 5  # one basis per two frames
    assert resolved.init.max_points == int(0.25 * 160 * 128) // 2
    assert resolved.resolved(SCENE) == resolved


def test_config_files_json_and_toml(tmp_path):
    toml = tmp_path / "run.toml"
    toml.write_text('name = "endoplanar"\n[train]\niterations = 123\n'
                    '[losses.normal]\nweight = 0.3\n')
    values = read_config_file(toml)
    config = method_from_values(values, method_config("endoplanar"), str(toml))
    assert config.train.iterations == 123 and config.losses["normal"].weight == 0.3
    saved = tmp_path / "config.json"
    saved.write_text(json.dumps(to_dict(config)))
    assert method_from_values(read_config_file(saved), method_config("endoplanar"),
                              "saved") == config
    with pytest.raises(SurgsplatError, match="names method 'endoplanar', but the preset is"):
        method_from_values(values, method_config("deform3dgs"), str(toml))
    (tmp_path / "bad.toml").write_text("[train\n")
    with pytest.raises(DataError, match="bad.toml: cannot be read as a config file"):
        read_config_file(tmp_path / "bad.toml")
    (tmp_path / "c.yaml").write_text("a: 1")
    with pytest.raises(DataError, match="expected a .json or .toml"):
        read_config_file(tmp_path / "c.yaml")
    with pytest.raises(DataError, match="config file not found"):
        read_config_file(tmp_path / "missing.json")


def test_a_saved_config_without_a_component_loads_without_it():
    """A run trained with a component removed (--set components.X=null) is rebuilt from its
    saved config.json without it; partial values (--config) still merge into the preset."""
    changed = apply_values(method_config("physiosplat"),
                           parse_assignment("components.specular=null"))
    changed = apply_values(changed, parse_assignment("losses.strain=null"))
    saved = json.loads(json.dumps(to_dict(changed)))
    loaded = method_from_values(saved, method_config("physiosplat"), "config.json", complete=True)
    assert "specular" not in loaded.components and "strain" not in loaded.losses
    assert to_dict(loaded) == to_dict(changed)
    partial = method_from_values({"losses": {"mask": {"weight": 0.5}}},
                                 method_config("physiosplat"), "extra.toml")
    assert "specular" in partial.components and partial.losses["mask"].weight == 0.5
