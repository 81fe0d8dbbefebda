"""Configuration values out of their valid range, and a method's name (issue 30, classes 4 and 5).

Every numeric field of every config a preset holds declares its valid range beside it; a value
outside it, NaN or +-inf, whether from `--set`, `--config` or a preset, stops with one line that
names the key, the value and the range. A run loads from its own saved config.json, whatever
its name, and `--set name=...` is refused (a method's name is its preset's).
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Iterator
from typing import Any

import pytest

from surgsplat.methods.overrides import build_method_config
from surgsplat.errors import SurgsplatError
from surgsplat.fields.gaussian_basis import GaussianBasisConfig
from surgsplat.methods.config import to_dict
from surgsplat.methods.ranges import Range, declared_range
from surgsplat.methods.registry import PRESETS, method_config
from surgsplat.model.component import ComponentConfig
from surgsplat.pipeline.train import train_run
from surgsplat.train.run import read_run_config, run_lock

TRAIN_FAST = ("--iters", "2", "--set", "init.max_points=1500")
"""Settings that keep a training these tests start (before the fix) to a few seconds."""


@dataclasses.dataclass(frozen=True)
class ConfigField:
    """One field of a preset's config: its dotted `--set` key, declaration and value."""

    key: str
    declaration: dataclasses.Field
    annotation: Any
    value: Any


def config_fields(config: Any, prefix: str = "") -> Iterator[ConfigField]:
    """Every field of dataclass `config`, of the dataclasses it holds and of those in its dicts
    (components, loss weights), with its dotted key."""
    hints = typing.get_type_hints(type(config))
    for declaration in dataclasses.fields(config):
        key = f"{prefix}{declaration.name}"
        value = getattr(config, declaration.name)
        yield ConfigField(key, declaration, hints[declaration.name], value)
        entries = value.items() if isinstance(value, dict) else ()
        if dataclasses.is_dataclass(value):
            yield from config_fields(value, f"{key}.")
        for name, entry in entries:
            yield from config_fields(entry, f"{key}.{name}.")


def scalar_types(annotation: Any) -> set[Any]:
    """The scalar types a field's annotation admits (a tuple's elements, a union's options)."""
    origin = typing.get_origin(annotation)
    if origin in (tuple, typing.Union, types.UnionType):
        return {kind for arg in typing.get_args(annotation) if arg is not Ellipsis
                for kind in scalar_types(arg)}
    return {annotation}


def is_numeric(field: ConfigField) -> bool:
    return bool(scalar_types(field.annotation) & {int, float})


def numeric_fields(preset: str) -> list[ConfigField]:
    return [field for field in config_fields(method_config(preset)) if is_numeric(field)]


def outside(valid: Range, integer: bool) -> float:
    """A value just outside `valid` (below it when it has a lower bound)."""
    step = 1 if integer else 0.5
    if math.isfinite(valid.low):
        number = valid.low if not valid.low_included else valid.low - step
    else:
        number = valid.high if not valid.high_included else valid.high + step
    return int(number) if integer else number


def with_value(field: ConfigField, number: float) -> Any:
    """`number` as the JSON value of `field`: in place of a tuple's first element."""
    if isinstance(field.value, tuple):
        return [number, *field.value[1:]]
    return number


def set_error(preset: str, key: str, value: Any) -> str:
    """The one-line error of `--set key=value` on `preset`, as `train` builds its config."""
    with pytest.raises(SurgsplatError) as raised:
        build_method_config(preset, None, [f"{key}={json.dumps(value)}"])
    message = str(raised.value)
    assert "\n" not in message and message.startswith(f"--set.{key}"), message
    return message


# ---- every field ----
def test_every_component_kind_declares_its_ranges():
    """Also the components that no preset uses yet (the package's own: a test may register
    a component of its own)."""
    own = {kind: config for kind, config in ComponentConfig.registry.items()
           if config.__module__.startswith("surgsplat.")}
    undeclared = [f"{kind}.{field.key}" for kind, config in sorted(own.items())
                  for field in config_fields(config())
                  if is_numeric(field) and declared_range(field.declaration) is None]
    assert not undeclared, f"numeric config fields without a declared range: {undeclared}"


@pytest.mark.parametrize("preset", PRESETS)
def test_every_numeric_field_declares_a_range_its_default_is_in(preset):
    fields = numeric_fields(preset)
    assert fields
    undeclared = [field.key for field in fields if declared_range(field.declaration) is None]
    assert not undeclared, f"numeric config fields without a declared range: {undeclared}"
    for field in fields:
        values = field.value if isinstance(field.value, tuple) else (field.value,)
        valid = declared_range(field.declaration)
        assert all(value in valid for value in values), (field.key, field.value, str(valid))


@pytest.mark.parametrize("preset", PRESETS)
def test_every_field_refuses_a_value_out_of_range_nan_and_inf(preset):
    for field in numeric_fields(preset):
        valid = declared_range(field.declaration)
        integer = float not in scalar_types(field.annotation)
        below = outside(valid, integer)
        message = set_error(preset, field.key, with_value(field, below))
        assert f" {below!r} " in message and str(valid) in message, message
        for number in (math.nan, math.inf, -math.inf):
            set_error(preset, field.key, with_value(field, number))


