"""The documentation holds together: the README teaches in its first screen and stays short,
and every relative link of the README and of the pages under docs/ leads somewhere (the
file exists; a ``#anchor`` names a heading of the target, as GitHub renders it)."""

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
PAGES = [README, *sorted((REPO / "docs").rglob("*.md"))]
README_MAX_LINES = 300
FIRST_SCREEN = 60

FENCE = re.compile(r"^\s*(```|~~~)")
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
# [text](target) and ![alt](target); the text may hold one level of brackets.
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def prose_lines(text: str) -> list[str]:
    """The lines outside fenced code blocks, with inline code spans blanked."""
    lines, fenced = [], False
    for line in text.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            lines.append("")
        elif fenced:
            lines.append("")
        else:
            lines.append(CODE_SPAN.sub(lambda m: " " * len(m.group(0)), line))
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: link text kept, markup and punctuation dropped, lower
    case, spaces as hyphens."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)
    text = re.sub(r"[^\w\- ]", "", text.lower())
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file's headings (a repeated one gets -1, -2, ...)."""
    seen: dict[str, int] = {}
    found = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        m = None if fenced else HEADING.match(line)
        if m:
            base = slug(m.group(2))
            n = seen.get(base, 0)
            seen[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def relative_links(path: Path) -> list[tuple[int, str]]:
    """(line number, target) of every link that is not a URL."""
    links = []
    for number, line in enumerate(prose_lines(path.read_text(encoding="utf-8")), 1):
        for m in LINK.finditer(line):
            target = m.group(1)
            if not SCHEME.match(target) and not target.startswith("//"):
                links.append((number, target))
    return links


def test_the_readme_is_short():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, (
        f"README.md has {len(lines)} lines; keep it at most {README_MAX_LINES} and move the "
        "details into a page of docs/guide/ linked from it.")


def test_the_readme_first_screen_shows_set_up_and_the_five_tasks():
    head = "\n".join(README.read_text(encoding="utf-8").splitlines()[:FIRST_SCREEN])
    wanted = {
        "set-up": ["make demo"], "tests": ["make test"],
        "generate a scene": ["mjexplore scene-gen"], "explore": ["mjexplore explore"],
        "benchmark": ["mjexplore bench"], "train": ["mjexplore train"],
        "watch or replay": ["mjexplore render", "--video"],
    }
    missing = [task for task, words in wanted.items() if not any(w in head for w in words)]
    assert not missing, f"README.md's first {FIRST_SCREEN} lines do not show: {missing}"


def test_the_guide_is_linked_from_the_readme():
    targets = {target.split("#")[0] for _, target in relative_links(README)}
    assert "docs/guide/index.md" in targets and "docs/results.md" in targets
    guide = {f"docs/guide/{p.name}" for p in (REPO / "docs" / "guide").glob("*.md")}
    assert guide <= targets, f"guide pages the README does not link: {sorted(guide - targets)}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(page: Path):
    broken = []
    for number, target in relative_links(page):
        file_part, _, anchor = target.partition("#")
        dest = (page.parent / file_part).resolve() if file_part else page
        if not dest.exists():
            broken.append(f"line {number}: {target} (no such file)")
        elif anchor and dest.suffix == ".md" and anchor.lower() not in anchors(dest):
            broken.append(f"line {number}: {target} (no heading #{anchor} in {dest.name})")
    assert not broken, f"{page.relative_to(REPO)}: " + "; ".join(broken)


def test_the_link_checker_finds_links_and_anchors(tmp_path):
    # The checker itself: links in code are not links, anchors follow GitHub's rule.
    page = tmp_path / "page.md"
    page.write_text("# The learned explorers: `gvn` and `cnn`\n\n## Table 3 and Fig. 9: the x\n\n"
                    "See [a](other.md#part) and ![b](img.png).\n`[no](code.md)`\n"
                    "```\n[no](fenced.md)\n```\n", encoding="utf-8")
    assert relative_links(page) == [(5, "other.md#part"), (5, "img.png")]
    assert anchors(page) == {"the-learned-explorers-gvn-and-cnn", "table-3-and-fig-9-the-x"}
