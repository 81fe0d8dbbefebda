"""The methods that `--method` names: surgsplat's own, one package each under
surgsplat/methods/<name>/, and those of installed packages that join through the entry-point
group `surgsplat.methods`.

An entry point's name is the method's name and its value the `Preset` its package declares
(`package.module:PRESET`); surgsplat's own methods are declared the same way (`BUILT_IN`).
Importing this module loads every method, so the component kinds each package defines are
registered before a saved config names them. An outside package that fails to load, or whose
entry point is not a `Preset`, is left out of `PRESETS` with its error in `UNLOADABLE`, which
`method_config` reports when that method is asked for; a name already taken keeps its first
method, with a warning.
"""

from __future__ import annotations

from importlib.metadata import EntryPoint, entry_points

from surgsplat.errors import SurgsplatError
from surgsplat.methods.config import MethodConfig, Preset
from surgsplat.methods.ranges import check_config
from surgsplat.model.camera_refine import CameraRefineConfig  # noqa: F401  (kind "camera_refine")
from surgsplat.plugins import load_extensions

ENTRY_POINT_GROUP = "surgsplat.methods"
"""The entry-point group through which an installed package adds methods."""

DEFAULT_PRESET = "deform3dgs"
"""The method a command uses when `--method` names none."""

BUILT_IN = tuple(EntryPoint(name, f"surgsplat.methods.{name}.preset:PRESET", ENTRY_POINT_GROUP)
                 for name in ("surgsplat", "deform3dgs", "endogaussian", "endoplanar", "endogsg",
                              "drawer", "lumistate", "physiosplat"))
"""surgsplat's own methods, in the order `surgsplat methods` lists them."""


def load_methods(installed: tuple[EntryPoint, ...]) -> tuple[dict[str, Preset], dict[str, str]]:
    """The presets of the built-in methods, then of the `installed` entry points, by name; and
    the error of each installed one that could not be loaded (`load_extensions`)."""
    return load_extensions(ENTRY_POINT_GROUP, BUILT_IN, Preset, installed)


PRESETS, UNLOADABLE = load_methods(tuple(entry_points(group=ENTRY_POINT_GROUP)))
"""Every method by name (`Preset`: description and builder), and the error of each installed
method that could not be loaded."""


def method_config(name: str) -> MethodConfig:
    """The preset called `name`, its values checked against their declared ranges;
    SurgsplatError listing the known presets otherwise."""
    if name in UNLOADABLE:
        raise SurgsplatError(f"method {name!r}: {UNLOADABLE[name]}")
    if name not in PRESETS:
        raise SurgsplatError(f"unknown method {name!r}; known: {', '.join(sorted(PRESETS))}")
    config = PRESETS[name].build()
    check_config(config, name)
    return config
