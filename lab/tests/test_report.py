"""The statistics and tables of the report (lab.report.stats, lab.report.tables, lab.report.curriculum_tables):
intervals, censored times, paired differences, Holm; and the blocks of lab/RESULTS.md from the committed results."""

import numpy as np
import pytest
from scipy import stats

from lab.report.curriculum_tables import SETTING_TABLES, curriculum_table, curriculum_tests, setting_table
from lab.report.stats import bootstrap_ci, detectable, fmt, holm, km_median, logrank_p, mean_ci, paired
from lab.report.tables import ablation_table


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
    assert "not reached (0/3 reached)" in table[2]  # censored: no run got there


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

    from lab.report.figures import ablation_figure

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


def test_rate_intervals_stay_in_the_unit_interval_where_t_intervals_leave_it():
    rates = [0.99, 0.98, 0.08, 0.97, 0.99]  # one failed seed (the eta1 row of the ablations had 0.763 ± 0.481)
    m, h = mean_ci(rates)
    assert m + h > 1  # the Student-t interval leaves [0, 1] ...
    m2, lo, hi = bootstrap_ci(rates)
    assert m2 == m and 0 <= lo < m < hi <= 1  # ... the bootstrap one does not
    assert fmt(rates, 3, "held_out_success").startswith(f"{m:.3f} [")


def test_kaplan_meier_median_counts_the_runs_that_never_got_there():
    assert km_median([100, 200, 300, None, None]) == (300.0, 3)  # not the mean 200 of the three survivors
    assert km_median([100, None, None, None]) == (None, 1)
    assert fmt([100, 200, 300, None, None], 0, "episodes_to_90") == "KM median 300 (3/5 reached)"
    assert logrank_p([100, 120, 130, 140, 150], [None] * 5, 1000) < 0.01
    assert logrank_p([100, None], [100, None], 1000) > 0.9


def test_holm_adjusts_step_down_and_keeps_the_order():
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    assert holm([0.5]) == [0.5]


def test_curriculum_tests_put_the_primary_comparison_first_and_holm_correct_the_rest():
    rng = np.random.default_rng(0)
    runs = [{"arm": arm, "seed": s, "budget": 100, "auc_coverage": base + rng.normal(0, 0.01),
             "held_out_success": 0.9, "episodes_to_90": 50 + s}
            for arm, base in (("maddpg", 0.70), ("per", 0.7), ("acl", 0.7), ("cmcl", 0.8), ("cmcl_permuted", 0.7),
                              ("cmcl_anti", 0.7)) for s in range(5)]
    lines = curriculum_tests(runs).splitlines()[2:]
    assert lines[0].startswith("| CMCL − MADDPG | auc_coverage | 5 vs 5 | unrecorded | +0.")
    assert "| primary | 0." in lines[0]
    assert len(lines) == 9 and all(line.split(" | ")[-2] for line in lines[1:])


def test_predator_prey_curriculum_tables_test_the_win_curve_and_count_no_stalls():
    rng = np.random.default_rng(1)
    runs = [{"arm": arm, "seed": s, "budget": 100, "task": "tag", "auc_predator_win": base + rng.normal(0, 0.01),
             "final_ma_predator_win": 0.9, "win_vs_random_prey": 0.9 + rng.normal(0, 0.01),
             "win_vs_trained_prey": 0.8, "episodes_to_win_90": None if s == 0 else 60 + s, "ess_mean": 0.8,
             "ess_first_quarter": 0.5, "wall_s": 10.0,
             "sampling_curve": {"episode": [20, 100], "reward_rows_sampled": [0.1, 0.2],
                                "reward_rows_buffer": [0.1, 0.2]}}
            for arm, base in (("maddpg", 0.60), ("per", 0.6), ("acl", 0.6), ("cmcl", 0.5), ("cmcl_permuted", 0.6),
                              ("cmcl_anti", 0.6)) for s in range(4)]
    lines = curriculum_tests(runs).splitlines()[2:]
    assert lines[0].startswith("| CMCL − MADDPG | auc_predator_win | 4 vs 4 | unrecorded | -0.")
    assert "| primary | 0." in lines[0]
    assert [line.split(" | ")[1] for line in lines[-2:]] == ["win_vs_random_prey", "episodes_to_win_90"]
    assert "KM median" in lines[-1] and "(3/4 reached)" in lines[-1]
    table = curriculum_table(runs).splitlines()
    assert "stalled" not in table[0] and "area under predator win" in table[0]
    assert all(line.count("|") == table[0].count("|") for line in table)


