"""Code, README and docs state facts, not their history, and point at the project's own design page.

* No tracker or milestone references ("stop" or "issue" followed by a number, with a space or a
  hyphen) in README.md, in any .py file under fixer4d/, app/, tests/ or benchmarks/, or in any
  page under docs/ (reference pages and decision records); CHANGELOG.md holds the history.
* Every reference to a design document is to docs/design.md (the architecture as built), never
  to the old shared sketch.

The patterns are built from pieces so that this file does not match itself.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CODE_DIRS = ("fixer4d", "app", "tests", "benchmarks")
HISTORY_DOCS: set[str] = set()  # docs that may cite milestones and trackers (none: CHANGELOG.md does)

_SEP = r"[ \t-]+"  # the keyword, then spaces or a hyphen, then the number
HISTORY = re.compile(r"\b(?:" + "st" + "op" + "|" + "iss" + r"ues?" + ")" + _SEP + r"\d", re.IGNORECASE)
# a design document named in capitals (the old sketch); the page is docs/design.md
OLD_DESIGN = re.compile(r"\b" + "DES" + "IGN" + r"(?:\.md|'s\b)")


def code_files() -> list[Path]:
    return sorted(p for d in CODE_DIRS for p in (ROOT / d).rglob("*.py") if ".venv" not in p.parts)


def doc_files(include_history: bool) -> list[Path]:
    return sorted(p for p in (ROOT / "docs").rglob("*.md") if include_history or p.name not in HISTORY_DOCS)


def offending_lines(paths: list[Path], pattern: re.Pattern) -> list[str]:
    """'path:line: text' for every line of ``paths`` that ``pattern`` matches."""
    found = []
    for path in paths:
        for n, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if pattern.search(line):
                found.append(f"{path.relative_to(ROOT)}:{n}: {line.strip()[:120]}")
    return found


def test_the_patterns_match_what_they_should():
    history = ["at stop" + " 21", "Stop" + "-19 code", "(issue" + " 12)", "the issue" + "-5 contract", "Issues" + " 11"]
    assert all(HISTORY.search(s) for s in history)
    clean = ["nonstop 3", "stop at T < 1e-4", "an issue with 2 cameras", "start, stop = 0, 5", "tissue 3"]
    assert not any(HISTORY.search(s) for s in clean)
    assert OLD_DESIGN.search("see " + "DESIGN" + ".md §4") and OLD_DESIGN.search("DESIGN" + "'s rule")
    assert not OLD_DESIGN.search("docs/design.md §4") and not OLD_DESIGN.search("DESIGN_SIZE = (1440.0, 900.0)")


def test_code_has_no_history_references():
    found = offending_lines(code_files(), HISTORY)
    assert not found, "state the fact, not its history (move history to CHANGELOG.md):\n" + "\n".join(found)


def test_docs_have_no_history_references():
    found = offending_lines(doc_files(include_history=False), HISTORY)
    assert not found, ("state the fact, not its history (history goes to CHANGELOG.md):\n"
                       + "\n".join(found))


def test_design_references_point_at_docs_design():
    assert (ROOT / "docs" / "design.md").is_file()
    found = offending_lines(code_files() + doc_files(include_history=True), OLD_DESIGN)
    assert not found, "point design references at docs/design.md (with its § number):\n" + "\n".join(found)


def test_readme_has_no_history_or_old_design_references():
    readme = [ROOT / "README.md"]
    found = offending_lines(readme, HISTORY) + offending_lines(readme, OLD_DESIGN)
    assert not found, "README.md:\n" + "\n".join(found)
