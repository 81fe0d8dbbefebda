"""Entry-point groups through which installed packages extend surgsplat: methods
(`surgsplat.methods`), metric families (`surgsplat.metric_families`) and products of a run after
training (`surgsplat.products`).

surgsplat declares its own extensions as entry points too (each registry's `BUILT_IN`), so that
one loader serves both: the built-in ones load first and a failure among them raises (a fault of
surgsplat); an installed one that fails to load, or is not of the registry's type, is left out
with its error, and one whose name is taken is ignored with a warning.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from importlib.metadata import EntryPoint, entry_points
from typing import TypeVar

T = TypeVar("T")


def load_extensions(group: str, built_in: Sequence[EntryPoint], kind: type[T],
                    installed: Sequence[EntryPoint] | None = None
                    ) -> tuple[dict[str, T], dict[str, str]]:
    """The objects of the `built_in` entry points, then of the `installed` ones of `group` (by
    default those of the installed packages), by name; and the error of each installed one that
    could not be loaded or is not a `kind`: an instance of it, or a class derived from it (a
    metric family registers its class)."""
    loaded: dict[str, T] = {entry.name: entry.load() for entry in built_in}
    unloadable: dict[str, str] = {}
    if installed is None:
        installed = tuple(entry_points(group=group))
    for entry in installed:
        if entry.name in loaded:
            warnings.warn(f"entry point {entry.value} of group {group} names {entry.name!r}, "
                          "which is taken; it is ignored", stacklevel=2)
            continue
        try:
            value = entry.load()
        except Exception as err:  # a plug-in's fault: reported where it is asked for
            unloadable[entry.name] = f"{entry.value} failed to load: {type(err).__name__}: {err}"
            continue
        if not _is_kind(value, kind):
            unloadable[entry.name] = (f"{entry.value} is a {type(value).__name__}, not a "
                                      f"{kind.__module__}.{kind.__qualname__}")
            continue
        loaded[entry.name] = value
    return loaded, unloadable


def _is_kind(value: object, kind: type) -> bool:
    """`value` is an instance of `kind`, or a class derived from it."""
    return isinstance(value, kind) or (isinstance(value, type) and issubclass(value, kind))
