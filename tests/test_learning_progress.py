"""cmcl.progress.learning: the windowed learning progress of the critic loss, the normalised TD error and the
coverage, the plateau rule run.stop_progress applies to the one run.progress_signal names, its checkpoint state (and
an old one's), the learner's normalised TD error, and the inline runner (the supervisor in one process) ending a run
by it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from cmcl.__main__ import main as cmcl
from cmcl.config import ConfigError
from cmcl.config.run_and_service import PROGRESS_SIGNALS
from cmcl.learners.maddpg import MADDPG
from cmcl.progress.learning import SIGNALS, LearningProgress, agent_mean
from cmcl.run.rundir import RunDirectory


def feed(progress: LearningProgress, window_means: list[float], per_window: int = 3) -> None:
    """`per_window` records of each mean, window after window (episodes advance by the window)."""
    for k, mean in enumerate(window_means):
        for _ in range(per_window):
            progress.record(k * progress.window, mean)
    progress.record(len(window_means) * progress.window, window_means[-1])  # opens the next: closes the last


def test_progress_is_the_relative_change_of_window_means_in_either_direction():
    lp = LearningProgress(threshold=0.1, window=10, patience=2, signal="critic_loss")
    feed(lp, [1.0, 2.0, 1.5])
    assert lp.means == [1.0, 2.0, 1.5]
    assert lp.progress == pytest.approx([1.0, 0.25])
    assert not lp.plateaued


def test_a_plateau_needs_patience_consecutive_windows_below_the_threshold():
    lp = LearningProgress(threshold=0.1, window=10, patience=2, signal="critic_loss")
    feed(lp, [1.0, 1.05, 2.0, 2.05])  # below, above (resets), below: one in a row
    assert lp.below == 1 and not lp.plateaued
    feed_more = LearningProgress(threshold=0.1, window=10, patience=2, signal="critic_loss")
    feed(feed_more, [1.0, 1.05, 2.0, 2.05, 2.1])
    assert feed_more.plateaued


def test_windows_without_updates_are_skipped_and_zero_threshold_never_plateaus():
    lp = LearningProgress(threshold=0.5, window=10, patience=1, signal="critic_loss")
    lp.record(35, 1.0)  # windows 0-2 had no update (warm-up)
    lp.record(45, 1.0)
    lp.record(55, 1.0)
    assert lp.means == [1.0, 1.0] and lp.plateaued
    off = LearningProgress(threshold=0.0, window=10, patience=1, signal="critic_loss")
    feed(off, [1.0, 1.0, 1.0])
    assert off.progress == [0.0, 0.0] and not off.plateaued


def test_state_round_trips_and_bad_settings_name_the_field():
    lp = LearningProgress(threshold=0.1, window=10, patience=2, signal="critic_loss")
    feed(lp, [1.0, 1.05])
    lp.record(25, 3.0)
    copy = LearningProgress(threshold=0.1, window=10, patience=2, signal="critic_loss")
    copy.load_state_dict(lp.state_dict())
    lp.record(31, 3.0)
    copy.record(31, 3.0)
    assert copy.state_dict() == lp.state_dict() and copy.progress == lp.progress
    with pytest.raises(ValueError, match="window must be an integer >= 1, got 0"):
        LearningProgress(window=0)
    with pytest.raises(ConfigError, match="run.stop_progress"):
        from tests.tiny import make_tiny_config
        make_tiny_config("maddpg", stop_progress=-1.0)


def feed_signal(progress: LearningProgress, signal: str, window_means: list[float], per_window: int = 4) -> None:
    """`per_window` values of each mean of `signal`, window after window, then the first record of the next window
    (which closes the last): updates for the critic signals (the critic loss doubling when it is not `signal`),
    episodes for the coverage."""
    w = progress.window
    for k, mean in enumerate([*window_means, None]):
        for i in range(per_window if mean is not None else 1):
            if signal == "coverage":
                progress.record_episode(k * w + i + 1, mean)
            else:
                values = {"critic_loss": 2.0 ** k, "normalised_td": math.nan,  # the other signal rises
                          signal: math.nan if mean is None else mean}
                progress.record(k * w + i, values["critic_loss"], values["normalised_td"])


def test_each_signal_has_its_own_learning_progress():
    """critic_loss and normalised_td: the relative change of their window means; coverage: the absolute change.
    Every signal is kept whichever the rule reads."""
    for signal, means, expected in (("critic_loss", [2.0, 3.0, 1.5], [0.5, 0.5]),
                                    ("normalised_td", [0.8, 0.4, 0.3], [0.5, 0.25]),
                                    ("coverage", [0.2, 0.5, 0.45], [0.3, 0.05])):
        lp = LearningProgress(threshold=0.1, window=10, patience=2, signal=signal)
        feed_signal(lp, signal, means)
        assert lp.means == pytest.approx(means) and lp.progress == pytest.approx(expected), signal
        assert lp.last == pytest.approx(expected[-1])
    both = LearningProgress(window=10)
    for k, (loss, normalised, coverage) in enumerate([(1.0, 0.5, 0.1), (4.0, 0.25, 0.4)]):
        both.record(k * 10 + 1, loss, normalised)
        both.record(k * 10 + 2, loss, math.nan)  # an update without a normalised TD error: not in its mean
        both.record_episode(k * 10 + 1, coverage)
        both.record_episode(k * 10 + 2, None)  # a task without coverage
    both.close()
    assert [w[key] for w in both.windows() for key in ("episodes", "critic_loss", "normalised_td", "coverage")] == \
        pytest.approx([10, 1.0, 0.5, 0.1, 20, 4.0, 0.25, 0.4])
    second = both.windows()[1]
    assert (second["critic_loss_lp"], second["normalised_td_lp"], second["coverage_lp"]) == pytest.approx(
        (3.0, 0.5, 0.3))
    assert both.windows()[0]["coverage_lp"] is None
    assert agent_mean([1.0, math.nan, 3.0]) == 2.0 and math.isnan(agent_mean([math.nan]))


@pytest.mark.parametrize("signal", SIGNALS)
def test_the_rule_fires_on_a_flat_series_of_its_signal_and_not_on_a_rising_one(signal):
    flat = [0.5, 0.5, 0.501, 0.499, 0.5]
    rising = [0.1, 0.2, 0.3, 0.4, 0.5]
    threshold = 0.01 if signal == "coverage" else 0.05
    fires = LearningProgress(threshold=threshold, window=10, patience=3, signal=signal)
    feed_signal(fires, signal, flat)
    assert fires.plateaued and fires.below == 4
    keeps = LearningProgress(threshold=threshold, window=10, patience=3, signal=signal)
    feed_signal(keeps, signal, rising)
    assert not keeps.plateaued and keeps.below == 0
    other = next(s for s in SIGNALS if s != signal)  # the rule reads its own signal only
    deaf = LearningProgress(threshold=threshold, window=10, patience=3, signal=other)
    feed_signal(deaf, signal, flat)
    assert not deaf.plateaued


def test_late_coverage_counts_in_the_open_window():
    """The service's episode reports may come after an update of the next window closed theirs."""
    lp = LearningProgress(window=10, signal="coverage")
    lp.record_episode(10, 0.2)
    lp.record(10, 1.0)  # window 1 opens: window 0 closes
    lp.record_episode(9, 0.6)  # late: in window 1
    lp.close()
    assert lp.means == pytest.approx([0.2, 0.6])


