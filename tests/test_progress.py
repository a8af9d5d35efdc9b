"""The early-stopping rule shared by the inline loop and the service."""

from types import SimpleNamespace

from cmcl.progress.rows import solved, window_mean

RUN = SimpleNamespace(stop_coverage=0.9, smoothing_window=4)


def rows(*coverage):
    return [{"coverage": c} for c in coverage]


def test_a_full_window_at_the_target_is_solved():
    assert solved(rows(0.75, 1.0, 1.0, 0.85), RUN)  # mean 0.9
    assert not solved(rows(0.75, 1.0, 1.0, 0.8), RUN)  # mean 0.8875


def test_a_window_that_is_not_full_yet_never_counts():
    assert not solved(rows(1.0, 1.0, 1.0), RUN)


def test_off_or_without_coverage_never_stops():
    assert not solved(rows(1.0, 1.0, 1.0, 1.0), SimpleNamespace(stop_coverage=0.0, smoothing_window=4))
    assert not solved([{"predator_win": 1.0}] * 4, RUN)
    assert window_mean([], "coverage") is None and window_mean(rows(0.5, 1.0), "coverage") == 0.75


def test_the_line_says_the_time_left_and_what_is_normal_while_lambda_is_low():
    from cmcl.progress.rows import progress_line, time_left
    from cmcl.replay.registry import early_notes

    assert time_left(1_000, 20_000, 50.0, 300.0) == "left ≤ 250s (budget)"  # the budget ends first
    assert time_left(10_000, 20_000, 100.0, 300.0) == "left ~100s"  # the episodes end first, at 100 episodes/s
    assert time_left(0, 20_000, 0.0) == "" and time_left(10, 20, 5.0) == "left ~5s"
    # the warm-up (no learner update yet): its cheap episodes' rate said "left ~0s"; only the budget tells then
    assert time_left(48, 400, 0.07, learning=False) == "" and time_left(48, 400, 0.07) == "left ~1s"
    assert time_left(48, 400, 0.07, 300.0, learning=False) == "left ≤ 300s (budget)"
    # a resumed run: the budget is this command's (segment_s), the episodes' rate the whole run's
    assert time_left(10_000, 20_000, 400.0, 300.0, segment_s=100.0) == "left ≤ 200s (budget)"
    assert time_left(10_000, 20_000, 100.0, 300.0, segment_s=10.0) == "left ~100s"
    notes = early_notes(["cmcl", "cmcl", "maddpg"])
    assert len(notes) == 1 and "λ < 0.5" in notes[0] and early_notes(["maddpg", "per", "relo"]) == []
    window = {"coverage": 0.3}  # a run with a coverage: the note's "cov may wait" stays
    early = progress_line(1_000, 20_000, 25_000, 100, window, 0.2, {}, 50.0, max_seconds=300.0, notes=notes)
    late = progress_line(1_000, 20_000, 25_000, 100, window, 0.6, {}, 50.0, max_seconds=300.0, notes=notes)
    assert early.endswith(f"50s | left ≤ 250s (budget) | {notes[0]}") and late.endswith("left ≤ 250s (budget)")


def test_the_line_shows_lambda_only_when_a_rule_of_the_run_reads_it():
    from cmcl.progress.rows import progress_line
    from cmcl.replay.registry import uses_lambda

    assert uses_lambda(["maddpg", "cmcl"]) and uses_lambda(["acl"])
    assert not uses_lambda(["maddpg", "per", "relo", "rho", "lp", "laber"])
    uniform = progress_line(1_000, 20_000, 25_000, 100, {}, None, {}, 50.0, notes=["never shown without λ"])
    curriculum = progress_line(1_000, 20_000, 25_000, 100, {}, 0.2, {}, 50.0)
    assert "λ" not in uniform and "never shown" not in uniform and "| λ 0.2000 |" in curriculum
