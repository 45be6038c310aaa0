"""The README stays a user's guide: short, the two commands first, links that resolve, figures that are measured."""
from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
MAX_LINES = 260
FIRST_COMMANDS = (
    "bash deploy/setup.sh && .venv/bin/poseidon demo",
    "bash deploy/setup.sh && .venv/bin/python -m pytest -q",
)
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
_FENCE = re.compile(r"^\s*(```|~~~)")


def _prose(text: str) -> list[str]:
    """The lines of a Markdown text outside fenced code blocks."""
    lines, fenced = [], False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
        elif not fenced:
            lines.append(line)
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip().lower())
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every heading anchor of a Markdown file (repeated headings get -1, -2, ... as on GitHub)."""
    seen: dict[str, int] = {}
    out = set()
    for line in _prose(path.read_text()):
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not m:
            continue
        base = slug(m.group(1))
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def broken_links(doc: Path) -> list[str]:
    """Relative links of ``doc`` whose file (or heading anchor, in a Markdown target) does not exist."""
    bad = []
    for line in _prose(doc.read_text()):
        for target in _LINK.findall(re.sub(r"`[^`]*`", "", line)):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target):  # https:, mailto:, ...
                continue
            path_part, _, anchor = target.partition("#")
            dest = (doc.parent / path_part).resolve() if path_part else doc
            if not dest.exists():
                bad.append(f"{doc.relative_to(REPO)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
                bad.append(f"{doc.relative_to(REPO)}: {target} (no such heading)")
    return bad


def test_the_readme_is_at_most_260_lines():
    n = len(README.read_text().splitlines())
    assert n <= MAX_LINES, f"README.md has {n} lines; a user's guide keeps to {MAX_LINES} (details go to docs/)"


def test_the_readme_starts_with_the_two_commands():
    lines = README.read_text().splitlines()
    start = lines.index("```bash")
    assert start <= 3, "the first thing after the title is the code block with the two commands"
    for i, expected in enumerate(FIRST_COMMANDS, start=start + 1):
        assert lines[i].startswith(expected), f"README line {i + 1}: expected {expected!r}"


def test_anchors_are_githubs():
    assert slug("Speed: a 60-minute mission") == "speed-a-60-minute-mission"
    assert slug("The `htm` front-end (SP + TM)") == "the-htm-front-end-sp--tm"


def test_every_relative_link_of_the_readme_and_the_docs_resolves():
    docs = [README, *sorted((REPO / "docs").glob("*.md"))]
    bad = [b for doc in docs for b in broken_links(doc)]
    assert not bad, "broken links:\n" + "\n".join(bad)


def test_the_readme_results_quote_only_figures_of_the_documents_they_link():
    """A number in the last column of the results table must appear in a document that row links."""
    text = README.read_text()
    section = text.split("\n## Results", 1)[1].split("\n## ", 1)[0]
    missing = []
    for row in (r for r in section.splitlines() if r.startswith("|") and not r.startswith("|---")):
        cell = row.strip("|").split("|")[-1]
        targets = [(REPO / t.partition("#")[0]) for t in _LINK.findall(cell) if not t.startswith("http")]
        sources = " ".join(t.read_text() for t in targets if t.is_file())
        for number in re.findall(r"\d+(?:\.\d+)?", _LINK.sub("", cell)):
            if not re.search(rf"(?<![\d.]){re.escape(number)}(?![\d]|\.\d)", sources):
                missing.append(f"{number} in {row[:60]}...")
    assert not missing, "figures not found in the linked documents:\n" + "\n".join(missing)
