"""The report's tests read the code a cell's runs ran (experiments.provenance.cell_versions): a cell of one code
version is tested, a mixed one is not, and the table says so."""

from lab.report.curriculum_tables import curriculum_tests
from tests.test_provenance import summary


def test_the_report_refuses_a_mixed_cell_and_tests_a_clean_one():
    runs = [summary(a, s, 0.5 + 0.01 * s + (0.1 if a == "maddpg" else 0), "a" * 40)
            for a in ("maddpg", "cmcl") for s in range(4)]
    clean = curriculum_tests(runs, [("cmcl", "maddpg", "auc_coverage")])
    assert "aaaaaaa" in clean and "not tested" not in clean
    runs[0]["provenance"].update(commit="b" * 40, segment_commits=["b" * 40])
    mixed = curriculum_tests(runs, [("cmcl", "maddpg", "auc_coverage")])
    assert "not tested: code versions mixed" in mixed and "bbbbbbb (1 runs)" in mixed
