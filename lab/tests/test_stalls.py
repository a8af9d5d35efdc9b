"""lab.report.stalls: the stall record of a real (tiny) inline run, and the per-arm table built from records."""

import json

import numpy as np
import pytest

from cmcl.run.rundir import RunDirectory
from experiments.labels import ARM_LABEL
from experiments.store import ResultsStore
from lab.report.stalls import MIN_PLATEAU, analyse_folder, analyse_run, load_stalls, stall_table
from tests.in_process import train_tiny
from tests.tiny import make_tiny_config

ONE_UPDATE_PER_STEP = {"maddpg": {"update_every": 1}}
# progress rows come every 2 s (and at the end): a tiny run's rows are its last; λ held below 0.5 for them
EARLY = {**ONE_UPDATE_PER_STEP, "curriculum": {"stride": 1e-6}}


# out of the default run (its 10-minute budget): trains a run; the record of an unfinished one stays in the default
# run
@pytest.mark.extended
def test_a_finished_run_gets_a_record_and_an_unfinished_one_none(tmp_path):
    folder = tmp_path / "grid"
    config = make_tiny_config("cmcl", service=True, sections=EARLY,
                              dir=str(folder / "runs" / "curriculum_cmcl_s0"), episodes=24)
    train_tiny(config, config.run.dir)
    ResultsStore(folder).write({"id": "curriculum_cmcl_s0", "arm": "cmcl"})
    record = analyse_run(folder / "runs" / "curriculum_cmcl_s0", "cmcl")
    coverage = [r["coverage"] for r in RunDirectory.open(config.run.dir).rows("episode")]
    assert record["arm"] == "cmcl" and record["seed"] == config.run.seed and len(coverage) == 24
    assert 0 <= record["plateau_episodes"] <= 24 < MIN_PLATEAU and record["at_plateau"] is None
    assert record["early"]["rows"] > 0 and 0 < record["early"]["ess"] <= 1  # λ starts at 0.1 < 0.5
    written = analyse_folder(folder, report=lambda line: None)
    assert [p.name for p in written] == ["curriculum_cmcl_s0.json"]
    assert analyse_folder(folder, report=lambda line: None) == []  # a record is written once
    stored = load_stalls(folder)[0]
    assert stored.pop("provenance")["versions"]["numpy"]  # every stall record names the code that wrote it
    assert stored == json.loads(json.dumps(record))
    unfinished = make_tiny_config("cmcl", service=True, sections=ONE_UPDATE_PER_STEP, dir=str(tmp_path / "unfinished"),
                                  episodes=24)
    train_tiny(unfinished, unfinished.run.dir)
    cfg = RunDirectory.open(unfinished.run.dir)
    (cfg.path / "metrics.jsonl").write_text("".join(line for i, line in enumerate(
        (cfg.path / "metrics.jsonl").read_text().splitlines(keepends=True)) if i < 5))
    assert analyse_run(cfg.path, "cmcl") is None


def test_the_table_has_one_row_per_arm_with_the_plateau_anatomy():
    anatomy = {"missed_by_class": {"crowded": 0.2, "short": 0.5, "far": 0.3}}
    state = {"idle_agent_reward_rows": [0.2, 0.3], "other_agents_reward_rows": [0.7, 0.8]}
    records = [{"arm": "maddpg", "plateau_episodes": p, "early": {"rows": 3, "ess": 1.0, "reward_rows_sampled": 0.2,
                                                                  "reward_rows_buffer": 0.2},
                "at_plateau": {"anatomy": anatomy, "idle_agent_share": 0.6, "idle_agent_wall_share": 0.1,
                               "curriculum": state} if p >= MIN_PLATEAU else None}
               for p in (500, 3000)]
    table = stall_table(records, ARM_LABEL).splitlines()
    assert len(table) == 3 and table[2].startswith("| MADDPG | 2 | 1,750 (500–3,000) | 1/2 | 1.00, 0.200 / 0.200")
    assert "0.60 / 0.10" in table[2] and "0.20 / 0.50 / 0.30" in table[2]
    assert "0.200 / 0.300 vs 0.700 / 0.800" in table[2]
    assert stall_table([], ARM_LABEL) == "no runs analysed yet"


def progress_row(episodes, lam, critic, actor, curriculum=None):
    row = {"kind": "progress", "episodes": episodes, "lambda": lam, "critic_loss": critic, "actor_loss": actor,
           "sampling": {"ess_fraction": [0.5, 0.5], "reward_rows_sampled": [0.0, 0.0],
                        "reward_rows_buffer": [0.1, 0.1]}}
    return {**row, "curriculum": curriculum} if curriculum else row


