"""No module outside surgsplat/methods/ names a paper, a preset or a paper's component.

Papers and their presets belong to their method packages (surgsplat/methods/<name>/) and to the
method pages of the documentation; the core says what a thing is, not whose it is. The scan
covers every Python file of the package outside surgsplat/methods/ and every native source in
csrc/ (a method's own native op lives in its package, surgsplat/methods/<name>/csrc/).
A command that needs the default method's name reads `surgsplat.methods.registry.DEFAULT_PRESET`.
The package's own name, which is also the name of its combined preset, cannot be scanned for.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "surgsplat"
METHODS = PACKAGE / "methods"
NATIVE = ROOT / "csrc"
NATIVE_SUFFIXES = (".cpp", ".h")

PAPER_NAMES = ("endo-?gsg", "physio-?splat", "endo-?planar", "lumi-?state", "drawer",
               "deform3dgs", "endo-?gaussian")
"""The papers and their presets, as patterns: the hyphen of a paper's name is optional, so both
the paper (Endo-GSG) and its preset (endogsg) match."""
NAMED = re.compile("|".join(PAPER_NAMES), flags=re.IGNORECASE)


def hits(paths: list[Path]) -> list[str]:
    """`path:line: text` of every line of `paths` that names a paper or a preset."""
    found = []
    for path in paths:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if NAMED.search(line):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    return found


def core_files() -> list[Path]:
    """The Python files of the package outside surgsplat/methods/, and the native sources of
    csrc/."""
    python = [path for path in sorted(PACKAGE.rglob("*.py")) if not path.is_relative_to(METHODS)]
    native = [path for path in sorted(NATIVE.rglob("*")) if path.suffix in NATIVE_SUFFIXES]
    return python + native


def test_the_scan_sees_the_core():
    files = core_files()
    assert PACKAGE / "model" / "component.py" in files
    assert NATIVE / "rasterize" / "forward.cpp" in files
    assert not any(path.is_relative_to(METHODS) for path in files)


def test_the_scan_finds_the_names_where_they_belong():
    """The same scan over the method packages finds every paper: the patterns match."""
    method_hits = "\n".join(hits(sorted(METHODS.rglob("*.py"))))
    for name in PAPER_NAMES:
        assert re.search(name, method_hits, flags=re.IGNORECASE), name


def test_no_core_module_names_a_paper_or_a_preset():
    found = hits(core_files())
    assert not found, ("the core names a paper or a preset (describe the thing instead; a "
                       "paper's measurements go to its method page):\n" + "\n".join(found))
