"""The sparse screen's choice and the confirmation's arms derived from it (docs/SPARSE_TASKS.md, its screen and
confirmation protocols): the choice and its tie-breaks, "no candidate", the curriculum control's fixed window, the
intrinsic control's scale from the frozen-ICM reference runs, and the grids built from them.

Every summary here is synthetic (written by the helpers below, named synthetic_*): they stand for finished runs'
summaries, never for a component of the code."""

import pytest

from cmcl.config import load_config
from experiments import grids
from experiments.__main__ import main
from experiments.sparse_arms import (
    SPARSE_CONFIRM_SEEDS,
    SPARSE_SCREEN,
    SPARSE_SCREEN_SEEDS,
    SparseNotReady,
    confirm_arms,
    current_round,
    fixed_window,
    frozen_coef,
    sparse_choice,
)
from experiments.store import ResultsStore

BOX_SEEDS = current_round("push_box").seeds  # the seeds of push_box's current round of the screen


def synthetic_screen(held: dict, tenth: dict | None = None, spans=None, updates=20_000, intrinsic=0.05):
    """Synthetic screen summaries: per (task, candidate), held-out success held[task, candidate] (a number, or one per
    seed) and final_tenth_success tenth[...] (default 0) on every seed of the task's current round; a curriculum's
    task_stages from spans(i), i the seed's index (default: stage 0 for 320 episodes, then stage 1); an intrinsic
    candidate's first-tenth reward."""
    out = []
    for (task, candidate), value in held.items():
        for i, seed in enumerate(current_round(task).seeds):
            s = {"id": f"sparse_screen_{task}_{candidate}_s{seed}", "grid": "sparse_screen", "env": task,
                 "arm": candidate, "seed": seed, "updates": updates,
                 "held_out_success": value[i] if isinstance(value, tuple) else value,
                 "final_tenth_success": (tenth or {}).get((task, candidate), 0.0)}
            if SPARSE_SCREEN[candidate][0] == "intrinsic":
                s["intrinsic_reward_first_tenth"] = intrinsic
            else:
                s["task_stages"] = (spans or (lambda _: [{"stage": 0, "first_episode": 0, "episodes_at_stage": 320},
                                                         {"stage": 1, "first_episode": 330,
                                                          "episodes_at_stage": 900}]))(i)
            out.append(s)
    return out


def every_candidate(task, value=0.0):
    return {(task, c): value for c in current_round(task).candidates}


def test_the_choice_is_the_best_mean_held_out_success_with_its_tie_breaks():
    held = every_candidate("vacl_n4") | {("vacl_n4", "radius_progress"): (0.9, 0.6, 0.3),
                                         ("vacl_n4", "curriculum_half"): (0.5, 0.5, 0.5)}
    choice = sparse_choice(synthetic_screen(held), "vacl_n4")
    assert choice.candidate == "radius_progress" and choice.held_out["radius_progress"] == pytest.approx(0.6)
    assert list(choice.held_out) == list(current_round("vacl_n4").candidates)  # the current round's only
    tied = every_candidate("vacl_n4", 0.4)
    by_tenth = sparse_choice(synthetic_screen(tied, {("vacl_n4", "curriculum_half"): 0.7}), "vacl_n4")
    assert by_tenth.candidate == "curriculum_half"  # the tie broken by the last tenth's training success
    assert sparse_choice(synthetic_screen(tied), "vacl_n4").candidate == "radius_half"  # then the order
    first_round = [s | {"seed": seed} for s, seed in zip(synthetic_screen(tied), (0, 1, 2) * 3, strict=True)]
    with pytest.raises(SparseNotReady, match="misses 9 runs"):  # a stopped round's seeds are not the current round's
        sparse_choice(first_round, "vacl_n4")


def test_no_candidate_when_none_solved_a_held_out_episode_and_not_ready_while_a_run_is_missing():
    none = sparse_choice(synthetic_screen(every_candidate("push_box")), "push_box")
    assert none.candidate is None and list(none.held_out) == list(current_round("push_box").candidates)
    partial = synthetic_screen(every_candidate("push_box", 0.5))[:-1]
    with pytest.raises(SparseNotReady, match=r"^the sparse screen on push_box misses 1 runs: "
                                             rf"sparse_screen_push_box_intrinsic_strong_s{current_round('push_box').seeds[-1]}$"):
        sparse_choice(partial, "push_box")


def test_the_curriculum_controls_window_is_the_pooled_median_of_the_stages_left_in_multiples_of_the_worlds():
    def spans(i):  # the i-th seed left stage 0 after 100 + 100·i episodes, stage 1 after 500; the last never counts
        return [{"stage": 0, "first_episode": 0, "episodes_at_stage": 100 + 100 * i},
                {"stage": 1, "first_episode": 150, "episodes_at_stage": 500},
                {"stage": 2, "first_episode": 700, "episodes_at_stage": 99_999}][:2 + (i > 0)]
    screen = synthetic_screen({("vacl_n4", "radius_half"): 0.5}, spans=spans)
    # left: 100 (seed 0), 200 and 500 (seed 1), 300 and 500 (seed 2): median 300, a multiple of 16 worlds: 304
    assert fixed_window(screen, "vacl_n4", "radius_half") == 304
    never = synthetic_screen({("vacl_n4", "radius_half"): 0.5}, spans=lambda _: [{"stage": 0, "first_episode": 0,
                                                                                   "episodes_at_stage": 5000}])
    with pytest.raises(SparseNotReady, match="never left its first stage"):
        fixed_window(never, "vacl_n4", "radius_half")


