"""The docs a user reads stay short, and every measured figure says how it was made (issue 34).

Rules, checked on the files as committed:

- every user doc `docs/*.md` (not `docs/results/`) is at most 400 lines: a user doc says what a
  part does, how to use it, its limits and where its current figures are; history lives in git;
- every `docs/results/*.md` file that holds a table (a line starting with `|`) or a figure
  (`![...](...)`) also holds a line naming the command that made it: a line inside a fenced
  (```) or 4-space-indented code block, a line starting with "Made with", or a line with an
  inline code span that starts with a command (`python`, `.venv/bin/`, `OMP_NUM_THREADS=`,
  `shelfpick `, `make `, `benchmarks/`, `/work/main/.venv/`); and that line stands in the same
  section (the text under one `## ` heading, its `###` subsections included; the text before the
  first `## ` is a section too), so a reader finds each figure's command beside it;
- no results file says a command was "not recorded": a figure nobody can remake is history, and
  history lives in git.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parent.parent / "docs"
MAX_LINES = 400
COMMAND_SPAN = re.compile(r"`(python|\.venv/bin/|OMP_NUM_THREADS=|shelfpick |make |benchmarks/|/work/main/\.venv/)")


def has_figure(text: str) -> bool:
    """A table row or an image."""
    return any(line.startswith("|") or re.search(r"!\[[^\]]*\]\(", line) for line in text.splitlines())


def names_command(text: str) -> bool:
    """True when some line names a command (the rule in the module docstring)."""
    fenced = False
    for line in text.splitlines():
        if line.startswith("```"):
            if fenced:
                return True      # a fenced block that held at least its opening line
            fenced = True
            continue
        if fenced or line.startswith("    ") and line.strip():
            return True
        if line.startswith("Made with") or COMMAND_SPAN.search(line):
            return True
    return False


def sections(text: str) -> list[str]:
    """The text under each `## ` heading (subsections included), the text before the first one first."""
    return re.split(r"(?m)^(?=## )", text)


def unmade_figures(text: str) -> list[str]:
    """The headings of the sections that hold a figure but name no command, or say none was recorded."""
    bad = []
    for section in sections(text):
        if has_figure(section) and not names_command(section) or "not recorded" in section:
            bad.append((section.splitlines() or ["(empty)"])[0][:80])
    return bad


@pytest.mark.parametrize("path", sorted(DOCS.glob("*.md")), ids=lambda p: p.name)
def test_user_doc_is_short(path: Path) -> None:
    lines = len(path.read_text(encoding="utf-8").splitlines())
    assert lines <= MAX_LINES, f"{path.name}: {lines} lines, more than {MAX_LINES}: move figures to docs/results/, history to git"


@pytest.mark.parametrize("path", sorted((DOCS / "results").glob("*.md")), ids=lambda p: p.name)
def test_results_name_their_command(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    assert not unmade_figures(text), f"{path.name}: figures whose section names no command: {unmade_figures(text)}"


def test_rules_catch_what_they_should() -> None:
    """The checks themselves: a bare table fails, a table with its command passes."""
    table = "| a | b |\n|---|---|\n| 1 | 2 |\n"
    assert has_figure(table) and not names_command(table)
    assert names_command(table + "\nMade with `x`.\n")
    assert names_command(table + "\n    .venv/bin/python benchmarks/x.py\n")
    assert names_command(table + "\n```\npython benchmarks/x.py\n```\n")
    assert names_command(table + "\nCommand: `OMP_NUM_THREADS=1 python x.py`\n")
    assert not names_command(table + "\nsee `docs/x.md`\n")
    assert has_figure("![plot](a.png)\n") and not has_figure("plain text\n")
    made = "intro\n\n    .venv/bin/python benchmarks/x.py\n\n" + table
    assert unmade_figures(made) == []
    assert unmade_figures(made + "\n## Later\n\n" + table) == ["## Later"]
    assert unmade_figures(made + "\n## Later\n\nThe command was not recorded.\n") == ["## Later"]
    assert unmade_figures(made + "\n## Later\n\n### Sub\n\n" + table + "\nMade with `x`.\n") == []
