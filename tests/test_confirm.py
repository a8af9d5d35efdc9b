"""The rule confirmation: its arms derived from the screen's summaries by the screen's selection rule, its
refusal while the screen has no selection, the permuted control of each rule and the interim look after seeds 0-9
(its tables and goal verdicts: lab/tests/test_confirm_tables.py).

Every summary here is synthetic (written by the helpers below, named fake_* / synthetic_*): they stand for finished
runs' summaries, never for a component of the code."""

import numpy as np
import pytest

from cmcl.replay.registry import ALGORITHMS, spec_of
from experiments.__main__ import build_parser, main, selected_runs
from experiments.confirm_arms import (
    CONFIRM_SEEDS,
    INTERIM_SEEDS,
    ConfirmNotReady,
    confirm_arms,
    has_permuted_control,
    stopped_at_interim,
)
from experiments.grids import CURRICULUM_ARMS, grid, team_sets
from experiments.screen_arms import PERMUTED_CONTROL, SCREEN_ARMS
from experiments.store import ResultsStore
from tests.test_replay_storage import N, filled
from tests.test_screen_selection import screen_runs

CHOSEN = ("relo", "lp")  # what the fake screen selects: rho has the best area but does not act


def fake_screen(folder, drop: int = 0):
    """A results folder with the screen's 18 planned summaries, all but the last `drop` of them; rho does not act."""
    store = ResultsStore(folder)
    runs = screen_runs()
    for summary in runs[:len(runs) - drop]:
        store.write(summary)
    return folder


def synthetic_confirm(areas: dict[str, float], seeds=CONFIRM_SEEDS, commit="c" * 40, sd=0.02, seed=0):
    """Synthetic confirmation summaries: per arm, area under coverage ~ N(areas[arm], sd) over `seeds`."""
    rng = np.random.default_rng(seed)
    return [{"id": f"confirm_{arm}_s{s}", "grid": "confirm", "task": "spread", "arm": arm, "seed": s,
             "budget": 20_000, "auc_coverage": float(np.clip(base + rng.normal(0, sd), 0, 1)),
             "held_out_coverage": 0.95, "held_out_success": float(np.clip(0.8 + rng.normal(0, 0.05), 0, 1)),
             "episodes_to_90": None if s % 5 == 0 else 9_000 + 100 * s, "ess_first_quarter": 0.6,
             "sampling_curve": {"episode": [200, 5_000, 20_000], "reward_rows_sampled": [0.3, 0.3, 0.3],
                                "reward_rows_buffer": [0.2, 0.2, 0.2]},
             "provenance": {"commit": commit, "dirty": False, "segment_commits": [commit]}}
            for s in seeds for arm, base in areas.items()]


# relo meets the goal; lp gains too little; both well above their permuted controls
AREAS = {"relo": 0.80, "relo_permuted": 0.66, "lp": 0.70, "lp_permuted": 0.64, "maddpg": 0.65}


def test_the_confirm_grid_is_the_screens_selection_with_maddpg_and_each_rules_permuted_control(tmp_path):
    screen = fake_screen(tmp_path / "screen")
    arms = confirm_arms(CHOSEN)
    assert list(arms) == ["relo", "relo_permuted", "lp", "lp_permuted", "maddpg"]
    for rule in CHOSEN:
        assert arms[rule] == SCREEN_ARMS[rule] and arms[f"{rule}_permuted"] == [*SCREEN_ARMS[rule], PERMUTED_CONTROL]
    assert CURRICULUM_ARMS["cmcl_permuted"][1] == [PERMUTED_CONTROL]  # one key for every permuted control
    runs = grid(["confirm"], [0, 1], screen=screen)
    assert [r.id for r in runs[:5]] == [f"confirm_{arm}_s0" for arm in arms]  # seed outermost
    assert {r.config for r in runs} == {"spread_hard.toml"} and {r.grid for r in runs} == {"confirm"}
    assert [r.algorithm for r in runs[:5]] == ["relo", "relo", "lp", "lp", "maddpg"]
    assert runs[1].sets == tuple(team_sets([*SCREEN_ARMS["relo"], PERMUTED_CONTROL], "agent"))
    # before the interim look only its seeds run (the confirmation's folder has no runs)
    folder = ["--screen", str(screen), "--out", str(tmp_path / "confirm")]
    every = selected_runs(build_parser().parse_args(["run", "confirm", *folder]))
    assert sorted({r.seed for r in every}) == list(INTERIM_SEEDS) == list(range(10)) and len(every) == 10 * 5
    some = selected_runs(build_parser().parse_args(["run", "confirm", "--screen", str(screen), "--seeds", "3",
                                                    "--arms", "lp_permuted"]))
    assert [r.id for r in some] == ["confirm_lp_permuted_s3"]


