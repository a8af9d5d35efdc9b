"""A sampling rule is one file: a rule written here, in ONE new file (a priority with an option of its own, recency's
half-life, and a learner score of its own, td²), registered with one line (`replay.rule_files`, which registers
the file at config load in every process of the run), trains on both schedulers (the inline runner in this
process, and the service on the session's embedded Ray), is refused in one line with a bad option value, and
appears in `python -m cmcl config`."""

from __future__ import annotations

import sys
import textwrap

import pytest

from cmcl.__main__ import main
from cmcl.config import ConfigError, load_config
from cmcl.replay.registry import REGISTRY
from cmcl.run.rundir import RunDirectory
from services.launch import run_service
from services.roles.replay_server import ReplayServer
from tests.in_process import train_tiny
from tests.tiny import tiny_overrides

RULE_FILE = textwrap.dedent('''
    """recency: p = 2^(−age/h)·(1 + td²) + ε_p, age in rows written since the row, h = teams.<team>.half_life; td²
    is this rule's own learner score, |y − Q|² of the rows the learner trained on."""

    from dataclasses import dataclass

    import numpy as np

    from cmcl.field_docs import documented
    from cmcl.replay.rules.contract import LearnerScore, Needs, Range, Rule
    from cmcl.replay.sampling import _ProportionalSampling


    @dataclass(frozen=True)
    class RecencyOptions:
        """recency's own keys in its team's table."""

        half_life: float = documented(300.0, "rows written after a row at which its priority halves", unit="rows",
                                      rule=Range("must be > 0", lambda v: v > 0))


    class RecencySampling(_ProportionalSampling):
        """State: when each slot was written (rows so far), and its last td² (0 until the learner scores it)."""

        name = "recency"

        def __init__(self, args, half_life):
            super().__init__(args)
            self.half_life, self.recomputes = float(half_life), True
            self.written_at, self.td_sq = np.zeros(args.capacity), np.zeros(args.capacity)
            self.clock = 0

        def initial_priority(self, slots):
            return 1.0

        def added(self, slots):
            self.clock += slots.size
            self.written_at[slots], self.td_sq[slots] = self.clock, 0.0
            super().added(slots)

        def feedback(self, storage, agent, slots, generations, scores):
            fresh = storage.fresh_mask(slots, generations)
            self.td_sq[slots[fresh]] = scores["td_sq"][fresh]
            return int(fresh.sum()), True

        def recompute(self, storage, lam):
            age = self.clock - self.written_at[:storage.size]
            return np.exp2(-age / self.half_life) * (1.0 + self.td_sq[:storage.size]) + self.eps

        def state_dict(self):
            return {**super().state_dict(), "written_at": self.written_at, "td_sq": self.td_sq, "clock": self.clock}

        def load_state_dict(self, state, size):
            super().load_state_dict(state, size)
            self.written_at, self.td_sq = np.asarray(state["written_at"]), np.asarray(state["td_sq"])
            self.clock = int(state["clock"])


    TD_SQ = LearnerScore("td_sq", lambda stats, minibatch: np.square(stats["td_abs"]))
    RULE = Rule("recency", "recency: p = 2^(−age/h)·(1 + td²)", lambda args, options: RecencySampling(
        args, options.half_life), "recency", needs=lambda team: Needs(learner_scores=("td_sq",)),
        learner_scores=(TD_SQ,), options=RecencyOptions)
''')


@pytest.fixture
def recency(tmp_path):
    """The rule's file, written here; the overrides that register it (one line) and select it. The rule leaves the
    registry of this process at the end (other tests read the registered rules)."""
    path = tmp_path / "recency.py"
    path.write_text(RULE_FILE)
    yield [f"replay.rule_files={str(path)!r}", "teams.agent.algorithm='recency'", "teams.agent.half_life=150.0"]
    REGISTRY.pop("recency", None)
    sys.modules.pop("cmcl_rule_file_recency", None)


def scored_rows(sampler) -> int:
    """Rows holding the rule's own learner score (td² > 0)."""
    return int((sampler.td_sq > 0).sum())


def test_the_rule_trains_inline_with_its_option_and_its_own_learner_score(recency, tmp_path):
    config = load_config(None, [*tiny_overrides(), *recency])
    assert config.teams["agent"].options.half_life == 150.0
    summary, roles = train_tiny(config, tmp_path / "inline")
    assert summary["updates"] > 0
    samplers = roles.replay.replay.sampling
    assert [s.name for s in samplers] == ["recency"] * len(samplers) and samplers[0].half_life == 150.0
    assert all(scored_rows(s) > 0 for s in samplers)  # td² reached every agent's sampler
    p = samplers[0].priorities[:roles.replay.replay.size]
    assert p.min() < p.max()  # recomputed from age and td², not left at the initial 1.0


def test_the_rule_trains_on_the_service(recency, tmp_path, ray_cluster):
    config = load_config(None, [*tiny_overrides(service=True), *recency, "run.episodes=24",
                                f"run.dir={str(tmp_path / 'service')!r}"])
    run_dir = RunDirectory.create(config.run.dir, config)
    summary = run_service(config, run_dir, progress=None)
    brief = {k: v for k, v in summary.items() if k != "metrics_text"}
    assert summary["updates"] > 0, brief
    # the replay server's last snapshot, loaded by the same role: its samplers hold the learner's td²
    server = ReplayServer(config.to_dict(), str(run_dir.service_paths()["replay"]), config.run.seed)
    assert server.replay.size > 0 and all(scored_rows(s) > 0 for s in server.replay.sampling)


def test_a_bad_option_is_refused_in_one_line_naming_it(recency):
    with pytest.raises(ConfigError) as refused:
        load_config(None, [*recency[:2], "teams.agent.half_life=-3.0"])
    assert str(refused.value) == "teams.agent.half_life must be > 0, got -3.0"
    with pytest.raises(ConfigError, match=r"unknown key teams\.agent\.half_life"):  # another rule has no such key
        load_config(None, [recency[0], "teams.agent.algorithm='per'", "teams.agent.half_life=10.0"])


def test_the_rule_and_its_option_appear_in_the_config_reference(recency, capsys):
    load_config(None, recency)  # registers the file
    assert main(["config", "teams.agent.half_life"]) == 0
    out = capsys.readouterr().out
    assert "half_life = 150.0" not in out and "half_life = 300.0" in out  # the rule's default
    assert "(algorithm = 'recency' only)" in out and "must be > 0" in out
    assert main(["config", "teams.agent.algorithm"]) == 0
    assert "'recency'" in capsys.readouterr().out


def test_a_rule_file_that_is_missing_or_takes_a_packaged_rules_name_is_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"replay\.rule_files: '.*nowhere\.py' is not a file"):
        load_config(None, [f"replay.rule_files={str(tmp_path / 'nowhere.py')!r}"])
    shadow = tmp_path / "shadow.py"
    shadow.write_text(RULE_FILE.replace('Rule("recency"', 'Rule("per"'))
    with pytest.raises(ConfigError, match=r"names its rule 'per', a rule of cmcl/replay/rules/"):
        load_config(None, [f"replay.rule_files={str(shadow)!r}"])
    assert REGISTRY["per"].sampling == "per"  # the packaged rule is still the one registered
    sys.modules.pop("cmcl_rule_file_shadow", None)