def test_presets_and_saved_configs_are_checked_too(tmp_path):
    """The same check covers a config file and a run's saved config.json."""
    saved = to_dict(method_config("deform3dgs"))
    saved["densify"]["every"] = 0
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps(saved))
    with pytest.raises(SurgsplatError, match=r"config.json.densify.every: 0 is out of range; "
                                             r"expected an integer in \[1, inf\)"):
        read_run_config(run)


# ---- the examples of the issue, through the CLI ----
@pytest.mark.parametrize("assignment, shown", [
    ("densify.every=0", "densify.every: 0 is out of range; expected an integer in [1, inf)"),
    ("train.checkpoint_every=0", "train.checkpoint_every: 0 is out of range"),
    ("init.pixel_stride=0", "init.pixel_stride: 0 is out of range"),
    ("gaussians.sh_degree=99", "gaussians.sh_degree: 99 is out of range; expected an integer "
                               "in [0, 3]"),
    ("gaussians.init_opacity=2", "gaussians.init_opacity: 2.0 is out of range; expected a "
                                 "finite number in (0, 1)"),
    ("init.max_points=0", "init.max_points: 0 is out of range"),
    ("train.tool_mask_offset_px=100000", "train.tool_mask_offset_px: 100000 is out of range"),
    ("losses.depth.weight=-1", "losses.depth.weight: -1.0 is out of range; expected a finite "
                               "number in [0, inf)"),
    ("train.checkpoint_seconds=1e999", "train.checkpoint_seconds: inf is out of range"),
    ("losses.photometric.weight=NaN", "losses.photometric.weight: nan is out of range"),
])
def test_out_of_range_settings_stop_with_one_line(assignment, shown, small_phantom, tmp_path,
                                                  cli, one_error_line):
    result = cli("train", "--data", str(small_phantom), "--out", str(tmp_path / "run"),
                 *TRAIN_FAST, "--set", assignment)
    assert shown in one_error_line(result)
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_zero_iterations_are_refused_like_iters_0(small_phantom, tmp_path, cli, one_error_line):
    result = cli("train", "--data", str(small_phantom), "--out", str(tmp_path / "run"),
                 "--set", "train.iterations=0")
    assert "train.iterations: 0 is out of range" in one_error_line(result)


@pytest.mark.parametrize("suffix, text, shown", [
    (".json", '{"losses": {"depth": {"weight": NaN}}}', "losses.depth.weight: nan"),
    (".json", '{"train": {"checkpoint_seconds": Infinity}}', "train.checkpoint_seconds: inf"),
    (".json", '{"train": {"background": [0, -Infinity, 0]}}', "train.background: -inf"),
    (".toml", "[densify]\ngrad_threshold = nan\n", "densify.grad_threshold: nan"),
])
def test_config_files_cannot_bring_nan_or_infinity(suffix, text, shown, small_phantom, tmp_path,
                                                   cli, one_error_line):
    path = tmp_path / f"settings{suffix}"
    path.write_text(text)
    result = cli("train", "--data", str(small_phantom), "--out", str(tmp_path / "run"),
                 *TRAIN_FAST, "--config", str(path))
    line = one_error_line(result)
    assert f"{path}.{shown} is out of range" in line, line


# ---- a method's name ----
@pytest.mark.parametrize("name", ["my-label", "physiosplat"])
def test_the_name_is_the_presets(name, small_phantom, tmp_path, cli, one_error_line):
    result = cli("train", "--method", "deform3dgs", "--data", str(small_phantom), "--out",
                 str(tmp_path / "run"), *TRAIN_FAST, "--set", f"name={name}")
    line = one_error_line(result)
    assert f"--set.name: names method {name!r}, but the preset is 'deform3dgs'" in line, line


def test_a_saved_config_loads_from_itself_whatever_its_name(tmp_path):
    """A config.json naming no preset (a run from before the name was fixed) loads from its own
    values, not from a preset looked up by name."""
    config = dataclasses.replace(method_config("deform3dgs"), name="my-label")
    config.gaussians.sh_degree = 2
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps(to_dict(config)))
    loaded = read_run_config(run)
    assert loaded == config
    assert isinstance(loaded.components["deformation"], GaussianBasisConfig)


def test_a_run_with_any_name_evaluates_exports_and_reports(small_phantom, tmp_path, cli):
    run = tmp_path / "run"
    config = build_method_config("deform3dgs", None, ["init.max_points=1500"])
    with run_lock(run, create=True):
        train_run(dataclasses.replace(config, name="my-label"), small_phantom, run, resume=False,
                  iterations=2)
    for args in (("eval", str(run), "--no-geometry"),
                 ("export", str(run), "--ply", "--frames", "0", "--out", str(tmp_path / "ply")),
                 ("report", str(run), "--out", str(tmp_path / "report.html"))):
        result = cli(*args)
        assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert json.loads((run / "metrics.json").read_text())["method"] == "my-label"
