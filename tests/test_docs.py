"""The README and the documentation pages: the README stays short and carries no issue numbers
or benchmark tables, every relative link of README.md and docs/ leads to a file that exists (and
to a heading of it, as GitHub names headings), every command and every preset has its page, the
command references are those of the CLI, and (slow) the site builds with warnings as errors."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README_MAX_LINES = 300
PAGES = [ROOT / "README.md", *sorted(DOCS.rglob("*.md"))]
METHOD_PAGES_OF_NO_PRESET = {"index", "shared-components"}
"""Pages of docs/methods/ that describe no single preset: the overview and the shared components."""
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def without_code(text: str) -> str:
    """Markdown with its fenced code blocks and code spans blanked out."""
    text = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)
    return re.sub(r"`[^`\n]*`", "", text)


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: its text lower-cased, without punctuation but `-` and
    `_`, spaces turned into hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).replace("`", "").strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    """The anchors a page offers: its headings' GitHub slugs (with GitHub's -1, -2 for repeats)
    and the objects it documents through mkdocstrings (`::: module.name`)."""
    text = page.read_text()
    found, seen = set(), {}
    for heading in re.findall(r"^#{1,6}\s+(.*)$", without_fences(text), flags=re.M):
        slug = github_slug(heading)
        found.add(slug if slug not in seen else f"{slug}-{seen[slug]}")
        seen[slug] = seen.get(slug, 0) + 1
    found.update(re.findall(r"^::: ([\w.]+)", text, flags=re.M))
    return found


def without_fences(text: str) -> str:
    return re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)


def relative_links(page: Path) -> list[str]:
    return [target for target in LINK.findall(without_code(page.read_text()))
            if not re.match(r"^[a-z][a-z0-9+.-]*:", target) and not target.startswith("#")]


def test_readme_is_short_and_has_no_issue_numbers_or_benchmark_tables():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= README_MAX_LINES
    assert not re.search(r"\bissues?\s+#?\d+|#\d+\b", readme, flags=re.I)
    assert ":begin -->" not in readme  # the generated tables live in docs/benchmarks/


def test_every_relative_link_leads_to_a_file_and_heading_that_exist():
    broken = []
    for page in PAGES:
        for target in relative_links(page):
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve()
            where = f"{page.relative_to(ROOT)}: {target}"
            if not resolved.exists():
                broken.append(f"{where} (no such file)")
            elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
                broken.append(f"{where} (no such heading)")
    assert not broken, "\n".join(broken)


def test_the_links_are_checked_at_all():
    assert len(relative_links(ROOT / "README.md")) > 20
    assert sum(len(relative_links(page)) for page in PAGES) > 100


def test_every_preset_has_a_method_page_and_every_page_a_preset():
    from surgsplat.methods.registry import PRESETS

    pages = {page.stem for page in (DOCS / "methods").glob("*.md")} - METHOD_PAGES_OF_NO_PRESET
    assert pages == set(PRESETS)


def test_the_command_pages_are_those_of_the_cli():
    """docs/gen_commands.py --check: a page for every command, each reference as the CLI
    declares it (run `python docs/gen_commands.py` after changing a command)."""
    done = subprocess.run([sys.executable, str(DOCS / "gen_commands.py"), "--check"],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.slow
def test_the_site_builds_with_warnings_as_errors(tmp_path):
    """What `make docs` builds in CI, here when mkdocs is installed (the extra `docs`)."""
    mkdocs = shutil.which("mkdocs", path=str(Path(sys.executable).parent)) or shutil.which(
        "mkdocs")
    if mkdocs is None:
        pytest.skip("mkdocs is not installed (pip install -e '.[docs]')")
    done = subprocess.run([mkdocs, "build", "--strict", "--site-dir", str(tmp_path / "site")],
                          capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stderr[-3000:]
    assert (tmp_path / "site" / "index.html").is_file()
