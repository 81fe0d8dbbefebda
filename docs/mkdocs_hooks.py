"""MkDocs hooks of the documentation site (mkdocs.yml `hooks:`).

- The benchmark pages show the plots that the benchmarks write beside their results, under
  benchmarks/results/ outside docs/, and link them relative to the page
  (`../../benchmarks/results/NAME.png`) so that the same Markdown works on GitHub. MkDocs only
  serves files under docs/, so `on_files` adds each results image to the site as a file whose
  source path is that link's target and whose place in the site is `results/NAME.png`.
- Docstrings start a list on the line after a sentence (`...:` then `- item`), which Markdown
  reads as one paragraph. `on_config` adds a preprocessor that puts a blank line before and
  after such a list, so the docstrings shown by mkdocstrings keep their lists.
"""

from __future__ import annotations

import re
from pathlib import Path

from markdown import Extension
from markdown.preprocessors import Preprocessor
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files, InclusionLevel

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
ITEM = re.compile(r"^[-*] \S")


class _ListsAfterSentences(Preprocessor):
    """A blank line before a top-level list item that follows a line of text, and after the
    list (its last item or indented continuation) when text follows at the margin."""

    def run(self, lines: list[str]) -> list[str]:
        out, in_list = [], False
        for line in lines:
            previous = out[-1] if out else ""
            if ITEM.match(line):
                if previous.strip() and not in_list:
                    out.append("")
                in_list = True
            elif not line.strip():
                in_list = False
            elif in_list and not line[0].isspace():
                out.append("")
                in_list = False
            out.append(line)
        return out


class _ListsAfterSentencesExtension(Extension):
    def extendMarkdown(self, md) -> None:  # noqa: N802 (Markdown's name)
        # after the fenced code blocks (priority 25) are set aside, so code is never touched
        md.preprocessors.register(_ListsAfterSentences(md), "lists_after_sentences", 20)


@event_priority(100)  # before mkdocstrings reads the Markdown extensions
def on_config(config):
    config.markdown_extensions.append(_ListsAfterSentencesExtension())
    return config


def on_files(files: Files, config) -> Files:
    for image in sorted(RESULTS.glob("*.png")):
        # included explicitly: MkDocs would exclude a source path starting with "." (hidden)
        file = File.generated(config, f"../benchmarks/results/{image.name}",
                              abs_src_path=str(image), inclusion=InclusionLevel.INCLUDED)
        file.dest_uri = f"results/{image.name}"
        files.append(file)
    return files
