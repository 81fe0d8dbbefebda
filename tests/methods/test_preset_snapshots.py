"""Every preset's config (`method_config(name)`, as `to_dict` serialises it) against its
snapshot, tests/methods/snapshots/<preset>.json, order included (components are built, and loss
terms summed, in the order they are listed). A change to a preset, or to a default it inherits
from a component or setting, fails here with the keys that changed, so that no preset changes
unseen.

To accept a change on purpose, regenerate the snapshots and review their diff:

    SURGSPLAT_UPDATE_SNAPSHOTS=1 .venv/bin/python -m pytest tests/methods/test_preset_snapshots.py
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

from surgsplat.methods.config import to_dict
from surgsplat.methods.registry import PRESETS, method_config

SNAPSHOTS = Path(__file__).resolve().parent / "snapshots"
UPDATE = os.environ.get("SURGSPLAT_UPDATE_SNAPSHOTS") == "1"


def stored_snapshot(name: str, actual: dict[str, Any]) -> dict[str, Any]:
    """The snapshot of preset `name`, first written from `actual` when
    SURGSPLAT_UPDATE_SNAPSHOTS=1."""
    path = SNAPSHOTS / f"{name}.json"
    if UPDATE:
        SNAPSHOTS.mkdir(exist_ok=True)
        path.write_text(json.dumps(actual, indent=2) + "\n")
    if not path.exists():
        pytest.fail(f"no snapshot {path.name} of preset {name!r}: SURGSPLAT_UPDATE_SNAPSHOTS=1 "
                    "writes it")
    return json.loads(path.read_text())


def flattened(value: Any, prefix: str = "") -> dict[str, Any]:
    """Every leaf of a nested dict / list under its dotted key (`losses.depth.weight`,
    `init.values.0`), in the order they are listed."""
    if isinstance(value, dict) and value:
        items = value.items()
    elif isinstance(value, list) and value:
        items = enumerate(value)
    else:
        return {prefix: value}
    leaves = {}
    for key, item in items:
        leaves.update(flattened(item, f"{prefix}.{key}" if prefix else str(key)))
    return leaves


def key_orders(value: Any, prefix: str = "") -> dict[str, list[str]]:
    """The order of the keys of every dict in a nested dict, under the dict's dotted key."""
    if not isinstance(value, dict):
        return {}
    orders = {prefix: list(value)}
    for key, item in value.items():
        orders.update(key_orders(item, f"{prefix}.{key}" if prefix else key))
    return orders


def differences(expected: dict[str, Any], actual: dict[str, Any]) -> list[str]:
    """One line per key removed, added or changed between two configs, and one per dict whose
    keys are the same but in another order."""
    before, after = flattened(expected), flattened(actual)
    lines = [f"- {key}: {before[key]!r} (removed)" for key in before if key not in after]
    lines += [f"+ {key}: {after[key]!r} (added)" for key in after if key not in before]
    lines += [f"~ {key}: {before[key]!r} -> {after[key]!r}"
              for key in before if key in after and before[key] != after[key]]
    old_orders, new_orders = key_orders(expected), key_orders(actual)
    lines += [f"order of {where or 'the config'}: {order} -> {new_orders[where]}"
              for where, order in old_orders.items()
              if where in new_orders and order != new_orders[where]
              and sorted(order) == sorted(new_orders[where])]
    return lines


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_preset_config_is_its_snapshot(name):
    actual = to_dict(method_config(name))
    changed = differences(stored_snapshot(name, actual), actual)
    assert not changed, (f"preset {name!r} differs from its snapshot (SURGSPLAT_UPDATE_SNAPSHOTS=1 "
                         "regenerates it):\n" + "\n".join(changed))


def test_every_snapshot_is_of_a_preset():
    stale = sorted(path.name for path in SNAPSHOTS.glob("*.json") if path.stem not in PRESETS)
    assert not stale, f"snapshots of no preset (delete them): {stale}"