@pytest.mark.parametrize("signal", SIGNALS)
def test_the_state_of_every_signal_round_trips(signal):
    lp = LearningProgress(threshold=0.1, window=10, patience=2, signal=signal)
    for k in range(4):
        lp.record(k * 10, 1.0 + 0.01 * k, 0.5 + 0.2 * k)
        lp.record_episode(k * 10 + 1, 0.3 + 0.001 * k)
    lp.record(41, 2.0, 0.1)  # half of an open window
    copy = LearningProgress(threshold=0.1, window=10, patience=2, signal=signal)
    copy.load_state_dict(lp.state_dict())
    assert copy.state_dict() == lp.state_dict() and copy.windows() == lp.windows()
    for progress in (lp, copy):
        progress.record(50, 2.0, 0.1)
        progress.record_episode(51, 0.3)
    assert copy.state_dict() == lp.state_dict() and copy.plateaued == lp.plateaued


def test_an_old_state_without_the_new_signals_is_refused_and_another_signal_counts_its_own_windows():
    """A checkpoint from before the normalised TD error and the coverage were kept (the critic loss's record at the
    top level) is refused in one line; a state of another signal restores every series, and the rule then counts its
    own signal's trailing windows below the threshold."""
    from cmcl.replay.snapshot import LAST_READER, OlderRunError

    old = {"window_index": 5, "total": 3.0, "count": 2, "means": [1.0, 2.0, 2.05], "progress": [1.0, 0.025],
           "below": 1}
    with pytest.raises(OlderRunError) as err:
        LearningProgress(threshold=0.1, window=10, patience=2, signal="critic_loss").load_state_dict(old)
    assert str(err.value) == (f"learning progress state without the series {SIGNALS[0]!r}: written by an older "
                              f"version; commit {LAST_READER} is the last that reads it")
    lp = LearningProgress(threshold=0.1, window=10, patience=2, signal="critic_loss")
    for episodes, loss in ((10, 1.0), (20, 2.0), (30, 2.05), (40, 2.05)):
        lp.record(episodes, loss)
    other = LearningProgress(threshold=0.1, window=10, patience=2, signal="coverage")
    other.load_state_dict(lp.state_dict())
    assert other.series["critic_loss"].means == lp.series["critic_loss"].means and other.below == 0


