"""The README and the pages in docs/: every relative link reaches a file (and a heading, when it
names one), and every cell of the README's tables fits on one line of a wide screen."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]
README_CELL_MAX_CHARS = 120
"""A README table cell longer than this wraps on a wide screen: its detail belongs in the page it links to."""
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)


def prose(text: str) -> str:
    """``text`` without its fenced code blocks and inline code (a link there is not a link)."""
    return re.sub(r"`[^`\n]*`", "", FENCE.sub("", text))


def anchor(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*]|\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(page: Path) -> set[str]:
    return {anchor(line.lstrip("#")) for line in FENCE.sub("", page.read_text(encoding="utf-8")).splitlines()
            if line.startswith("#")}


def relative_links(page: Path) -> list[str]:
    return [target for target in LINK.findall(prose(page.read_text(encoding="utf-8")))
            if not re.match(r"[a-z][a-z0-9+.-]*:", target)]


def broken_links(page: Path) -> list[str]:
    """Each relative link of ``page`` whose file, or heading within it, does not exist."""
    broken = []
    for target in relative_links(page):
        path, _, fragment = target.partition("#")
        linked = (page.parent / path).resolve() if path else page
        if not linked.exists():
            broken.append(f"{target} (no such file)")
        elif fragment and linked.suffix == ".md" and fragment not in anchors(linked):
            broken.append(f"{target} (no such heading)")
    return broken


def table_cells(text: str) -> list[str]:
    """The cells of every Markdown table row in ``text`` (code blocks left out)."""
    cells = []
    for line in FENCE.sub("", text).splitlines():
        if line.startswith("|") and not re.fullmatch(r"[|:\- ]+", line):
            cells += [cell.strip() for cell in line.strip().strip("|").split("|")]
    return cells


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_reaches_a_file_and_heading(page):
    assert broken_links(page) == []


def test_the_pages_include_the_experiment_logs():
    assert REPO / "docs" / "experiments" / "README.md" in PAGES


def test_a_broken_link_and_a_missing_heading_are_found(tmp_path):
    (tmp_path / "there.md").write_text("# A heading, with `code`\n")
    page = tmp_path / "page.md"
    page.write_text("[ok](there.md#a-heading-with-code) [gone](missing.md) [no](there.md#nope) "
                    "[web](https://example.com) `[code](nowhere.md)`\n```\n[fenced](nowhere.md)\n```\n")
    assert [b.split(" ")[0] for b in broken_links(page)] == ["missing.md", "there.md#nope"]


def test_every_readme_table_cell_fits_one_line_of_a_wide_screen():
    long = [cell for cell in table_cells((REPO / "README.md").read_text(encoding="utf-8")) if len(cell) > README_CELL_MAX_CHARS]
    assert long == [], f"README table cells over {README_CELL_MAX_CHARS} characters: move the detail to the linked page"


def test_a_long_table_cell_is_found():
    cells = table_cells("| a | b |\n|---|---:|\n| short | " + "x" * 121 + " |\n```\n| " + "y" * 200 + " |\n```\n")
    assert cells == ["a", "b", "short", "x" * 121]
