"""The docs read as a manual: present tense, no dated runs. Measured figures live on the generated benchmarks
page (``python -m benchmarks.page``), which says the machine and date each section ran on."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted(p for p in (ROOT / "docs").glob("*.md") if p.name != "benchmarks.md") + [ROOT / "README.md"]
DATED = re.compile(
    r"\b20\d\d-\d\d-\d\d\b|\btoday\b|\byesterday\b|\bthe day's\b|\bon an earlier day\b|\bthis machine\b"
    r"|\bslower machine\b|\bthe default then\b|\bthe setting before\b",
    re.I,
)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_no_dated_prose_outside_the_benchmarks_page(page):
    found = [line.strip() for line in page.read_text().splitlines() if DATED.search(line)]
    assert not found, f"{page.name} reads as a lab notebook: {found}"


def test_pages_link_the_benchmarks_page_for_figures():
    linking = [p.name for p in PAGES if "benchmarks.md" in p.read_text()]
    assert {"mission.md", "engine.md", "planner.md", "noise_models.md"} <= set(linking)
