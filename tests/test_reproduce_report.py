"""The statistics of the reproduction report (bench/reproduce_report.py): intervals and paired differences."""

import numpy as np
from scipy import stats

from bench.reproduce_report import ablation_table, mean_ci, paired


def test_mean_ci_is_the_student_t_interval():
    values = [0.1, 0.4, 0.35, 0.2]
    m, h = mean_ci(values)
    lo, hi = stats.t.interval(0.95, len(values) - 1, loc=np.mean(values), scale=stats.sem(values))
    assert np.isclose(m, np.mean(values)) and np.isclose(m - h, lo) and np.isclose(m + h, hi)


def test_paired_uses_only_the_seeds_both_have_and_the_differences_of_each():
    variant = {0: 0.70, 1: 0.80, 2: 0.75, 7: 5.0}
    reference = {0: 0.60, 1: 0.72, 2: 0.64, 3: -9.0}
    text = paired(variant, reference, 3)
    d = [0.10, 0.08, 0.11]
    assert text.startswith(f"{np.mean(d):+.3f} [") and text.endswith(", n = 3")
    assert f"p = {stats.ttest_1samp(d, 0.0).pvalue:.3f}" in text


def test_paired_says_when_there_are_too_few_common_seeds():
    assert paired({0: 1.0, 1: 2.0}, {1: 1.5, 2: 0.0}) == "n/a (1 paired seed)"


def ablation_run(ablation, seed, auc, budget=20_000):
    return {"ablation": ablation, "seed": seed, "budget": budget, "auc_coverage": auc, "held_out_coverage": 0.9,
            "held_out_success": 0.5 + auc / 10, "episodes_to_90": None, "mean_reward": 1.0, "wall_s": 100.0}


def test_ablation_table_lists_each_variant_with_its_seeds():
    reference = [ablation_run(None, s, 0.7 + s / 100) for s in range(3)]
    table = ablation_table([ablation_run("eta0", 0, 0.5), ablation_run("eta0", 2, 0.55)], reference).splitlines()
    assert len(table) == 4 and table[3].startswith("| eta0 | 20,000 | 0,2 |")
    assert "-0.185" in table[3] and "n = 2" in table[3]
    assert "never (3/3)" in table[2]


def test_a_shorter_variant_is_paired_with_the_reference_read_to_its_budget():
    full = [ablation_run(None, s, 0.7) for s in range(2)]
    prefix = [ablation_run(None, s, 0.2 + s / 100, budget=4_000) for s in range(2)]
    variants = [ablation_run("paper_schedule", s, 0.3 + s / 50, budget=4_000) for s in range(2)]
    table = ablation_table(variants + [ablation_run("k2", 0, 0.6), ablation_run("k2", 1, 0.6)], full + prefix)
    lines = table.splitlines()[2:]
    assert [line.split(" | ")[0] for line in lines] == [
        "| reference (η 0.5, K 5, max, default stride, IS off)", "| k2", "| reference, its first 4,000 episodes",
        "| paper_schedule"]
    assert "+0.105 [" in lines[3]  # paper_schedule against the prefix: 0.30 − 0.20 and 0.32 − 0.21
    assert "-0.100 (no spread, n = 2)" in lines[1]  # k2 against the full runs


def test_the_ablation_figure_draws_a_panel_per_budget(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from bench.reproduce_figures import ablation_figure

    def run(ablation, seed, budget):
        curve = list(np.linspace(0, 1, budget // 100))
        return {**ablation_run(ablation, seed, 0.5, budget), "curves": {"coverage": curve}}

    reference = [run(None, s, 2_000) for s in range(2)]
    png = ablation_figure([run("k2", 0, 2_000), run("paper_schedule", 0, 400), run("paper_schedule", 1, 400)],
                          reference, tmp_path, plt)
    assert png.name == "ablations_coverage.png" and png.stat().st_size > 10_000
    width, height = plt.imread(png).shape[1::-1]
    assert width > 1.8 * height  # two panels side by side
    png = ablation_figure([run("k2", 0, 2_000)], reference, tmp_path, plt)
    width, height = plt.imread(png).shape[1::-1]
    assert width < 1.8 * height  # one panel
