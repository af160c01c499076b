"""The README a newcomer reads (issue 33 item 5): short, and every relative link resolves.

README.md stays at most 250 lines (the rest lives in docs/), every relative link and image
in README.md and docs/*.md names a file that exists, and the README reaches the pages a
newcomer needs within two links.
"""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").glob("*.md"))]
README_MAX_LINES = 250

# [text](target) and ![alt](target); targets without spaces, an optional "title" after.
_LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_FENCE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)


def relative_links(text: str) -> list[str]:
    """The relative link targets of a Markdown text (fenced code and URLs left out)."""
    prose = _FENCE.sub("", text)
    targets = [m.group(1) for m in _LINK.finditer(prose)]
    return [t for t in targets if not re.match(r"^[a-z][a-z0-9+.-]*:", t) and not t.startswith("#")]


def test_link_finder_reads_links_images_and_skips_urls_and_code():
    text = (
        'see [a](docs/a.md#x), ![f](figures/f.png "t") and [u](https://x.org/y)\n'
        "```sh\n[not](a/link.md)\n```\n[anchor](#here)\n"
    )
    assert relative_links(text) == ["docs/a.md#x", "figures/f.png"]


def test_readme_is_at_most_250_lines():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines: move detail into docs/"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    missing = []
    for target in relative_links(page.read_text(encoding="utf-8")):
        path = unquote(target.split("#", 1)[0])
        if not (page.parent / path).exists():
            missing.append(target)
    assert not missing, f"{page.relative_to(ROOT)}: links to missing files {missing}"


def test_every_docs_page_is_linked_from_the_readme():
    linked = {
        (README.parent / t.split("#", 1)[0]).resolve()
        for t in relative_links(README.read_text(encoding="utf-8"))
    }
    orphans = [p.name for p in PAGES[1:] if p.resolve() not in linked]
    assert not orphans, f"docs pages the README does not link: {orphans}"


@pytest.mark.parametrize(
    "command",
    [
        "bash scripts/demo.sh",
        "bash scripts/test.sh",
        "bash scripts/test.sh --fast",
        "stereo-avoid fly --scenario",
        "stereo-avoid montecarlo",
        "--mavlink",
        "stereo-camera",
    ],
)
def test_readme_shows_how_to_run_each_thing_a_newcomer_asks_for(command):
    assert command in README.read_text(encoding="utf-8"), f"README.md lacks `{command}`"
