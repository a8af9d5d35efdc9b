"""`make run` measured, not remembered (issue 35): the README's table is the make_run grid's committed summaries."""

import re

from experiments.grids import GRIDS
from experiments.make_run_table import make_run_table
from experiments.run_spec import ROOT
from experiments.store import ResultsStore


def test_the_readme_table_is_regenerated_from_the_committed_summaries():
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"<!-- makerun:begin -->\n(.*?)\n<!-- makerun:end -->", readme, re.S)
    assert block, "README.md lacks its makerun block"
    assert block.group(1) == make_run_table(ResultsStore(GRIDS["make_run"]).load()), \
        "stale: run `python -m experiments report --update README.md`"


def test_the_tally_counts_a_run_that_never_got_there_as_censored():
    runs = [{"seed": s, "seconds_to_90": t, "episodes_to_90": None if t is None else 10_000,
             "held_out_coverage": 0.9, "held_out_success": 0.6, "wall_s": 300.0 if t is None else t,
             "provenance": {"commit": "c" * 40, "dirty": False, "load_mean": 1.1}}
            for s, t in enumerate([100.0, None, 140.0, None])]
    text = make_run_table(runs)
    assert "| 1 | no | — | — | 0.900 |" in text and "| 0 | yes | 100 | 10,000 |" in text
    assert text.endswith("2 of 4 seeds reached MA 0.9 within the 300-second budget; Kaplan–Meier median time to "
                         "MA 0.9: ≥ 140 s.")
    assert make_run_table([]) == "not measured yet"