def test_the_stride_tables_holm_correct_every_test_and_measure_the_curriculum_while_lambda_is_below_half():
    """The λ-schedule grid has no primary comparison; its table reads the sampling while λ < 0.5 in each arm's own
    schedule, not over a fixed quarter of the budget."""
    rng = np.random.default_rng(2)

    def run(arm: str, seed: int, base: float, lam_step: float) -> dict:
        lam = [min(1.0, 0.1 + lam_step * k) for k in range(1, 11)]
        return {"arm": arm, "seed": seed, "budget": 1000, "auc_coverage": base + rng.normal(0, 0.01),
                "held_out_coverage": 0.9, "held_out_success": 0.5, "episodes_to_50": 300 + seed,
                "episodes_to_90": None, "final_ma_coverage": 0.75 if seed == 0 else 0.95,
                "sampling_curve": {"episode": [100 * k for k in range(1, 11)], "lambda": lam,
                                   "ess": [0.4 if v < 0.5 else 0.9 for v in lam],
                                   "reward_rows_sampled": [0.01 if v < 0.5 else 0.2 for v in lam],
                                   "reward_rows_buffer": [0.1] * 10}}

    arms = (("maddpg", 0.6, 0.0), ("cmcl", 0.4, 0.1), ("cmcl_stride_x2", 0.5, 0.2), ("cmcl_stride_half", 0.3, 0.05))
    runs = [run(arm, s, base, step) for arm, base, step in arms for s in range(4)]
    arms, comparisons = SETTING_TABLES["curriculum_stride"]
    tests = curriculum_tests(runs, comparisons).splitlines()[2:]
    assert [line.split(" | ")[0] for line in tests] == ["| CMCL, λ stride ×2 − CMCL", "| CMCL, λ stride ×½ − CMCL",
                                                        "| CMCL, λ stride ×2 − MADDPG"]
    assert all(float(line.split(" | ")[-2]) >= float(line.split(" | ")[-3]) for line in tests)
    table = {line.split(" | ")[0]: line.split(" | ") for line in setting_table(runs, arms).splitlines()[2:]}
    assert list(table) == ["| MADDPG", "| CMCL, λ stride ×2", "| CMCL", "| CMCL, λ stride ×½"]
    assert table["| CMCL"][8:10] == ["300", "0.40"]  # λ = 0.2, 0.3, 0.4 below 0.5: the rows up to episode 300
    assert table["| CMCL, λ stride ×2"][8] == "100" and table["| CMCL, λ stride ×½"][8] == "700"
    assert table["| CMCL"][10] == "0.010 / 0.100 |" and table["| MADDPG"][7] == "1/4"


def test_the_report_of_the_committed_results_is_the_page_as_committed(tmp_path):
    """`python -m lab report --update lab/RESULTS.md` on the committed summaries changes nothing: the
    page's tables are those of its results."""
    from experiments.run_spec import ROOT
    from lab.report.report import blocks, update

    page = tmp_path / "RESULTS.md"
    page.write_text((ROOT / "lab" / "RESULTS.md").read_text())
    new = blocks()
    assert {"spread", "seeds", "tests", "ablations", "tag", "tagtests", "curriculum", "curriculumtests",
            "curriculumhard", "curriculumhardtests", "timetosolve", "screen", "screenselect", "confirm",
            "confirmtests"} <= set(new)
    update(page, new)
    assert page.read_text() == (ROOT / "lab" / "RESULTS.md").read_text()


def test_the_hard_curriculum_grid_gets_the_same_tables_in_its_own_blocks(tmp_path):
    import shutil

    from experiments.grids import RESULTS
    from lab.report.report import NO_RUNS, blocks

    empty = blocks(tmp_path)
    assert empty["curriculumhard"] == empty["curriculumhardtests"] == NO_RUNS
    assert empty["curriculum"] == NO_RUNS  # no summaries under this results root at all
    shutil.copytree(RESULTS / "curriculum" / "summaries", tmp_path / "curriculum_hard" / "summaries")
    both = blocks(tmp_path)
    committed = blocks()
    assert both["curriculumhard"] == committed["curriculum"] != NO_RUNS
    assert both["curriculumhardtests"] == committed["curriculumtests"]


