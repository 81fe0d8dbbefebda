"""Layers import downward only (DESIGN.md): a module may import from its own layer or below.

    cli > pipeline > eval, export > train > methods > model, fields, losses > render, image
    > data > errors, atomic
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "surgsplat"
LAYERS = {
    "errors": 0, "atomic": 0, "plugins": 0, "data": 1, "image": 2, "render": 2, "model": 3, "fields": 3, "losses": 3,
    "methods": 4, "train": 5, "eval": 6, "export": 6, "pipeline": 7, "cli": 8,
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
    """Every top-level package and module (a package's subpackages share its layer)."""
    packages = {p.relative_to(PACKAGE).parts[0] for p in source_files() if p.parent != PACKAGE}
    packages |= {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    assert packages <= set(LAYERS), packages - set(LAYERS)


@pytest.mark.parametrize("path", source_files(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_imports_point_down(path):
    relative = path.relative_to(PACKAGE)
    own = relative.parts[0] if len(relative.parts) > 1 else relative.stem
    if own not in LAYERS:
        return  # the package's own __init__
    upward = [f"line {line}: {module}" for line, module in imported_modules(path)
              if (target := layer_of(module)) in LAYERS and LAYERS[target] > LAYERS[own]]
    assert not upward, f"{relative} imports from higher layers: {upward}"


COMPONENT_PACKAGES = ("model", "fields", "losses", "methods")
ATTRIBUTE_HOOKS = ("initial_attributes", "per_gaussian_attributes", "attribute_lrs")
"""Component hooks whose returned dicts are keyed by the component's per-Gaussian attributes."""


def module_name(path: Path) -> str:
    """surgsplat/fields/hexplane.py -> 'surgsplat.fields.hexplane'."""
    return ".".join(("surgsplat", *path.relative_to(PACKAGE).with_suffix("").parts))


def attribute_keys(path: Path) -> tuple[set[str], set[str]]:
    """(names of the module-level constants, values) of the keys of the per-Gaussian attributes
    a component module declares: the keys of the dicts its ATTRIBUTE_HOOKS return."""
    tree = ast.parse(path.read_text(), str(path))
    constants = {target.id: node.value.value for node in tree.body if isinstance(node, ast.Assign)
                 and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
                 for target in node.targets if isinstance(target, ast.Name)}
    names, values = set(), set()
    for hook in ast.walk(tree):
        if isinstance(hook, ast.FunctionDef) and hook.name in ATTRIBUTE_HOOKS:
            for key in (k for node in ast.walk(hook) if isinstance(node, ast.Dict) for k in node.keys):
                if isinstance(key, ast.Name) and key.id in constants:
                    names.add(key.id)
                    values.add(constants[key.id])
                elif isinstance(key, ast.Constant) and isinstance(key.value, str):
                    values.add(key.value)
    return names, values


def test_no_module_reads_another_components_attribute_keys():
    """A component's per-Gaussian attributes are its own: no other module imports the constants
    that key them or spells their keys (tool membership and capabilities go through the
    component contract, `model.membership` and `model.capabilities`)."""
    owners = {module_name(path): attribute_keys(path) for path in source_files()
              if path.relative_to(PACKAGE).parts[0] in COMPONENT_PACKAGES}
    owners = {module: keys for module, keys in owners.items() if keys[1]}
    tool_field = "surgsplat.methods.physiosplat.tool_field"
    assert "semantic_logit" in owners[tool_field][1]  # the check sees keys
    offences = []
    for path in source_files():
        reader = module_name(path)
        others = {module: keys for module, keys in owners.items() if module != reader}
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module in others:
                offences += [f"{reader} imports {alias.name} from {node.module}"
                             for alias in node.names if alias.name in others[node.module][0]]
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                offences += [f"{reader} spells {value!r} of {module}"
                             for module, (_, values) in others.items() for value in values
                             if value in node.value]
    assert not offences, offences
