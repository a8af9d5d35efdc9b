"""Every citation of the specification names a section that exists (docs/ALGORITHM.md, docs/DESIGN.md).

What is checked, over the repository's tracked text files (code, configs, docs, tests):
* "ALGORITHM.md §X", "ALGORITHM.md A12", ranges ("§3.4–3.5", "A5–A7") and lists ("§3.2, A2/A3") name a heading
  of docs/ALGORITHM.md; "§7 property N" names an item of its §7 list;
* a bare "§X" (the code cites the specification's sections that way too) names a heading of docs/ALGORITHM.md;
* every paper equation the code cites by number ("eq. 12", "eqs. 13–16") is a row of ALGORITHM.md's equation index;
* "DESIGN.md "Heading"" names a heading of docs/DESIGN.md (or a term the page defines in emphasis), "DESIGN.md §X"
  a numbered heading, and "DESIGN.md data flow step N" an item of its data-flow list.
The tests of the parser at the end show each check fails on a citation that names nothing.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALGORITHM = ROOT / "docs" / "ALGORITHM.md"
DESIGN = ROOT / "docs" / "DESIGN.md"
TEXT_SUFFIXES = {".py", ".md", ".toml", ".yaml", ".yml", ".cfg", ".txt", ".sh", ".ini"}

SECTION = r"\d+(?:\.\d+)*"
# the text after "ALGORITHM.md" that holds its section ids: up to a closing bracket, a semicolon, a colon, a
# sentence end or a citation of the other page
SPAN_END = re.compile(r"\)|;|:|\.\s|\.$|DESIGN\.md|\"")


def tracked_text_files() -> list[Path]:
    """The repository's tracked text files (git ls-files), without the generated results and this file (whose
    examples of citations name missing sections on purpose)."""
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    return [ROOT / name for name in names
            if (Path(name).suffix in TEXT_SUFFIXES or Path(name).name == "Makefile")
            and not name.startswith("lab/results/") and ROOT / name != Path(__file__).resolve()
            and (ROOT / name).is_file()]


def flat(text: str) -> str:
    """`text` with line breaks, comment leaders and runs of whitespace as single spaces."""
    return re.sub(r"\s+", " ", re.sub(r"\n[ \t]*(?:#|//|\*)?[ \t]*", " ", text))


def headings(page: str) -> list[str]:
    """The markdown headings of a page, without their leading #s."""
    return [line.lstrip("#").strip() for line in page.splitlines() if re.match(r"#{1,6} ", line)]


def section_ids(page: str) -> set[str]:
    """The ids of ALGORITHM.md's headings: "3.2" of "### 3.2 K-fold teachers", "A12" of "### A12 — ...",
    "eq. 20" of nothing (equations are checked against the index)."""
    out = set()
    for head in headings(page):
        m = re.match(rf"(?:§\s?)?({SECTION}|A\d+)\.?(?:\s|$)", head)
        if m:
            out.add(m.group(1))
    return out


def numbered_items(page: str, heading: str) -> set[int]:
    """The numbers of the list items ("7. ...") between the first heading matching `heading` and the next heading."""
    part = re.split(heading, page, maxsplit=1, flags=re.M)
    if len(part) < 2:
        return set()
    body = re.split(r"^#+ ", part[1], maxsplit=1, flags=re.M)[0]
    return {int(n) for n in re.findall(r"^(\d+)\. ", body, re.M)}


def properties(page: str) -> set[int]:
    """The item numbers of ALGORITHM.md's §7 list (the testable properties)."""
    return numbered_items(page, r"^## 7\.? .*$")


def indexed_equations(page: str) -> set[int]:
    """The equation numbers of ALGORITHM.md's equation index: the table rows that start with "| (N) |"."""
    return {int(n) for n in re.findall(r"^\| \((\d+)\) \|", page, re.M)}


def expand(first: str, last: str) -> list[str]:
    """The ids a range cites: A5–A7 -> A5, A6, A7; 3.4–3.5 -> 3.4, 3.5 (sections: its ends)."""
    if first.startswith("A") and last.startswith("A"):
        return [f"A{i}" for i in range(int(first[1:]), int(last[1:]) + 1)]
    return [first] if first == last else [first, last]


