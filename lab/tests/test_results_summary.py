"""docs/RESULTS.md, the five-minute summary, quotes the record: every number it gives stands in lab/RESULTS.md, and
every link to the record names one of the record's headings (GitHub's anchors)."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SUMMARY, RECORD = ROOT / "docs" / "RESULTS.md", ROOT / "lab" / "RESULTS.md"
NUMBER = re.compile(r"\d[\d,]*(?:\.\d+)?")


def anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_number_of_the_summary_stands_in_the_record():
    record = RECORD.read_text()
    text = re.sub(r"\]\([^)]*\)", "]", SUMMARY.read_text())  # the links' targets are no numbers
    numbers = {n for n in NUMBER.findall(text) if len(n.replace(",", "")) > 1}
    assert len(numbers) > 50
    assert sorted(n for n in numbers if n not in record) == []


def test_every_link_of_the_summary_names_a_heading_of_the_record():
    headings = {anchor(line.lstrip("#")) for line in RECORD.read_text().splitlines() if re.match(r"#{1,6} ", line)}
    links = re.findall(r"\]\(\.\./lab/RESULTS\.md#([^)]+)\)", SUMMARY.read_text())
    assert len(links) > 20
    assert sorted(set(links) - headings) == []


def test_the_summary_reads_in_five_minutes():
    assert len(SUMMARY.read_text().splitlines()) <= 80
    assert anchor("Sparse cooperative navigation, N = 4 (the paper's Figs. 8–9)") == \
        "sparse-cooperative-navigation-n--4-the-papers-figs-89"
