"""Layers import downward only (DESIGN.md): a module may import from its own layer or below.

    cli > eval, export > train > methods > model, fields, losses > render, image > data
    > errors, atomic
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "surgsplat"
LAYERS = {
    "errors": 0, "atomic": 0, "data": 1, "image": 2, "render": 2, "model": 3, "fields": 3, "losses": 3,
    "methods": 4, "train": 5, "eval": 6, "export": 6, "cli": 7,
}


def layer_of(module: str) -> str | None:
    """'surgsplat.render.project' -> 'render'; None for the package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[0] == "surgsplat" else None


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every surgsplat import in a source file, type-checking ones included."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
            if node.module == "surgsplat":
                names = [f"surgsplat.{alias.name}" for alias in node.names]
            found += [(node.lineno, name) for name in names]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
    return [(line, name) for line, name in found if name.split(".")[0] == "surgsplat"]


def source_files() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_every_package_has_a_layer():
    packages = {p.parent.name for p in source_files() if p.parent != PACKAGE}
    packages |= {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    assert packages - {"phantom", "weights"} <= set(LAYERS), packages - set(LAYERS)


@pytest.mark.parametrize("path", source_files(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_point_down(path):
    relative = path.relative_to(PACKAGE)
    own = relative.parts[0] if len(relative.parts) > 1 else relative.stem
    if own not in LAYERS:
        return  # the package's own __init__
    upward = [f"line {line}: {module}" for line, module in imported_modules(path)
              if (target := layer_of(module)) in LAYERS and LAYERS[target] > LAYERS[own]]
    assert not upward, f"{relative} imports from higher layers: {upward}"
