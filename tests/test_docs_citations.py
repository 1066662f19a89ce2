"""The docs are reference pages plus decision records, and every result file backs a cited figure.

Rules (docs/decisions/README.md states them for writers):

* Every file in ``docs/results/`` is cited by README.md or a page under ``docs/`` (reference
  pages and ``docs/decisions/``), and every cited ``docs/results/`` file exists: a result file
  nobody cites is deleted (git keeps it), a figure's file is never missing.
* ``benchmarks/results/`` is the benchmarks' output folder (``make bench`` rewrites it, so it
  may hold files no page cites); every file of it that README.md or a docs page cites exists.
* A citation is the file's path: ``docs/results/NAME``, ``benchmarks/results/NAME``, or from a
  page under ``docs/`` the relative ``results/NAME`` / ``../results/NAME``. A generated results
  table links each row to its file (benchmarks/results_table.py). A name in capitals
  (``docs/results/NAME.json``) is a placeholder, not a citation.
* Every relative Markdown link in README.md and the docs points at a file that exists.
* The reference pages (``docs/*.md``, not ``docs/decisions/``) hold at most 15,000 words
  together, and README.md at most 200 lines.
* The rendering contract (docs/render.md) names only tests that exist, and every one of them
  under tests/render/ points back at it in its docstring.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
DOCS_RESULTS = DOCS / "results"
BENCH_RESULTS = ROOT / "benchmarks" / "results"

MAX_REFERENCE_WORDS = 15_000
MAX_README_LINES = 200

# a results path: benchmarks/results/NAME, docs/results/NAME, or results/NAME relative to docs/
RESULT_REF = re.compile(r"(benchmarks/results|docs/results|(?<![\w/])(?:\.\./)*results)/([A-Za-z0-9_.\-]+\.(?:json|md|csv))")
# a Markdown link or image target, relative (no scheme, no leading '#')
LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")


def pages() -> list[Path]:
    """README.md and every Markdown page under docs/ (reference pages and decision records)."""
    return [ROOT / "README.md"] + sorted(DOCS.rglob("*.md"))


def reference_pages() -> list[Path]:
    return sorted(DOCS.glob("*.md"))


def cited_results() -> dict[Path, list[str]]:
    """Every results file the pages cite -> where ('page:line')."""
    cited: dict[Path, list[str]] = {}
    for page in pages():
        if page.parent == DOCS_RESULTS:
            continue  # a result file's own text cites nothing
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            for folder, name in RESULT_REF.findall(line):
                if name.split(".")[0].isupper():
                    continue  # a placeholder such as NAME.json in a command's description
                base = BENCH_RESULTS if folder.startswith("benchmarks") else DOCS_RESULTS
                cited.setdefault(base / name, []).append(f"{page.relative_to(ROOT)}:{n}")
    return cited


def test_the_citation_pattern_reads_every_form():
    found = RESULT_REF.findall("`docs/results/demo.json`, [a](results/panoptic_val.json), [b](../results/x_y.json), "
                               "`benchmarks/results/raster.json`, runs/demo/results/no.json")
    assert [(f.split("/")[0].strip("."), n) for f, n in found] == [
        ("docs", "demo.json"), ("results", "panoptic_val.json"), ("", "x_y.json"), ("benchmarks", "raster.json")]


def test_every_docs_result_file_is_cited():
    cited = cited_results()
    uncited = sorted(p.name for p in DOCS_RESULTS.iterdir() if p.is_file() and p not in cited)
    assert not uncited, ("docs/results/ files that README.md and docs/ never cite (cite each where its figure "
                         "stands, or `git rm` it):\n" + "\n".join(uncited))


def test_every_cited_result_file_exists():
    missing = [f"{p.relative_to(ROOT)} (cited at {', '.join(where)})"
               for p, where in sorted(cited_results().items()) if not p.is_file()]
    assert not missing, "cited result files that do not exist:\n" + "\n".join(missing)


def test_relative_links_resolve():
    broken = []
    for page in pages():
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            for target in LINK.findall(line):
                if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, mailto: ...
                    continue
                if not (page.parent / target).exists():
                    broken.append(f"{page.relative_to(ROOT)}:{n}: {target}")
    assert not broken, "links to files that do not exist:\n" + "\n".join(broken)


def test_reference_pages_fit_the_word_budget():
    words = {p.name: len(p.read_text(encoding="utf-8").split()) for p in reference_pages()}
    total = sum(words.values())
    detail = ", ".join(f"{name} {n}" for name, n in sorted(words.items(), key=lambda kv: -kv[1]))
    assert total <= MAX_REFERENCE_WORDS, (f"docs/*.md hold {total} words (at most {MAX_REFERENCE_WORDS}): {detail}; "
                                          "move studies to docs/decisions/ and history to CHANGELOG.md")


def test_readme_is_a_front_page():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines (at most {MAX_README_LINES})"


def test_the_rendering_contract_names_real_tests_that_point_back():
    named = sorted(set(re.findall(r"tests/[\w/]+\.py", (DOCS / "render.md").read_text(encoding="utf-8"))))
    assert named, "docs/render.md's parity table names no test"
    missing = [n for n in named if not (ROOT / n).is_file()]
    assert not missing, "docs/render.md names tests that do not exist: " + ", ".join(missing)
    silent = [n for n in named if n.startswith("tests/render/")
              and "docs/render.md" not in (ast.get_docstring(ast.parse((ROOT / n).read_text(encoding="utf-8"))) or "")]
    assert not silent, "these tests of the rendering contract do not name docs/render.md in their docstring: " + ", ".join(silent)