def test_the_older_time_to_solve_log_reads_as_summaries_and_counts_as_finished(tmp_path):
    import json

    from experiments.store import ResultsStore

    line = {"id": "schedule_inline_maddpg_u1_b128_s0", "mode": "inline", "algorithm": "maddpg", "seed": 0,
            "update_every": 1, "batch_size": 128, "episodes": 1904, "episodes_to_90": None, "wall_s": 305.3,
            "held_out": {"coverage": 0.18, "success": 0.0, "collisions": 7.1, "wall_hits": 22.1}}
    (tmp_path / "results.jsonl").write_text(json.dumps(line) + "\n")
    store = ResultsStore(tmp_path)
    [run] = store.load()
    assert run["grid"] == "schedule" and run["task"] == "spread" and run["held_out_coverage"] == 0.18
    assert "held_out" not in run and store.finished() == {line["id"]}
    store.write({**run, "held_out_coverage": 0.5})  # a summary of the same id wins over the log's line
    assert [r["held_out_coverage"] for r in store.load()] == [0.5]


def test_a_median_at_the_censoring_edge_is_labelled_a_lower_bound():
    """5 of 10 runs reach the threshold: the survival curve falls to exactly 0.5 at the fifth event and the other
    runs are censored at the budget, so the median is that time or any later one."""
    times = [100, 200, 300, 400, 500] + [None] * 5
    assert km_median(times) == (500.0, 5)
    assert fmt(times, 0, "episodes_to_90") == "KM median ≥ 500 (5/10 reached)"
    assert fmt([100, 200, 300, 400, 500, 600] + [None] * 4, 0, "episodes_to_90") == "KM median 500 (6/10 reached)"
    assert fmt([100, 200, 300, 400, 500] + [None] * 4, 0, "episodes_to_90") == "KM median 500 (5/9 reached)"
    assert fmt([100, 200, None], 0, "episodes_to_90") == "KM median 200 (2/3 reached)"
    assert fmt([100, None, None, None], 0, "episodes_to_90") == "not reached (1/4 reached)"


def test_the_detectable_difference_of_a_holm_corrected_test_is_at_the_familys_alpha():
    """The primary test is judged at α = 0.05; each of m Holm-corrected tests at α / m (Holm's first step), so its
    detectable difference is larger than at 0.05."""
    rng = np.random.default_rng(3)
    arms, comparisons = SETTING_TABLES["curriculum_stride"]
    runs = [{"arm": arm, "seed": s, "budget": 1000, "auc_coverage": base + rng.normal(0, 0.1)}
            for arm, base in (("maddpg", 0.6), ("cmcl", 0.4), ("cmcl_stride_x2", 0.45), ("cmcl_stride_half", 0.3))
            for s in range(10)]
    by_arm = {arm: [r["auc_coverage"] for r in runs if r["arm"] == arm] for arm in arms}
    for line, (a, b, _) in zip(curriculum_tests(runs, comparisons).splitlines()[2:], comparisons, strict=True):
        cell = line.split(" | ")[-1].strip(" |")
        assert cell == f"{detectable(by_arm[a], by_arm[b], 0.05 / 3):.3f} (α 0.017)"
        assert float(cell.split()[0]) > detectable(by_arm[a], by_arm[b], 0.05)
    x, y = by_arm["cmcl_stride_x2"], by_arm["cmcl"]  # the formula: (t[1 − α/2] + t[0.8]) · SE at Welch's dof
    va, vb = np.var(x, ddof=1) / 10, np.var(y, ddof=1) / 10
    dof = (va + vb) ** 2 / (va ** 2 / 9 + vb ** 2 / 9)
    assert detectable(x, y, 0.01) == pytest.approx((stats.t.ppf(0.995, dof) + stats.t.ppf(0.8, dof)) * np.sqrt(va + vb))
    primary = curriculum_tests([{**r, "held_out_success": 0.5, "episodes_to_90": None} for r in runs
                                if r["arm"] in ("maddpg", "cmcl")]).splitlines()[2]
    assert primary.endswith(f"| primary | {detectable(by_arm['cmcl'], by_arm['maddpg'], 0.05):.3f} (α 0.05) |")