def test_the_progress_signal_setting_is_checked_and_feeds_the_rule(tmp_path):
    """run.progress_signal: coverage by default (the rule off by default all the same), a bad value refused naming
    the key and the value, coverage refused where the episodes have none while the rule is on."""
    from tests.tiny import make_tiny_config
    assert SIGNALS == PROGRESS_SIGNALS
    default = make_tiny_config("maddpg").run
    assert (default.progress_signal, default.stop_progress) == ("coverage", 0.0)
    assert LearningProgress().signal == "coverage"
    with pytest.raises(ConfigError, match="run.progress_signal must be one of .*got 'td'"):
        make_tiny_config("maddpg", progress_signal="td")
    config = make_tiny_config("maddpg", progress_signal="normalised_td", stop_progress=0.1)
    lp = LearningProgress.from_run_config(config.run)
    assert (lp.signal, lp.threshold) == ("normalised_td", 0.1)
    with pytest.raises(ValueError, match="signal must be one of"):
        LearningProgress(signal="return")
    with pytest.raises(ConfigError, match="run.progress_signal needs episodes with a coverage .*'tag'"):
        make_tiny_config("maddpg", task="tag", stop_progress=0.02)
    make_tiny_config("maddpg", task="tag", stop_progress=0.02, progress_signal="normalised_td")
    make_tiny_config("maddpg", task="tag", progress_signal="coverage")  # the rule off: nothing to refuse


def test_the_learner_reports_the_share_of_its_targets_variance_it_does_not_explain():
    """critic_loss_normalised = mean (y − Q)² / Var(y) per owner over the same batch, unweighted (the critic loss
    stays IS-weighted); nan when the targets have no variance."""
    n, s, od, ad = 2, 32, 6, 2
    rng = np.random.default_rng(0)
    batch = {"obs": rng.normal(size=(n, s, n, od)).astype(np.float32),
             "act": rng.uniform(-1, 1, size=(n, s, n, ad)).astype(np.float32),
             "rew": rng.normal(size=(n, s, n)).astype(np.float32),
             "next_obs": rng.normal(size=(n, s, n, od)).astype(np.float32),
             "is_weights": rng.uniform(0.5, 1.0, size=(n, s)).astype(np.float32)}
    m = MADDPG(n, od, ad, hidden=16, seed=0)
    y = m.td_targets(batch["rew"], batch["next_obs"])
    td = m.td_abs(batch)
    out = m.update(batch)
    expected = (td ** 2).mean(1) / y.var(1)
    np.testing.assert_allclose(out["critic_loss_normalised"], expected, rtol=1e-4)
    np.testing.assert_allclose(out["critic_loss"], ((td ** 2) * batch["is_weights"]).mean(1), rtol=1e-4)
    constant = {**batch, "rew": np.zeros_like(batch["rew"])}
    flat = MADDPG(n, od, ad, hidden=16, seed=0)
    for p in flat.target_critic.parameters():
        torch.nn.init.zeros_(p)
    assert np.isnan(flat.update(constant)["critic_loss_normalised"]).all()  # y ≡ 0: no variance to explain


def test_the_inline_runner_ends_a_run_whose_learning_stopped_progressing(tmp_path, tiny_config_file):
    """Every window's change of each signal is below an enormous threshold: the run ends after patience + 1 windows
    of values of the signal run.progress_signal names, long before its 400-episode budget, and says so. (The learner's
    signals come once per learner call, service.updates_per_call updates: here a value every other 4-episode
    window.)"""
    run = tmp_path / "plateau"
    config = str(tiny_config_file("maddpg", dir=str(run), episodes=400))

    def main(argv):
        return cmcl(["train", "--runner", "inline", *argv])

    for signal in SIGNALS:
        assert main(["--config", config, "--no-eval", "--quiet", "--overwrite", "--set", "run.stop_progress=1e9",
                     "--set", "run.progress_window=4", "--set", "run.progress_patience=2",
                     "--set", f"run.progress_signal={signal!r}"]) == 0
        summary = RunDirectory.open(run).summary()
        assert summary["ended"] == "plateau" and summary["episodes"] < 100, (signal, summary["episodes"])
    untouched = tmp_path / "budget"  # the same run without the rule trains its budget
    assert main(["--config", config, "--no-eval", "--quiet", "--set", f"run.dir={untouched}",
                 "--set", "run.episodes=40", "--set", "run.progress_window=4"]) == 0
    assert RunDirectory.open(untouched).summary()["ended"] == "budget"