def test_the_interim_look_stops_a_rule_not_above_maddpg_and_the_later_seeds_run_the_others(tmp_path):
    screen = fake_screen(tmp_path / "screen")
    store = ResultsStore(tmp_path / "confirm")
    interim = synthetic_confirm({**AREAS, "lp": 0.64}, seeds=INTERIM_SEEDS)  # lp below MADDPG's 0.65 by 0.01
    for summary in interim[:-1]:
        store.write(summary)
    assert stopped_at_interim(store.load(), CHOSEN) is None  # one interim run missing: no look yet
    args = ["run", "confirm", "--screen", str(screen), "--out", str(store.root)]
    assert {r.seed for r in selected_runs(build_parser().parse_args(args))} == set(INTERIM_SEEDS)
    store.write(interim[-1])
    assert stopped_at_interim(store.load(), CHOSEN) == ("lp",)
    later = [r for r in selected_runs(build_parser().parse_args(args)) if r.seed not in INTERIM_SEEDS]
    assert sorted({r.seed for r in later}) == list(CONFIRM_SEEDS[10:]) and len(later) == 10 * 3
    assert {r.arm for r in later} == {"relo", "relo_permuted", "maddpg"}
    # every rule stopped: the later seeds have no runs, and the verdicts need none
    for summary in synthetic_confirm({**AREAS, "relo": 0.60, "lp": 0.64}, seeds=INTERIM_SEEDS):
        store.write(summary)
    assert all(r.seed in INTERIM_SEEDS for r in selected_runs(build_parser().parse_args(args)))


def test_the_screen_runs_round_two_once_round_one_is_in_and_refuses_a_seed_of_neither(tmp_path, capsys):
    folder = tmp_path / "screen"
    args = build_parser().parse_args(["run", "screen", "--out", str(folder)])
    assert {r.seed for r in selected_runs(args)} == {100}  # round two waits for round one
    store = ResultsStore(folder)
    for summary in screen_runs()[:len(SCREEN_ARMS)]:
        store.write(summary)
    second = [r for r in selected_runs(args) if r.seed != 100]
    assert [r.id for r in second[:4]] == ["screen_maddpg_s101", "screen_relo_s101", "screen_lp_s101",
                                          "screen_laber_s101"] and len(second) == 8
    assert main(["run", "screen", "--seeds", "103", "--out", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--seeds: 103 is not a seed of the screen" in err


@pytest.mark.parametrize("drop", [18, 1])
def test_run_confirm_refuses_in_one_line_while_the_screen_is_incomplete(tmp_path, capsys, drop):
    screen = fake_screen(tmp_path / "screen", drop=drop)
    assert main(["run", "confirm", "--screen", str(screen), "--out", str(tmp_path / "confirm")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{drop} of 18 screen runs missing in {screen}" in err
    assert not (tmp_path / "confirm").exists()


def test_a_screen_without_a_selection_is_refused_with_its_reason(tmp_path):
    screen = fake_screen(tmp_path / "screen")
    store = ResultsStore(screen)
    for summary in store.load():
        store.write({**summary, "sampling_curve": {**summary["sampling_curve"], "reward_rows_sampled": [0.0] * 4}})
    with pytest.raises(ConfirmNotReady, match="0 of 10 screen runs missing .*No candidate acted"):  # no round two
        grid(["confirm"], [0], screen=screen)


def priorities_shuffled(algorithm: str) -> bool:
    """Whether, in a buffer of `algorithm`, the permuted control moves agent 0's sampling probabilities across rows
    (same multiset): scored as every rule needs (teachers' difficulty twice, for lp's progress; the learner's
    errors), then one recompute, as the runners do before each update."""
    out = []
    for transform in ("none", "permuted"):
        rb = filled(capacity=60, episodes=2, algorithms=algorithm, difficulty_transform=transform)
        s = rb.valid_slots()
        for draw in (0, 1):
            rb.update_scores("difficulty", s, rb.generations(s), np.random.default_rng(draw).exponential(1, (60, N)))
            rb.update_scores("curiosity", s, rb.generations(s), np.random.default_rng(7).exponential(1, (60, N)))
            rb.feedback(0, s, rb.generations(s), {"td_abs": np.random.default_rng(2).exponential(1, 60),
                                                  "target_td_abs": np.random.default_rng(3).exponential(0.5, 60)})
            if rb.recomputes:
                rb.recompute_priorities(0.3)
        out.append(rb.sampling_distribution()[:, 0])
    assert np.allclose(np.sort(out[0]), np.sort(out[1]))
    return not np.allclose(out[0], out[1])


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_the_permuted_control_shuffles_exactly_the_rules_said_to_have_one(algorithm):
    """Every rule whose priorities the buffer holds (teachers' or learner's: per, relo, rho, lp, acl, cmcl) is
    shuffled; LaBER, whose priorities are the learner's fresh |δ| of its candidates, has them shuffled across the
    candidates at each pick (tests/test_laber_permuted.py); uniform replay has nothing to shuffle. So a LaBER
    selection is confirmed with its permuted control like the others."""
    picks_among_candidates = spec_of(algorithm).pick is not None
    assert has_permuted_control(algorithm) == (priorities_shuffled(algorithm) or picks_among_candidates)
    assert has_permuted_control(algorithm) == (algorithm != "maddpg")
    if picks_among_candidates:
        assert confirm_arms(["laber"])["laber_permuted"] == [*SCREEN_ARMS["laber"], PERMUTED_CONTROL]
    with pytest.raises(ConfirmNotReady, match="does not act on the selected \\['maddpg'\\]"):
        confirm_arms(["maddpg"])
