"""Every pointer the documentation gives resolves: files, links to headings, named sections.

The docs and docstrings send readers to other places in three forms: a repository path
(``docs/results/...``, ``benchmarks/speed.py``), a Markdown link with an anchor
(``docs/training.md#throughput``) and a page with a quoted section name
(`` `docs/training.md`, "Stage II" ``). A renamed section or a moved file breaks them silently;
these tests read every tracked text file and check each pointer against the tree.
"""

from __future__ import annotations

import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEXT_SUFFIXES = (".md", ".py", ".toml", ".yaml", ".txt")
#: A repository path: docs/... (any file) or a Python file of the project's folders.
PATH = re.compile(
    r"(?<![\w/.-])(docs/[\w./-]*\w|(?:benchmarks|examples|mivecc_env|mivecc_agents|tests)/"
    r"[\w/-]+\.py)"
)
ANCHOR = re.compile(r"(?<![\w/.-])((?:docs/)?[\w/-]+\.md)#([\w-]+)")
IN_PAGE = re.compile(r"\]\(#([\w-]+)\)")  # [text](#anchor) within one page
SECTION = re.compile(r"`?(docs/[\w/-]+\.md|README\.md)`?,?\s+\"([^\"]+)\"")
#: Characters just after a path that make it a pattern, not a file (``session<N>/``,
#: ``name.{csv,md}``).
TEMPLATE = set("<{*")


@cache
def _tracked_text_files() -> tuple[Path, ...]:
    try:
        out = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                             check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("not a git checkout")
    return tuple(ROOT / p for p in out.splitlines() if p.endswith(TEXT_SUFFIXES))


@cache
def _read(path: Path) -> str:
    return path.read_text(encoding="utf-8", errors="replace")


def anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, only letters, digits, ``-`` and
    ``_`` kept, each space a ``-``."""
    text = heading.lstrip("#").strip().lower()
    return "".join(c for c in text if c.isalnum() or c in "-_ ").replace(" ", "-")


@cache
def _anchors(page: Path) -> frozenset[str]:
    seen: dict[str, int] = {}
    out = set()
    in_code = False
    for line in _read(page).splitlines():
        if line.startswith("```"):
            in_code = not in_code
        if in_code or not line.startswith("#"):
            continue
        a = anchor(line)
        n = seen.get(a, 0)
        seen[a] = n + 1
        out.add(a if n == 0 else f"{a}-{n}")
    return frozenset(out)


@cache
def _section_names(page: Path) -> tuple[str, ...]:
    """Headings and bold lead-ins (``**Name.**``) of a page, lower case, spaces collapsed."""
    text = re.sub(r"^```.*?^```", "", _read(page), flags=re.S | re.M)  # code blocks:
    names = [ln.lstrip("#") for ln in text.splitlines() if ln.startswith("#")]  # no headings
    text = re.sub(r"`[^`]*`", "", text)  # code spans: their ** (**kwargs) pairs with no other
    names += re.findall(r"\*\*(.+?)\*\*", text, flags=re.S)
    return tuple(" ".join(n.split()).lower() for n in names)


def _pointers(pattern: re.Pattern[str]) -> list[tuple[Path, re.Match[str]]]:
    found = []
    for f in _tracked_text_files():
        text = _read(f)
        for m in pattern.finditer(text):
            if not TEMPLATE & set(text[m.end():m.end() + 2]):
                found.append((f, m))
    return found


def _where(f: Path) -> str:
    return str(f.relative_to(ROOT))


def test_anchor_follows_github() -> None:
    assert anchor("## Throughput") == "throughput"
    assert anchor("### Training on a GPU (`--device cuda`, measured in session 22)") == (
        "training-on-a-gpu---device-cuda-measured-in-session-22")
    assert anchor("### `released`: the authors' trainer") == "released-the-authors-trainer"


def test_every_referenced_repository_path_exists() -> None:
    missing = sorted({(m.group(1), _where(f)) for f, m in _pointers(PATH)
                      if not (ROOT / m.group(1)).exists()})
    assert not missing, f"(path, where) pairs naming no file or folder: {missing}"


def test_every_markdown_anchor_resolves() -> None:
    pointers = _pointers(ANCHOR)
    assert pointers  # the pattern sees the docs' links
    bad = []
    for f, m in pointers:
        page, name = m.group(1), m.group(2)
        target = ROOT / page if page.startswith("docs/") or page == "README.md" else (
            f.parent / page)
        if not target.is_file() or name not in _anchors(target):
            bad.append((f"{page}#{name}", _where(f)))
    assert not bad, f"(link, where) pairs whose page or heading does not exist: {bad}"


def test_every_in_page_link_resolves() -> None:
    pages = [f for f in _tracked_text_files() if f.suffix == ".md"]
    links = [(f, m.group(1)) for f in pages for m in IN_PAGE.finditer(_read(f))]
    assert links  # training.md's contents use them
    bad = [(f"#{name}", _where(f)) for f, name in links if name not in _anchors(f)]
    assert not bad, f"(link, page) pairs with no such heading in the page: {bad}"


def test_every_named_section_exists() -> None:
    pointers = _pointers(SECTION)
    assert len(pointers) >= 10  # the pattern sees the docs' references
    bad = []
    for f, m in pointers:
        page, name = ROOT / m.group(1), " ".join(m.group(2).split()).lower()
        if not page.is_file() or not any(name in s for s in _section_names(page)):
            bad.append((m.group(1), m.group(2), _where(f)))
    assert not bad, f"(page, section, where) with no such heading or bold lead-in: {bad}"
