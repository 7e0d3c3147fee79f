"""The documentation's cross-references: the sections of docs/reference.md the code cites, and relative links."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def _headings(path: Path) -> set[str]:
    """GitHub's anchors of a Markdown file's headings (code blocks left out)."""
    text = re.sub(r"```.*?```", "", path.read_text(), flags=re.S)
    anchors, seen = set(), {}
    for title in re.findall(r"^#{1,6}\s+(.*)$", text, flags=re.M):
        slug = re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        anchors.add(slug if count == 0 else f"{slug}-{count}")
    return anchors


def test_cited_reference_sections_exist():
    sections = set(re.findall(r"^## (\d+)\. ", (ROOT / "docs" / "reference.md").read_text(), flags=re.M))
    cited = {}
    for path in [*(ROOT / "src").rglob("*.py"), *(ROOT / "conf").rglob("*.yaml")]:
        for match in re.finditer(r"reference\.md sections? (\d+)(?: and (\d+))?", path.read_text()):
            for number in filter(None, match.groups()):
                cited.setdefault(number, path.relative_to(ROOT))
    assert cited, "no citation of docs/reference.md found"
    assert {n: p for n, p in cited.items() if n not in sections} == {}


def test_relative_links_resolve():
    broken = []
    for doc in DOCS:
        body = re.sub(r"```.*?```", "", doc.read_text(), flags=re.S)
        for target in re.findall(r"\]\(([^)\s]+)\)", body):
            if target.startswith(("http://", "https://")):
                continue
            file, _, anchor = target.partition("#")
            path = (doc.parent / file).resolve() if file else doc
            if not path.exists():
                broken.append(f"{doc.name}: {target} (no such file)")
            elif anchor and path.suffix == ".md" and anchor not in _headings(path):
                broken.append(f"{doc.name}: {target} (no such heading)")
    assert broken == []