def synthetic_scale(task, candidate, value=0.02, last=4_000):
    """Synthetic frozen-ICM reference summaries: coef·ρ = value at every progress row up to `last` updates."""
    return [{"id": f"sparse_scale_{task}_{candidate}_s{seed}", "grid": "sparse_scale", "env": task, "seed": seed,
             "intrinsic_curve": {"updates": list(range(500, last + 1, 500)),
                                 "intrinsic_reward": [value] * len(range(500, last + 1, 500))}}
            for seed in current_round(task).seeds]


def test_the_intrinsic_controls_coef_matches_the_candidates_reward_over_its_first_tenth_of_updates():
    screen = synthetic_screen({("push_box", "intrinsic"): 0.5}, updates=20_000, intrinsic=0.05)
    assert frozen_coef(screen, synthetic_scale("push_box", "intrinsic", 0.02), "push_box", "intrinsic") == 2.5
    with pytest.raises(SparseNotReady, match="stopped before 2000 updates"):
        frozen_coef(screen, synthetic_scale("push_box", "intrinsic", last=1_500), "push_box", "intrinsic")
    with pytest.raises(SparseNotReady, match=f"sparse_scale_push_box_intrinsic_s{BOX_SEEDS[0]} is missing"):
        frozen_coef(screen, [], "push_box", "intrinsic")


def test_the_arms_are_the_candidate_maddpg_and_its_control_and_each_loads():
    screen = synthetic_screen(every_candidate("vacl_n4") | {("vacl_n4", "curriculum_half"): 0.3}
                              | every_candidate("push_box") | {("push_box", "intrinsic_strong"): 0.2})
    scale = synthetic_scale("push_box", "intrinsic_strong", 0.04)
    vacl, box = confirm_arms(screen, scale, "vacl_n4"), confirm_arms(screen, scale, "push_box")
    assert list(vacl) == ["curriculum_half", "maddpg", "control"] and list(box) == ["intrinsic_strong", "maddpg",
                                                                                     "control"]
    control = load_config(grids.ROOT / "configs" / vacl["control"][0], list(vacl["control"][1]))
    assert control.task_curriculum.advance == "fixed" and control.task_curriculum.window == 320
    assert control.task_curriculum.level == 0.5 and control.task_curriculum.stages == load_config(
        grids.ROOT / "configs" / "vacl_n4_curriculum.toml").task_curriculum.stages
    frozen = load_config(grids.ROOT / "configs" / box["control"][0], list(box["control"][1]))
    assert frozen.icm.frozen and frozen.icm.intrinsic_reward_coef == pytest.approx(0.05 / 0.04)
    assert confirm_arms(synthetic_screen(every_candidate("push_box")), [], "push_box") == {}  # no candidate


def test_the_grids_run_the_scale_references_then_the_confirmation_and_refuse_in_one_line_before(tmp_path,
                                                                                                monkeypatch, capsys):
    for name in ("sparse_screen", "sparse_scale", "sparse_confirm"):
        monkeypatch.setitem(grids.GRIDS, name, tmp_path / name)
    assert main(["run", "sparse_confirm", "--seeds", "100"]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0  # one line naming what is missing
    for summary in synthetic_screen(every_candidate("vacl_n4") | {("vacl_n4", "radius_half"): 0.5}
                                    | every_candidate("push_box") | {("push_box", "intrinsic"): 0.1}):
        ResultsStore(tmp_path / "sparse_screen").write(summary)
    scale = grids.grid(["sparse_scale"], list(SPARSE_SCREEN_SEEDS))
    assert [r.id for r in scale] == [f"sparse_scale_push_box_intrinsic_s{s}" for s in current_round("push_box").seeds]
    assert all(r.max_seconds == 300 and "icm.frozen=true" in r.sets for r in scale)
    with pytest.raises(SparseNotReady, match=f"sparse_scale_push_box_intrinsic_s{BOX_SEEDS[0]} is missing"):
        grids.grid(["sparse_confirm"], list(SPARSE_CONFIRM_SEEDS))
    for summary in synthetic_scale("push_box", "intrinsic"):
        ResultsStore(tmp_path / "sparse_scale").write(summary)
    runs = grids.grid(["sparse_confirm"], list(SPARSE_CONFIRM_SEEDS))
    assert len(runs) == 10 * 6 and [r.seed for r in runs] == sorted(r.seed for r in runs)
    assert [r.id for r in runs[:6]] == [f"sparse_confirm_{t}_{a}_s100" for t, first in (("vacl_n4", "radius_half"),
                                                                                        ("push_box", "intrinsic"))
                                        for a in (first, "maddpg", "control")]
    assert all(r.max_seconds == 1800 for r in runs)