class Axes:
    """Records what a figure function draws: the lines and the bands."""

    def __init__(self):
        self.lines, self.bands = [], []

    def plot(self, x, y, **_):
        self.lines.append(np.asarray(y))

    def fill_between(self, x, lo, hi, **_):
        self.bands.append((np.asarray(lo), np.asarray(hi)))


def test_the_figures_bands_of_a_rate_stay_in_the_unit_interval():
    """A rate's band over seeds is a bootstrap band, inside [0, 1], where a t band leaves it (coverage near 1 with one
    slow seed); a reward keeps its t band; the sampling figure's ESS band likewise stays within [0, 1]."""
    from lab.report.curriculum_figure import sampling_band
    from lab.report.figures import band

    curves = [[0.2, 0.9, 1.0, 1.0], [0.1, 0.95, 1.0, 0.99], [0.0, 0.1, 0.5, 0.98], [0.3, 0.97, 1.0, 1.0]]
    ax = Axes()
    band(ax, curves, "red", "CMCL", rate=True)
    [(lo, hi)] = ax.bands
    assert np.all(lo >= 0) and np.all(hi <= 1) and np.all(lo <= ax.lines[0]) and np.all(ax.lines[0] <= hi)
    band(ax, curves, "red", "CMCL")  # not a rate: the t band, which here leaves [0, 1]
    assert ax.bands[1][1].max() > 1 or ax.bands[1][0].min() < 0
    ess = [np.array([np.nan, 0.5, 0.99, 1.0]), np.array([0.2, 0.6, 0.4, 1.0]), np.array([np.nan, 0.55, 0.98, 1.0])]
    ax = Axes()
    sampling_band(ax, np.arange(4.0), ess, "red")
    [(lo, hi)] = ax.bands
    assert np.isnan(lo[0]) and np.isclose(ax.lines[0][0], 0.2)  # one run has a value: its mean, no band
    assert np.all(lo[1:] >= 0) and np.all(hi[1:] <= 1) and np.isclose(lo[3], 1.0) and np.isclose(hi[3], 1.0)


def test_the_report_reads_a_rerun_at_one_commit_once_it_holds_every_run(tmp_path):
    import json

    from experiments.grids import grid
    from lab.report.report import blocks, folders
    from lab.report.reruns import RERUN_COMMIT, RERUN_SEEDS, rerun_progress

    rerun = tmp_path / f"curriculum_hard_{RERUN_COMMIT}" / "summaries"
    rerun.mkdir(parents=True)
    needed = sorted(run.id for run in grid(["curriculum_hard"], list(RERUN_SEEDS)))
    for run_id in needed[:-1]:
        (rerun / f"{run_id}.json").write_text(json.dumps({"id": run_id}))
    assert rerun_progress("curriculum_hard", rerun.parent) == (len(needed) - 1, len(needed)) == (59, 60)
    assert folders(tmp_path)["curriculum_hard"] == tmp_path / "curriculum_hard"  # one run short: the first folder
    assert f"curriculum grid {len(needed) - 1} of 60 runs" in blocks(tmp_path)["reruns"]
    (rerun / "curriculum_hard_maddpg_s99.json").write_text(json.dumps({"id": "curriculum_hard_maddpg_s99"}))
    assert folders(tmp_path)["curriculum_hard"] == tmp_path / "curriculum_hard"  # a seed it does not need
    (rerun / f"{needed[-1]}.json").write_text(json.dumps({"id": needed[-1]}))
    where = folders(tmp_path)
    assert where["curriculum_hard"] == rerun.parent and where["curriculum_stride"] == tmp_path / "curriculum_stride"
    # the page's figure follows the folder the report reads
    from lab.report.report import FIGURE_LINKS, figure_link

    grid_name, alt = FIGURE_LINKS["curriculumhardfigure"]
    link = figure_link(where[grid_name], alt)
    assert link.startswith(f"![{alt}](") and link.endswith(f"curriculum_hard_{RERUN_COMMIT}/figures/"
                                                           "curriculum_sampling.png)"), link
