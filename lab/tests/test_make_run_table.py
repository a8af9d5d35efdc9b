"""`make run` measured, not remembered: the README's table is the make_run grid's committed summaries."""

import re

from experiments.grids import GRIDS, MAKE_RUN
from experiments.run_spec import ROOT
from experiments.store import ResultsStore
from lab.report.make_run_table import earlier_runs, make_run_summary, make_run_table, tally


def block_of(path, name: str) -> str:
    found = re.search(rf"<!-- {name}:begin -->\n(.*?)\n<!-- {name}:end -->", path.read_text(), re.S)
    assert found, f"{path.name} lacks its {name} block"
    return found.group(1)


def test_the_readme_table_and_the_records_are_regenerated_from_the_committed_summaries():
    runs = ResultsStore(GRIDS["make_run"]).load()
    assert block_of(ROOT / "README.md", "makerun") == make_run_summary(runs, MAKE_RUN["config"]), \
        "stale: run `python -m lab report --update README.md`"
    assert block_of(ROOT / "lab" / "RESULTS.md", "makerun_record") == make_run_table(
        runs, MAKE_RUN["config"], earlier_runs(GRIDS["make_run"])), \
        "stale: run `python -m lab report --update lab/RESULTS.md`"


def test_the_readme_view_names_no_commit_and_the_records_does():
    runs = [run(0, 100.0), run(1, None)]
    user, record = make_run_summary(runs, "now.toml"), make_run_table(runs, "now.toml")
    assert "ccccccc" not in user and "ccccccc" in record
    assert "| 0 | yes | 100 | 10,000 | 0.900 | 0.600 |" in user and "| 1 | no | — | — | 0.900 | 0.600 |" in user
    assert user.endswith("1 of 2 seeds reached MA 0.9 within the 300-second budget; Kaplan–Meier median time to "
                         "MA 0.9: ≥ 100 s.")
    assert make_run_summary([], "now.toml") == "not measured yet"


def test_the_tally_counts_a_run_that_never_got_there_as_censored():
    runs = [run(s, t) for s, t in enumerate([100.0, None, 140.0, None])]
    text = make_run_table(runs, "now.toml")
    assert "| 1 | no | — | — | 0.900 |" in text and "| 0 | yes | 100 | 10,000 |" in text and "| ccccccc | — |" in text
    assert text.endswith("2 of 4 seeds reached MA 0.9 within the 300-second budget; Kaplan–Meier median time to "
                         "MA 0.9: ≥ 140 s (code ccccccc).")
    assert make_run_table([], "now.toml") == "not measured yet"


def run(seed: int, seconds: float | None, config: str = "now.toml", commit: str = "c" * 40) -> dict:
    """A make_run summary: reached MA 0.9 after `seconds` (None: not in its 300 s)."""
    return {"seed": seed, "seconds_to_90": seconds, "episodes_to_90": None if seconds is None else 10_000,
            "held_out_coverage": 0.9, "held_out_success": 0.6, "wall_s": 300.0 if seconds is None else seconds,
            "config": config, "provenance": {"commit": commit, "dirty": False, "load_mean": 1.1}}


def test_the_table_holds_todays_make_run_and_tallies_what_it_trained_before_apart():
    runs = [run(0, 100.0), run(1, 120.0), run(0, None, "before.toml", "b" * 40), run(1, None, "before.toml", "b" * 40)]
    text = make_run_table(runs, "now.toml")
    assert text.count("| yes |") == 2 and "| no |" not in text
    assert "2 of 2 seeds reached MA 0.9" in text and text.endswith(
        "Earlier, `make run` trained `configs/before.toml`: 0 of 2 seeds reached MA 0.9 within the 300-second budget; "
        "Kaplan–Meier median time to MA 0.9: not reached (code bbbbbbb).")
    assert make_run_table(runs[2:], "now.toml").startswith("not measured yet\n\nEarlier, `make run` trained")


def test_an_earlier_measurement_of_the_same_config_is_tallied_apart_by_commit_with_its_day_and_cpu():
    earlier = [run(0, None, commit="e" * 40), run(1, 200.0, commit="e" * 40)]
    for r, cpu in zip(earlier, ("EPYC", ""), strict=True):
        r["provenance"].update(measured_utc="2026-12-05 08:16", cpu={"model": cpu} if cpu else None)
    text = make_run_table([run(0, 90.0)], "now.toml", earlier)
    assert "1 of 1 seeds reached MA 0.9" in text.split("Earlier")[0]
    assert text.endswith("Earlier, `make run` trained `configs/now.toml` (measured 2026-12-05 on EPYC): 1 of 2 seeds "
                         "reached MA 0.9 within the 300-second budget; Kaplan–Meier median time to MA 0.9: ≥ 200 s "
                         "(code eeeeeee).")


def test_a_run_that_ran_out_of_episodes_before_its_seconds_is_said_so():
    runs = [run(0, 80.0), {**run(1, None), "episodes": 20_000, "budget": 20_000, "wall_s": 155.0},
            {**run(2, 90.0), "budget": 20_000}]
    assert tally(runs).startswith("2 of 3 seeds reached MA 0.9 within the budget, 300 s of training or 20,000 "
                                  "episodes, whichever ends first (the 1 that did not ran out of episodes first, at "
                                  "155 s); Kaplan–Meier median time to MA 0.9: 90 s")
    runs.append({**run(3, None), "episodes": 9_000, "budget": 20_000})
    assert "(1 of the 2 that did not ran out of episodes first, at 155 s)" in tally(runs)
    assert tally([run(0, 80.0), run(1, None)]).startswith("1 of 2 seeds reached MA 0.9 within the 300-second budget")
