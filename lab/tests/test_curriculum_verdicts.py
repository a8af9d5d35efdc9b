"""The harder task's verdict table (lab.report.curriculum_verdicts) follows its tests: a verdict per question at the
level its test is judged at, "withdrawn" without numbers for mixed code, the code the tests ran."""

from lab.report.curriculum_verdicts import setting_verdict_table, verdict_rows, verdict_table

ARMS = ("maddpg", "per", "acl", "cmcl", "cmcl_permuted", "cmcl_anti")


def grid(means: dict[str, float], commits: dict[str, list[str]] | None = None) -> list[dict]:
    """A navigation curriculum grid of 6 seeds per arm: arm -> the mean of its areas (spread ±0.02 by seed); success
    follows the area, the time to MA 0.9 falls with it (never reached below an area of 0.4)."""
    out = []
    for arm in ARMS:
        for seed, jitter in enumerate((-0.02, 0.0, 0.02, -0.01, 0.01, 0.0)):
            value = means[arm] + jitter
            commit = (commits or {}).get(arm, ["a" * 40] * 6)[seed]
            out.append({"arm": arm, "task": "spread", "seed": seed, "budget": 20_000, "auc_coverage": value,
                        "held_out_success": value, "episodes_to_90": None if value < 0.4 else
                        round(20_000 * (1.2 - value)) + seed, "provenance": {"commit": commit, "dirty": False}})
    return out


def test_a_curriculum_behind_every_arm_but_level_with_acl_is_judged_so_at_each_tests_level():
    rows = verdict_rows(grid({"maddpg": 0.62, "per": 0.65, "acl": 0.32, "cmcl": 0.33, "cmcl_permuted": 0.66,
                              "cmcl_anti": 0.34}))
    verdicts = {q.split("?")[0][-40:]: v for q, v, _ in rows}
    assert [v for _, v, _ in rows] == ["**not reproduced: CMCL learns later**",
                                       "**against PER-MADDPG not reproduced (behind); against ACL not shown**",
                                       "**held-out success worse; MA 0.9 later**", "**no: it hurts**",
                                       "**not shown**"], verdicts
    primary = rows[0][2]
    assert primary.startswith("−0.290 [") and "Welch p < 0.0001" in primary and "detects with 80% power is" in primary
    assert "not reached (0/6) against" in rows[2][2] and "Holm p" in rows[2][2]


def test_a_curriculum_ahead_is_judged_ahead_and_a_level_one_not_shown():
    ahead = verdict_rows(grid({"maddpg": 0.5, "per": 0.5, "acl": 0.5, "cmcl": 0.7, "cmcl_permuted": 0.5,
                               "cmcl_anti": 0.5}))
    assert [v for _, v, _ in ahead] == ["**reproduced: CMCL learns sooner**",
                                        "**against PER-MADDPG reproduced; against ACL reproduced**",
                                        "**held-out success better; MA 0.9 sooner**", "**yes: it helps**",
                                        "**yes: it helps**"]
    level = verdict_rows(grid({arm: 0.6 for arm in ARMS}))
    assert level[0][1] == "**not shown**" and level[3][1] == "**not shown**"
    assert level[2][1] == "**held-out success not shown; MA 0.9 not shown sooner or later**"


def test_mixed_code_withdraws_the_questions_that_rest_on_it_without_numbers():
    mixed = {"cmcl": ["a" * 40] * 3 + ["b" * 40] * 3}
    table = verdict_table(grid({"maddpg": 0.62, "per": 0.65, "acl": 0.32, "cmcl": 0.33, "cmcl_permuted": 0.66,
                                "cmcl_anti": 0.34}, mixed))
    assert "(code: mixed" in table
    rows = [line for line in table.splitlines() if line.startswith("| **") or line.startswith("| Does")
            or line.startswith("| The")]
    assert len(rows) == 5 and all("**withdrawn**: its runs ran mixed code versions |  |" in r for r in rows)
    assert "−0." not in table
    clean = verdict_table(grid({arm: 0.6 for arm in ARMS}))
    assert "(code: aaaaaaa)" in clean


def test_no_runs_no_table():
    assert verdict_table([]) == "no runs yet"


def setting_grid(means: dict[str, float], grid_name: str) -> list[dict]:
    """A settings grid's runs (6 seeds per arm) with the harder task's MADDPG and CMCL runs beside them."""
    runs = [r for r in grid({**{arm: 0.5 for arm in ARMS}, **means}) if r["arm"] in ("maddpg", "cmcl")]
    for arm in set(means) - {"maddpg", "cmcl"}:
        for seed, jitter in enumerate((-0.02, 0.0, 0.02, -0.01, 0.01, 0.0)):
            runs.append({"arm": arm, "grid": grid_name, "task": "spread", "seed": seed, "budget": 20_000,
                         "auc_coverage": means[arm] + jitter, "provenance": {"commit": "a" * 40, "dirty": False}})
    return runs


def test_a_settings_grid_gets_one_verdict_per_comparison_of_its_holm_family():
    stride = verdict_lines(setting_verdict_table(
        setting_grid({"maddpg": 0.62, "cmcl": 0.33, "cmcl_stride_x2": 0.34, "cmcl_stride_half": 0.22},
                     "curriculum_stride"), "curriculum_stride"))
    assert [line.split(" | ")[2] for line in stride] == ["**not shown**", "**yes: it holds CMCL back**",
                                                         "**no: still behind MADDPG**"]
    assert "at the family's α/3 = 0.017 is" in stride[1] and "| aaaaaaa |" in stride[0]
    eta = verdict_lines(setting_verdict_table(
        setting_grid({"maddpg": 0.40, "cmcl": 0.33, "cmcl_eta1": 0.45}, "curriculum_eta"), "curriculum_eta"))
    assert [line.split(" | ")[2] for line in eta] == ["**yes: it helps**", "**yes: ahead of MADDPG**"]
    assert setting_verdict_table(setting_grid({}, "curriculum_eta"), "curriculum_eta") == "no runs yet"


def verdict_lines(table: str) -> list[str]:
    return [line for line in table.splitlines() if line.startswith("| ") and "---" not in line][1:]
