"""Valid ranges of config fields: declared beside each field, checked in one place.

A numeric field of a config dataclass declares its range in its metadata, in interval notation:

    iterations: int = field(default=3000, metadata={"range": "[1, inf)"})

`[` and `]` include a bound, `(` and `)` exclude it, and an `inf` bound leaves that side open.
The declaration is a plain string under `RANGE_KEY`, so the component layers below this one
(model, fields, losses) declare ranges without importing anything from here. For a tuple field
the range holds for each element. Whatever the range, a number must be finite: NaN and +-inf
are refused everywhere.

`check_field` checks a value as `overrides.apply_values` sets it (`--set`, `--config`, a saved
config.json); `check_config` checks every field of a whole config (a preset).
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


def check_config(config: Any, where: str) -> None:
    """`check_field` on every field of dataclass `config`, of the dataclasses it holds and of
    the dataclasses in its dicts (components, loss weights), each named by its dotted key."""
    if isinstance(config, dict):
        for key, entry in config.items():
            check_config(entry, f"{where}.{key}")
        return
    if not dataclasses.is_dataclass(config):
        return
    for config_field in dataclasses.fields(config):
        value = getattr(config, config_field.name)
        key = f"{where}.{config_field.name}"
        check_field(config_field, value, key)
        check_config(value, key)
