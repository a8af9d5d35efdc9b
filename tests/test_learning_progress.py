"""cmcl.learning_progress: the windowed relative change of the critic loss, the plateau rule run.stop_progress
applies, its checkpoint state, and the inline runner ending a run by it."""

from __future__ import annotations

import pytest

from cmcl.config import ConfigError
from cmcl.io.rundir import RunDirectory
from cmcl.learning_progress import LearningProgress
from cmcl.loop.__main__ import main


def feed(progress: LearningProgress, window_means: list[float], per_window: int = 3) -> None:
    """`per_window` records of each mean, window after window (episodes advance by the window)."""
    for k, mean in enumerate(window_means):
        for _ in range(per_window):
            progress.record(k * progress.window, mean)
    progress.record(len(window_means) * progress.window, window_means[-1])  # opens the next: closes the last


def test_progress_is_the_relative_change_of_window_means_in_either_direction():
    lp = LearningProgress(threshold=0.1, window=10, patience=2)
    feed(lp, [1.0, 2.0, 1.5])
    assert lp.means == [1.0, 2.0, 1.5]
    assert lp.progress == pytest.approx([1.0, 0.25])
    assert not lp.plateaued


def test_a_plateau_needs_patience_consecutive_windows_below_the_threshold():
    lp = LearningProgress(threshold=0.1, window=10, patience=2)
    feed(lp, [1.0, 1.05, 2.0, 2.05])  # below, above (resets), below: one in a row
    assert lp.below == 1 and not lp.plateaued
    feed_more = LearningProgress(threshold=0.1, window=10, patience=2)
    feed(feed_more, [1.0, 1.05, 2.0, 2.05, 2.1])
    assert feed_more.plateaued


def test_windows_without_updates_are_skipped_and_zero_threshold_never_plateaus():
    lp = LearningProgress(threshold=0.5, window=10, patience=1)
    lp.record(35, 1.0)  # windows 0-2 had no update (warm-up)
    lp.record(45, 1.0)
    lp.record(55, 1.0)
    assert lp.means == [1.0, 1.0] and lp.plateaued
    off = LearningProgress(threshold=0.0, window=10, patience=1)
    feed(off, [1.0, 1.0, 1.0])
    assert off.progress == [0.0, 0.0] and not off.plateaued


def test_state_round_trips_and_bad_settings_name_the_field():
    lp = LearningProgress(threshold=0.1, window=10, patience=2)
    feed(lp, [1.0, 1.05])
    lp.record(25, 3.0)
    copy = LearningProgress(threshold=0.1, window=10, patience=2)
    copy.load_state_dict(lp.state_dict())
    lp.record(31, 3.0)
    copy.record(31, 3.0)
    assert copy.state_dict() == lp.state_dict() and copy.progress == lp.progress
    with pytest.raises(ValueError, match="window must be an integer >= 1, got 0"):
        LearningProgress(window=0)
    with pytest.raises(ConfigError, match="run.stop_progress"):
        from tests.tiny import make_tiny_config
        make_tiny_config("maddpg", stop_progress=-1.0)


def test_the_inline_runner_ends_a_run_whose_learning_stopped_progressing(tmp_path, tiny_config_file):
    """Every window's change is below an enormous threshold: the run ends after patience + 1 windows of updates,
    long before its budget, and says so."""
    run = tmp_path / "plateau"
    config = str(tiny_config_file("maddpg", dir=str(run), episodes=400))
    assert main(["--config", config, "--no-eval", "--quiet", "--set", "run.stop_progress=1e9",
                 "--set", "run.progress_window=4", "--set", "run.progress_patience=2"]) == 0
    summary = RunDirectory.open(run).summary()
    assert summary["ended"] == "plateau" and summary["episodes"] < 40, summary
    untouched = tmp_path / "budget"  # the same run without the rule trains its budget
    assert main(["--config", config, "--no-eval", "--quiet", "--set", f"run.dir={untouched}",
                 "--set", "run.episodes=40", "--set", "run.progress_window=4"]) == 0
    assert RunDirectory.open(untouched).summary()["ended"] == "budget"
