"""Valid ranges of config fields: declared beside each field, checked in one place.

A numeric field of a config dataclass declares its range in its metadata, in interval notation:

    iterations: int = field(default=3000, metadata={"range": "[1, inf)"})

`[` and `]` include a bound, `(` and `)` exclude it, and an `inf` bound leaves that side open.
The declaration is a plain string under `RANGE_KEY`, so the component layers below this one
(model, fields, losses) declare ranges without importing anything from here. For a tuple field
the range holds for each element. Whatever the range, a number must be finite: NaN and +-inf
are refused everywhere.

A field whose valid values depend on a sibling field declares that too, by the sibling's name:

    stop: float = field(default=1.0, metadata={"range": "(0, 1]", "above": "start"})

`ABOVE_KEY`: greater than the sibling's value; `AT_LEAST_KEY`: greater than or equal to it. A
rule that no such order states (two fields that only act together, say) is a config class's
`check_rules(where)` method.

`check_field` checks a value as `overrides.apply_values` sets it (`--set`, `--config`, a saved
config.json); `check_config` checks every field of a whole config and the rules between them
(a preset, a user's config once all its changes are applied, a saved config): one change may
need another to satisfy a rule, so the rules are checked once every change is in.
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from typing import Any

from surgsplat.errors import SurgsplatError

RANGE_KEY = "range"
"""Key of a field's valid range in its `dataclasses.field(metadata=...)`."""

ABOVE_KEY = "above"
"""Key naming the sibling field that a field's value must be greater than."""
AT_LEAST_KEY = "at_least"
"""Key naming the sibling field that a field's value must be greater than or equal to."""
RULES_METHOD = "check_rules"
"""Name of the method (taking the config's dotted key, "" at the top) by which a config class
checks the rules between its fields that no declared order states."""

_INTERVAL = re.compile(r"^([\[(])\s*(\S+)\s*,\s*(\S+)\s*([\])])$")


@dataclass(frozen=True)
class Range:
    """An interval of valid values, e.g. "[0, 1)"; either bound may be infinite (open)."""

    low: float
    high: float
    low_included: bool
    high_included: bool

    @classmethod
    def parse(cls, text: str) -> Range:
        """The interval written as `text` ("[1, inf)", "(0, 1]", "[-100, 100]")."""
        match = _INTERVAL.match(text)
        if match is None:
            raise ValueError(f"invalid range {text!r}: expected interval notation, e.g. '[0, 1)'")
        opening, low, high, closing = match.groups()
        return cls(float(low), float(high), opening == "[", closing == "]")

    def __contains__(self, value: float) -> bool:
        above = value >= self.low if self.low_included else value > self.low
        below = value <= self.high if self.high_included else value < self.high
        return is_finite(value) and above and below

    def __str__(self) -> str:
        return (f"{'[' if self.low_included else '('}{_bound(self.low)}, "
                f"{_bound(self.high)}{']' if self.high_included else ')'}")


def _bound(value: float) -> str:
    """A bound as written: 1 rather than 1.0, inf and -inf."""
    return str(int(value)) if math.isfinite(value) and value == int(value) else str(value)


def is_finite(number: int | float) -> bool:
    """False for NaN and +-inf (an integer, however large, is finite)."""
    return isinstance(number, int) or math.isfinite(number)


def declared_range(config_field: dataclasses.Field) -> Range | None:
    """The range declared in `config_field`'s metadata; None when it declares none."""
    text = config_field.metadata.get(RANGE_KEY)
    return None if text is None else Range.parse(text)


def _numbers(value: Any) -> list[int | float]:
    """The numbers a field value holds: itself, or a tuple's elements (booleans excluded)."""
    items = value if isinstance(value, (tuple, list)) else (value,)
    return [item for item in items
            if isinstance(item, (int, float)) and not isinstance(item, bool)]


def check_field(config_field: dataclasses.Field, value: Any, where: str) -> None:
    """SurgsplatError naming `where`, the value and the valid range when a number of `value`
    (the field's value, or each element of a tuple) is not finite or not in the declared range."""
    valid = declared_range(config_field)
    for number in _numbers(value):
        if not is_finite(number) or (valid is not None and number not in valid):
            kind = "an integer" if isinstance(number, int) else "a finite number"
            span = f" in {valid}" if valid is not None else ""
            raise SurgsplatError(f"{where}: {number!r} is out of range; expected {kind}{span}")


def dotted(where: str, key: str | int) -> str:
    """The dotted key of `key` in the config at `where` ("" at the top)."""
    return f"{where}.{key}" if where else str(key)


def check_order(config: Any, config_field: dataclasses.Field, where: str) -> None:
    """SurgsplatError naming both keys when `config_field` of dataclass `config` (at `where`)
    is not above / at least the sibling field its metadata names (ABOVE_KEY, AT_LEAST_KEY)."""
    value = getattr(config, config_field.name)
    for key, relation in ((ABOVE_KEY, "greater than"), (AT_LEAST_KEY, "at least")):
        sibling = config_field.metadata.get(key)
        if sibling is None:
            continue
        bound = getattr(config, sibling)
        if value > bound or (key == AT_LEAST_KEY and value == bound):
            continue
        raise SurgsplatError(f"{dotted(where, config_field.name)} ({value!r}) must be "
                             f"{relation} {dotted(where, sibling)} ({bound!r})")


def check_config(config: Any, where: str = "") -> None:
    """`check_field` and `check_order` on every field of dataclass `config`, of the
    dataclasses it holds and of the dataclasses in its dicts (components, loss weights), and
    each one's RULES_METHOD, each named by its dotted key below `where`."""
    if isinstance(config, dict):
        for key, entry in config.items():
            check_config(entry, dotted(where, key))
        return
    if not dataclasses.is_dataclass(config):
        return
    for config_field in dataclasses.fields(config):
        value = getattr(config, config_field.name)
        key = dotted(where, config_field.name)
        check_field(config_field, value, key)
        check_config(value, key)
    for config_field in dataclasses.fields(config):
        check_order(config, config_field, where)
    rules = getattr(config, RULES_METHOD, None)
    if rules is not None:
        rules(where)