def test_the_early_learner_measures_average_the_rows_after_warm_up_while_lambda_is_below_half():
    from lab.report.stalls import WARM_UP, early_learner

    curriculum = {"difficulty_sampled": [0.2, 0.4], "difficulty_buffer": [0.5, 0.5]}
    rows = [progress_row(WARM_UP - 1, 0.1, [9.0, 9.0], [-90.0, -90.0], curriculum),  # before the warm-up: left out
            progress_row(WARM_UP, 0.2, [1.0, 3.0], [-10.0, -30.0], curriculum),
            progress_row(WARM_UP + 200, 0.4, [2.0, 2.0], [-40.0, -40.0], curriculum),
            progress_row(WARM_UP + 400, 0.5, [9.0, 9.0], [-90.0, -90.0], curriculum)]  # λ = 0.5: left out
    assert early_learner(rows) == pytest.approx({"critic_loss": 2.0, "q_sampled": 30.0, "difficulty_sampled": 0.3,
                                                 "difficulty_buffer": 0.5})
    uniform = early_learner([progress_row(WARM_UP, 0.2, [1.0, 1.0], [-5.0, -5.0])])  # MADDPG: no curriculum rows
    assert uniform["q_sampled"] == 5.0 and uniform["difficulty_sampled"] is None
    assert early_learner(rows[-1:]) == dict.fromkeys(("critic_loss", "q_sampled", "difficulty_sampled",
                                                      "difficulty_buffer"))


# out of the default run (its 10-minute budget): trains a run
@pytest.mark.extended
@pytest.mark.xfail(strict=True, raises=TypeError, reason="the learner measures (`early_learner`) read the inline "
                   "loop's progress rows' critic_loss / actor_loss / difficulty columns; the service's progress rows "
                   "(services/observability/progress_view.py, both runners now) carry none of them")
def test_a_record_written_before_the_learner_measures_gets_them_and_keeps_the_rest(tmp_path, monkeypatch):
    import lab.report.stalls as stalls

    monkeypatch.setattr(stalls, "WARM_UP", 0)  # the tiny run is shorter than the real warm-up
    folder = tmp_path / "grid"
    config = make_tiny_config("cmcl", service=True, sections=EARLY,
                              dir=str(folder / "runs" / "curriculum_cmcl_s0"), episodes=24)
    train_tiny(config, config.run.dir)
    ResultsStore(folder).write({"id": "curriculum_cmcl_s0", "arm": "cmcl"})
    [path] = analyse_folder(folder, report=lambda line: None)
    fresh = json.loads(path.read_text())
    assert fresh["early"]["critic_loss"] > 0 and fresh["early"]["difficulty_sampled"] is not None
    old = {**fresh, "early": {k: v for k, v in fresh["early"].items() if k not in stalls.LEARNER_KEYS},
           "plateau_episodes": 7}  # a marker: an old record's other fields are kept, not recomputed
    path.write_text(json.dumps(old))
    assert analyse_folder(folder, report=lambda line: None) == [path]
    assert json.loads(path.read_text()) == {**old, "early": fresh["early"]}
    assert analyse_folder(folder, report=lambda line: None) == []  # now complete: left alone


def test_the_early_learner_table_has_a_row_per_arm_and_skips_records_without_the_measures():
    from lab.report.stalls import early_learner_table

    def record(arm, critic, q, difficulty=None):
        early = {"rows": 3, "ess": 0.5, "reward_rows_sampled": 0.02, "reward_rows_buffer": 0.2, "critic_loss": critic,
                 "q_sampled": q, "difficulty_sampled": difficulty, "difficulty_buffer": 0.5 if difficulty else None}
        return {"arm": arm, "early": early}

    records = [record("maddpg", 2.0, 20.0), record("maddpg", 4.0, 30.0), record("cmcl", 0.2, 1.0, 0.25),
               {"arm": "acl", "early": {"rows": 3, "ess": 0.5, "reward_rows_sampled": 0.0, "reward_rows_buffer": 0.1}}]
    table = early_learner_table(records, ARM_LABEL).splitlines()
    assert len(table) == 4  # header, rule, MADDPG, CMCL; the old ACL record has no learner measures
    assert table[2].startswith("| MADDPG | 2 | 3.000 ± ") and "| 25.0 ± " in table[2] and "| — |" in table[2]
    assert table[3] == "| CMCL | 1 | 0.200 | 1.0 | 0.25 / 0.50 | 0.020 / 0.200 |"
    assert early_learner_table(records[3:], ARM_LABEL) == "no runs analysed yet"


def test_the_plateau_anatomy_reads_the_learners_checkpoints_of_the_service_format(tmp_path):
    """Both runners write the learner's verified generations (checkpoints/service/learner-*.pt): the anatomy's
    checkpoint is one of them, placed at the last episode acted with its weights or older ones."""
    from cmcl.run.evaluate import load_policy
    from lab.report.stalls import policy_checkpoints

    config = make_tiny_config("maddpg", service=True, sections=ONE_UPDATE_PER_STEP, dir=str(tmp_path / "run"))
    summary, roles = train_tiny(config, config.run.dir)
    checkpoints = policy_checkpoints(RunDirectory.open(config.run.dir))
    assert list(checkpoints) == [summary["episodes"]] and checkpoints[summary["episodes"]].path.parent.name == "service"
    obs = np.random.default_rng(0).normal(size=(2, config.env.spread.num_agents, roles.learner.maddpg.obs_dim))
    obs = obs.astype(np.float32)
    restored = load_policy(config, checkpoints[summary["episodes"]])
    np.testing.assert_array_equal(restored.act(obs, 0.0), roles.learner.maddpg.act(obs, 0.0))