def algorithm_citations(text: str) -> list[tuple[str, str]]:
    """(kind, id) of every "ALGORITHM.md ..." citation in `text`: kind "section" (3.2, A12) or "property" (33)."""
    out: list[tuple[str, str]] = []
    text = flat(text)
    for m in re.finditer(r"ALGORITHM\.md(?:'s)?,?", text):
        rest = text[m.end():m.end() + 120]
        span = rest[:SPAN_END.search(rest).start()] if SPAN_END.search(rest) else rest
        out += ids_of_span(span)
    return out


def ids_of_span(span: str) -> list[tuple[str, str]]:
    """The ids of one citation's span: §-sections, A-items, ranges of both and "§7 properties 8, 16, 18–20"."""
    out: list[tuple[str, str]] = []
    token = rf"§\s?(?P<sec>{SECTION})(?:\s?[–-]\s?§?(?P<sec2>{SECTION}))?|\b(?P<a>A\d+)(?:\s?[–-]\s?(?P<a2>A\d+))?\b"
    for m in re.finditer(token, span):
        if m.group("sec"):
            out += [("section", s) for s in expand(m.group("sec"), m.group("sec2") or m.group("sec"))]
        else:
            out += [("section", s) for s in expand(m.group("a"), m.group("a2") or m.group("a"))]
    for m in re.finditer(r"§\s?7,? propert(?:y|ies) ((?:\d+(?:\s?[–-]\s?\d+)?(?:,\s?|\s(?:and)\s)?)+)", span):
        for part in re.findall(r"\d+(?:\s?[–-]\s?\d+)?", m.group(1)):
            ends = [int(n) for n in re.findall(r"\d+", part)]
            out += [("property", str(n)) for n in range(ends[0], ends[-1] + 1)]
    return out


def bare_sections(text: str) -> list[str]:
    """The §-ids of `text` not preceded by "DESIGN.md" (those are ALGORITHM.md's)."""
    text = flat(text)
    return [m.group(1) for m in re.finditer(rf"§\s?({SECTION})", text)
            if not re.search(r"DESIGN\.md(?:'s)?,?\s?$", text[max(0, m.start() - 14):m.start()])]


def cited_equations(text: str) -> list[int]:
    """The paper equation numbers `text` cites: "eq. 12", "eq. (12)", "eqs. 13–16", "eqs. (9)"."""
    out = []
    for m in re.finditer(r"\beqs?\.\s?\(?(\d+)\)?(?:\s?[–-]\s?\(?(\d+)\)?)?", text):
        first, last = int(m.group(1)), int(m.group(2) or m.group(1))
        out += list(range(first, last + 1))
    return out


def design_citations(text: str) -> list[tuple[str, str]]:
    """(kind, what) of every "DESIGN.md ..." citation: ("heading", quoted text), ("section", §-id) or
    ("step", data-flow step number)."""
    out = []
    text = flat(text)
    for m in re.finditer(r"DESIGN\.md(?:'s)?,?\s?", text):
        rest = text[m.end():m.end() + 80]
        step = re.match(r"\"?data[- ]flow\"?,? step (\d+)", rest, re.I)
        quoted = re.match(r"(?:\"([^\"]+)\"|“([^”]+)”)", rest)
        section = re.match(rf"§\s?({SECTION})", rest)
        if step:
            out.append(("step", step.group(1)))
        elif quoted:
            out.append(("heading", quoted.group(1) or quoted.group(2)))
        elif section:
            out.append(("section", section.group(1)))
    return out


def data_flow_steps(page: str) -> set[int]:
    """The numbered items under DESIGN.md's data-flow heading."""
    return numbered_items(page, r"^#+ .*[Dd]ata flows?.*$")


def design_has(page: str, kind: str, what: str) -> bool:
    """Whether DESIGN.md has the heading (or the emphasised term, *like this*), §-section or data-flow step a
    citation names."""
    if kind == "step":
        return int(what) in data_flow_steps(page)
    if kind == "section":
        return what in section_ids(page)
    low = re.sub(r"^(?:a|an|the) ", "", what.lower())
    terms = {t.lower() for t in re.findall(r"(?<![*\w])\*{1,2}([^*\n]+?)\*{1,2}(?![*\w])", page)}
    return any(low in head.lower() for head in headings(page)) or low in terms


@pytest.fixture(scope="module")
def files() -> dict[str, str]:
    return {str(p.relative_to(ROOT)): p.read_text(errors="replace") for p in tracked_text_files()}


