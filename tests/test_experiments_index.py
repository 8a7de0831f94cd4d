"""docs/experiments/README.md: one short line per record, each record listed, every link to a file that exists."""

from __future__ import annotations

import re
from pathlib import Path

EXPERIMENTS = Path(__file__).resolve().parents[1] / "docs" / "experiments"
INDEX = EXPERIMENTS / "README.md"


def test_the_index_lists_every_record_once_in_lines_of_at_most_200_characters():
    text = INDEX.read_text()
    assert max(len(line) for line in text.splitlines()) <= 200
    records = sorted(str(p.relative_to(EXPERIMENTS)) for p in EXPERIMENTS.rglob("*.md") if p != INDEX)
    linked = re.findall(r"^- \[[^]]+\]\(([^)]+\.md)\): ", text, flags=re.MULTILINE)
    assert sorted(linked) == records
    archived = [link.startswith("archive/") for link in linked]
    assert any(archived) and archived == sorted(archived)  # the archive's lines come last


def test_links_to_the_records_across_the_repository_name_files_that_exist():
    root = EXPERIMENTS.parents[1]
    pattern = re.compile(r"docs/experiments/[\w./-]+?\.md")
    texts = [p for folder in ("docs", "model", "tests", "service", "rsmt_cli") for p in (root / folder).rglob("*")
             if p.suffix in (".md", ".py", ".json") and p.is_file()] + [root / "README.md"]
    missing = {(str(p.relative_to(root)), link) for p in texts for link in pattern.findall(p.read_text(errors="replace"))
               if not (root / link).is_file()}
    assert not missing, sorted(missing)
    assert any("docs/experiments/archive/" in p.read_text(errors="replace") for p in texts)  # the pattern finds links
