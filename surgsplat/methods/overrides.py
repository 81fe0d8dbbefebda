"""Changing a method config from outside: saved config.json files, `--config FILE` (JSON or
TOML) and `--set dotted.key=value`, all type-checked against the config's dataclasses.

Every change goes through `apply_values`: a nested dict is matched key by key against the
dataclass fields, each value is checked against the field's type annotation and its declared
valid range (ranges.py), and the first unknown key, wrong type or value out of range stops with
a SurgsplatError that names the full dotted key. A method's `name` is its preset's: a change of
it is refused (`method_from_values`). Dicts of
configs (`components`, `losses`) take new entries: a component needs its "kind", a loss weight
starts from `LossWeight()`; a value of null removes an entry.
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Literal

from surgsplat.errors import DataError, SurgsplatError
from surgsplat.methods.config import KIND_KEY, MethodConfig
from surgsplat.methods.ranges import check_config, check_field
from surgsplat.methods.registry import DEFAULT_PRESET, method_config  # also registers every kind
from surgsplat.model.component import ComponentConfig


def apply_values(config: Any, values: dict, where: str = "config") -> Any:
    """A copy of dataclass `config` with the nested dict `values` applied (see module doc)."""
    if not isinstance(values, dict):
        raise SurgsplatError(f"{where}: expected a table of settings, got {values!r}")
    hints = typing.get_type_hints(type(config))
    fields = {f.name: f for f in dataclasses.fields(config)}
    changes = {}
    for key, value in values.items():
        if key == KIND_KEY and isinstance(config, ComponentConfig):
            if value != config.kind:
                raise SurgsplatError(f"{where}.{KIND_KEY}: expected {config.kind!r}, got {value!r}")
            continue
        if key not in fields:
            raise SurgsplatError(f"{where}: unknown setting {key!r}; "
                                 f"known: {', '.join(sorted(fields))}")
        changes[key] = _coerce(getattr(config, key), value, hints[key], f"{where}.{key}")
        check_field(fields[key], changes[key], f"{where}.{key}")
    return dataclasses.replace(config, **changes)


def _coerce(current: Any, value: Any, annotation: Any, where: str) -> Any:
    """`value` checked against `annotation` (given the field's `current` value)."""
    if dataclasses.is_dataclass(current) and not isinstance(current, type):
        return apply_values(current, value, where)
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is dict:
        return _coerce_dict(current, value, args[1], where)
    if origin in (typing.Union, types.UnionType):
        for option in args:
            try:
                return _coerce(current, value, option, where)
            except SurgsplatError:
                continue
        raise SurgsplatError(f"{where}: expected {_describe(annotation)}, got {value!r}")
    if origin is Literal:
        if value not in args:
            raise SurgsplatError(f"{where}: expected one of {', '.join(map(repr, args))}, "
                                 f"got {value!r}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise SurgsplatError(f"{where}: expected a list, got {value!r}")
        element_types = [args[0]] * len(value) if args[-1] is Ellipsis else list(args)
        if len(element_types) != len(value):
            raise SurgsplatError(f"{where}: expected {len(element_types)} values, got {value!r}")
        return tuple(_coerce(None, item, kind, f"{where}[{i}]")
                     for i, (item, kind) in enumerate(zip(value, element_types)))
    return _coerce_scalar(value, annotation, where)


def _coerce_scalar(value: Any, annotation: Any, where: str) -> Any:
    if annotation is type(None):
        if value is not None:
            raise SurgsplatError(f"{where}: expected null, got {value!r}")
        return None
    if annotation is bool:
        if not isinstance(value, bool):
            raise SurgsplatError(f"{where}: expected true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SurgsplatError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SurgsplatError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise SurgsplatError(f"{where}: expected a string, got {value!r}")
        return value
    raise SurgsplatError(f"{where}: settings of type {_describe(annotation)} cannot be changed")


def _coerce_dict(current: dict, value: Any, value_type: Any, where: str) -> dict:
    """Entries of `value` applied to a dict of configs; new entries built, null removes one."""
    if not isinstance(value, dict):
        raise SurgsplatError(f"{where}: expected a table, got {value!r}")
    result = dict(current)
    for key, entry in value.items():
        path = f"{where}.{key}"
        if entry is None:
            result.pop(key, None)
            continue
        if key in result:
            kind = entry.get(KIND_KEY) if isinstance(entry, dict) else None
            existing = result[key]
            if kind is not None and isinstance(existing, ComponentConfig) and kind != existing.kind:
                existing = ComponentConfig.of_kind(kind, path)()
            result[key] = _coerce(existing, entry, value_type, path)
        else:
            result[key] = _coerce(_new_entry(value_type, entry, path), entry, value_type, path)
    return result


def _new_entry(value_type: Any, entry: Any, where: str) -> Any:
    """A default instance for a new dict entry: a component by its kind, else the value type."""
    if isinstance(value_type, type) and issubclass(value_type, ComponentConfig):
        if not isinstance(entry, dict) or KIND_KEY not in entry:
            raise SurgsplatError(f"{where}: a new component needs a {KIND_KEY!r} "
                                 f"(one of {', '.join(sorted(ComponentConfig.registry))})")
        return ComponentConfig.of_kind(entry[KIND_KEY], where)()
    if dataclasses.is_dataclass(value_type):
        return value_type()
    raise SurgsplatError(f"{where}: unknown entry")


def _describe(annotation: Any) -> str:
    return getattr(annotation, "__name__", None) or str(annotation).replace("typing.", "")


# ---- where changes come from ----
def parse_assignment(text: str) -> dict:
    """`a.b.c=value` -> {"a": {"b": {"c": value}}}; the value is read as JSON (numbers, true,
    false, null, lists, quoted strings) and otherwise taken as a plain string."""
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise SurgsplatError(f"--set {text!r}: expected KEY=VALUE, e.g. train.iterations=5000")
    try:
        value = json.loads(raw)
    except json.JSONDecodeError:
        value = raw
    nested: Any = value
    for part in reversed(key.strip().split(".")):
        if not part:
            raise SurgsplatError(f"--set {text!r}: empty part in key {key!r}")
        nested = {part: nested}
    return nested


def dotted_keys(values: dict, prefix: str = "") -> set[str]:
    """The dotted key of every setting a nested dict of changes makes (`parse_assignment`'s
    result, say): {"train": {"iterations": 30}} -> {"train.iterations"}."""
    keys = set()
    for key, value in values.items():
        path = f"{prefix}.{key}" if prefix else str(key)
        keys |= dotted_keys(value, path) if isinstance(value, dict) and value else {path}
    return keys


def read_config_file(path: Path) -> dict:
    """A JSON (.json) or TOML (.toml) config file as a dict; DataError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise DataError(path, "config file not found (expected JSON or TOML)")
    try:
        if path.suffix.lower() == ".toml":
            values = tomllib.loads(path.read_text())
        elif path.suffix.lower() == ".json":
            values = json.loads(path.read_text())
        else:
            raise DataError(path, "expected a .json or .toml config file")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as err:
        raise DataError(path, f"cannot be read as a config file ({err})") from err
    if not isinstance(values, dict):
        raise DataError(path, "expected a table of settings at the top level")
    return values


def method_from_values(values: dict, preset: MethodConfig, where: str,
                       complete: bool = False) -> MethodConfig:
    """`preset` with `values` applied; `values` may not change the method's name (the name of
    the preset it starts from). `complete`: `values` is a whole saved config, so a component or
    loss weight of the preset that it does not list was removed from the run and is dropped here
    too."""
    values = dict(values)
    name = values.pop("name", preset.name)
    if name != preset.name:
        raise SurgsplatError(f"{where}.name: names method {name!r}, but the preset is "
                             f"{preset.name!r} "
                             "(a method's name is its preset's; choose the preset with --method)")
    if complete:
        kept = {key: {name: entry for name, entry in getattr(preset, key).items()
                      if name in values[key]}
                for key in ("components", "losses") if isinstance(values.get(key), dict)}
        preset = dataclasses.replace(preset, **kept)
    return apply_values(preset, values, where)


def build_method_config(method: str | None, config_file: Path | None,
                        assignments: list[str]) -> MethodConfig:
    """The preset `method` (default DEFAULT_PRESET, or the one `config_file` names), with the file's
    values and then each `KEY=VALUE` assignment applied, type-checked; the rules between fields
    (`check_config`) are checked once all are in."""
    values = read_config_file(config_file) if config_file is not None else {}
    name = values.get("name", method) or DEFAULT_PRESET
    if method is not None and name != method:
        raise SurgsplatError(f"{config_file}: configures method {name!r} but --method is "
                             f"{method!r}")
    config = method_from_values(values, method_config(name), str(config_file or "config"))
    for text in assignments:
        config = method_from_values(parse_assignment(text), config, where="--set")
    check_config(config)
    return config