def test_the_pages_exist_and_have_their_sections():
    page = ALGORITHM.read_text()
    assert {"2", "3.1", "3.9", "5", "6.4", "7", "A1", "A22"} <= section_ids(page)
    assert properties(page) == set(range(1, 34)), "ALGORITHM.md §7 must list properties 1-33"
    assert set(range(1, 21)) == indexed_equations(page), "the equation index must hold the paper's eqs. 1-20"
    assert data_flow_steps(DESIGN.read_text()) >= {1, 7}


def test_every_algorithm_citation_names_a_section(files):
    page = ALGORITHM.read_text()
    ids, props = section_ids(page), properties(page)
    missing = sorted({f"{name}: {kind} {what}" for name, text in files.items()
                      for kind, what in algorithm_citations(text)
                      if (kind == "section" and what not in ids) or (kind == "property" and int(what) not in props)})
    assert not missing, f"citations of sections docs/ALGORITHM.md lacks: {missing}"


def test_every_bare_section_sign_names_an_algorithm_section(files):
    ids = section_ids(ALGORITHM.read_text())
    missing = sorted({f"{name}: §{s}" for name, text in files.items() if name != "docs/DESIGN.md"
                      for s in bare_sections(text) if s not in ids})
    assert not missing, f"§-sections docs/ALGORITHM.md lacks: {missing}"


def test_every_equation_the_code_cites_is_in_the_index(files):
    index = indexed_equations(ALGORITHM.read_text())
    missing = sorted({f"{name}: eq. {n}" for name, text in files.items()
                      if name.split("/")[0] in {"cmcl", "services", "experiments", "lab", "bench", "tests"}
                      for n in cited_equations(text) if n not in index})
    assert not missing, f"equations the equation index of docs/ALGORITHM.md lacks: {missing}"


def test_every_design_citation_names_a_section(files):
    page = DESIGN.read_text()
    missing = sorted({f"{name}: {kind} {what!r}" for name, text in files.items()
                      for kind, what in design_citations(text) if not design_has(page, kind, what)})
    assert not missing, f"citations docs/DESIGN.md has nothing for: {missing}"


def test_the_parser_reads_every_form_of_citation():
    assert algorithm_citations("(ALGORITHM.md §3.2, A2/A3/A13/A19): the") == [
        ("section", "3.2"), ("section", "A2"), ("section", "A3"), ("section", "A13"), ("section", "A19")]
    assert algorithm_citations('"""x (ALGORITHM.md\n    §3.4–3.5, A5–A7).""" more §9') == [
        ("section", "3.4"), ("section", "3.5"), ("section", "A5"), ("section", "A6"), ("section", "A7")]
    assert ("property", "20") in algorithm_citations("(ALGORITHM.md §3.6, §7 properties 8, 16, 18–20, 22).")
    assert algorithm_citations("ALGORITHM.md §3.8–3.9, DESIGN.md data flow step 7)") == [
        ("section", "3.8"), ("section", "3.9")]
    assert bare_sections("as in §3.9 and DESIGN.md §2") == ["3.9"]
    assert cited_equations("eq. (11), eqs. 13–16 and eq. 20's") == [11, 13, 14, 15, 16, 20]
    assert design_citations('DESIGN.md "Modes"; DESIGN.md data-flow step 7; DESIGN.md §4') == [
        ("heading", "Modes"), ("step", "7"), ("section", "4")]


def test_a_citation_of_a_missing_section_is_caught():
    page = "## 3. CMCL\n### 3.1 Storage\n### A1 — Scale\n## 7. Properties\n1. one\n2. two\n"
    ids, props = section_ids(page), properties(page)
    assert ids == {"3", "3.1", "7", "A1"} and props == {1, 2}
    cited = algorithm_citations("(ALGORITHM.md §3.1, §3.2, A1, A2, §7 property 3)")
    assert [what for kind, what in cited if kind == "section" and what not in ids] == ["3.2", "A2"]
    assert [what for kind, what in cited if kind == "property" and int(what) not in props] == ["3"]
    design = "## Modes\n## Data flow\n1. rollout\n2. replay, a *provisional priority*; scorers\n"
    assert design_has(design, "heading", "Modes") and not design_has(design, "heading", "Scorers")
    assert design_has(design, "heading", "a provisional priority") and not design_has(design, "heading", "replay,")
    assert design_has(design, "step", "2") and not design_has(design, "step", "7")
    assert indexed_equations("| (3) | buffer |\n| (12) | KP |\n") == {3, 12}
