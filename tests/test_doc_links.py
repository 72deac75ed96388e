"""The README's and docs' relative links lead somewhere: the file exists, and a #fragment names a heading."""

import functools
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")
HEADING = re.compile(r"^#+\s+(.*)$")
FENCED = re.compile(r"```.*?```", re.S)


def heading_anchor(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation other than - and _ dropped, spaces to -."""
    text = re.sub(r"[^\w\- ]", "", heading.replace("`", "").strip().lower())
    return text.replace(" ", "-")


@functools.cache
def page_anchors(page: Path) -> frozenset[str]:
    """Every heading anchor of a markdown page; repeated headings get GitHub's -1, -2 suffixes.
    Read once per page, however many links name it."""
    anchors, seen = set(), {}
    for line in FENCED.sub("", page.read_text()).splitlines():
        match = HEADING.match(line)
        if match:
            anchor = heading_anchor(match.group(1))
            count = seen.get(anchor, 0)
            seen[anchor] = count + 1
            anchors.add(anchor if count == 0 else f"{anchor}-{count}")
    return frozenset(anchors)


def relative_links(page: Path) -> list[str]:
    """The link targets of a page that are not web addresses, outside code blocks."""
    targets = LINK.findall(FENCED.sub("", page.read_text()))
    return [t for t in targets if not t.startswith(("http://", "https://", "mailto:"))]


def test_the_anchor_rule_matches_github_on_our_kinds_of_heading():
    assert heading_anchor("Three times the budget: the Ant at 2.9 M env steps") == \
        "three-times-the-budget-the-ant-at-29-m-env-steps"
    assert heading_anchor("Why `point-mass-k2` runs 8 goal-space iterations") == \
        "why-point-mass-k2-runs-8-goal-space-iterations"
    assert heading_anchor("Phase 2 on the robots") == "phase-2-on-the-robots"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_names_an_existing_file_and_heading(page):
    broken = []
    for target in relative_links(page):
        path, _, fragment = target.partition("#")
        linked = (page.parent / path).resolve() if path else page
        if not linked.exists():
            broken.append(f"{target}: no such file")
        elif fragment and linked.suffix == ".md" and fragment not in page_anchors(linked):
            broken.append(f"{target}: no heading with that anchor")
    assert not broken, f"{page.name}: " + "; ".join(broken)
