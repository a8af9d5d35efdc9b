"""No tracked file cites a tracker's issue number in code, and none points at the spec folder outside the
repository (the one beside the checkout, which a user's clone does not have).

What is checked, over `git ls-files` (.py, .md, .toml):
* a .py file never cites an issue by number (the word, then a number, with or without "#": the pattern ISSUE): a
  comment cites the spec section (ALGORITHM.md §X, DESIGN.md §X) or says why in words. Identifiers that merely hold
  digits after the word inside a longer name (names of stored results and of a bench flag) are not citations;
* no file names the outside spec folder (the pattern SHARED): the specification lives in docs/ALGORITHM.md and
  docs/DESIGN.md.
The tests of the patterns at the end show each check fails on the text it is meant to catch; their examples are
built from pieces, so that this file does not itself hold what it forbids.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = {".py", ".md", ".toml"}
ISSUE = re.compile(r"\bissues?\s?#?\d+", re.IGNORECASE)
# assembled so that this file does not name what it forbids (and the walk skips it anyway, as test_spec_citations
# skips its own examples)
WORD = "iss" + "ue"
SHARED = re.compile(re.escape("..") + "/" + "shared" + r"\b|/work/" + "shared" + r"\b")


def tracked() -> list[Path]:
    """The tracked .py, .md and .toml files of the repository (git ls-files), as paths under ROOT."""
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    return [ROOT / n for n in names
            if Path(n).suffix in SUFFIXES and (ROOT / n).is_file() and ROOT / n != Path(__file__).resolve()]


def offences(name: str, text: str) -> list[str]:
    """"name:line: text" for each line of `text` (the contents of file `name`) that cites an issue number (.py files
    only) or names the shared folder (every file)."""
    out = []
    for number, line in enumerate(text.splitlines(), start=1):
        if (name.endswith(".py") and ISSUE.search(line)) or SHARED.search(line):
            out.append(f"{name}:{number}: {line.strip()}")
    return out


def test_no_tracked_file_cites_an_issue_number_or_the_shared_folder():
    files = tracked()
    assert ROOT / "cmcl" / "__init__.py" in files  # the walk sees the repository's files
    found = [hit for p in files for hit in offences(str(p.relative_to(ROOT)), p.read_text(encoding="utf-8"))]
    assert not found, "\n".join(found)


def test_the_patterns_catch_what_they_forbid_and_spare_identifiers():
    bad = [f"# the rule before {WORD} 38", f'"""{WORD.title()} 37: a torn line."""', f"x = 1  # {WORD}s 22 and 38",
           f"(see {WORD} #5)", f"({WORD}21)"]
    for line in bad:
        assert offences("a.py", line), line
    assert not offences("a.md", f"the rule before {WORD} 38")  # docs are checked by hand, not by this pattern
    spared = [f"def before_{WORD}_38(m):", f'REFACTORING = "time_to_solve_{WORD}8"', f"# the t{WORD} 3 layers",
              f"# no {WORD} here"]
    for line in spared:
        assert not offences("a.py", line), line
    shared = ".." + "/" + "shared" + "/ALGORITHM.md §5"
    assert offences("a.md", f"see {shared}") == [f"a.md:1: see {shared}"]
    assert offences("a.toml", "# /work/" + "shared" + "/x") and not offences("a.py", "'shared' networks")
