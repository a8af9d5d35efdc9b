"""The sampling-rule registry and the rules beyond the paper's four: ReLo, the reducible held-out loss,
held-out learning progress, and the uniform floor every prioritised rule can take. Pure numpy, no Ray."""

import ast
from pathlib import Path

import numpy as np
import pytest

from cmcl.config import ConfigError, PriorityConfig, TeamConfig, load_config
from cmcl.replay.priority import EPS_P
from cmcl.replay.registry import ALGORITHMS, PAPER_ALGORITHMS, REGISTRY, build_sampler, spec_of
from cmcl.replay.rules.progress import STALENESS
from cmcl.replay.rules.reducible import rank01
from cmcl.replay.sampling import SamplerArgs
from tests.test_replay_storage import N, chunk, filled

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.filterwarnings("error")


def test_every_registered_rule_builds_and_is_a_config_value():
    assert PAPER_ALGORITHMS == ("maddpg", "per", "acl", "cmcl") and set(PAPER_ALGORITHMS) < set(ALGORITHMS)
    for name in ALGORITHMS:
        sampler = build_sampler(name, SamplerArgs(capacity=8, alpha=1.0, backend="cdf", eps=EPS_P))
        assert sampler.name == spec_of(name).sampling
        assert load_config(None, [f"teams.agent.algorithm={name}"]).teams["agent"].algorithm == name
    with pytest.raises(ConfigError, match="teams.agent.algorithm"):
        load_config(None, ["teams.agent.algorithm=ddpg"])
    with pytest.raises(ValueError, match=r"one of \['maddpg'"):
        spec_of("ddpg")


def test_a_team_reads_what_it_needs_from_the_registry():
    assert TeamConfig(algorithm="relo").needs.learner_scores == ("td_abs", "target_td_abs")
    assert TeamConfig(algorithm="relo").importance_weights and TeamConfig(algorithm="relo").effective_alpha() == 0.6
    assert TeamConfig(algorithm="rho").uses_teachers and not TeamConfig(algorithm="rho").uses_icm
    assert TeamConfig(algorithm="lp").uses_teachers and TeamConfig(algorithm="lp").effective_eta == 0.0
    assert TeamConfig(algorithm="acl", acl_variant="td_self").needs.difficulty_source == "td_abs"
    assert TeamConfig(algorithm="cmcl", eta=0.0).uses_icm is False
    with pytest.raises(ConfigError, match="uniform_floor"):
        TeamConfig(algorithm="per", priority=PriorityConfig(uniform_floor=1.0))


def _names_in(node: ast.AST, names: set[str]) -> bool:
    """Whether `node` is a rule's name as a string literal, or a set / tuple / list (or a set(...) / frozenset(...) /
    tuple(...) of one) holding one."""
    if isinstance(node, ast.Constant):
        return isinstance(node.value, str) and node.value in names
    if isinstance(node, ast.Set | ast.Tuple | ast.List):
        return any(_names_in(e, names) for e in node.elts)
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in ("set", "frozenset", "tuple",
                                                                                           "list"):
        return any(_names_in(a, names) for a in node.args)
    return False


def name_comparisons(source: str, names: set[str]) -> list[int]:
    """The lines of `source` that compare something with a rule's name: any comparison (==, !=, in, not in, is,
    <=, ...) one of whose sides is a name or a collection of names, and a `match` case on a name."""
    lines = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare) and any(_names_in(side, names) for side in (node.left, *node.comparators)):
            lines.append(node.lineno)
        elif isinstance(node, ast.MatchValue) and _names_in(node.value, names):
            lines.append(node.lineno)
    return sorted(lines)


def test_the_guard_catches_every_form_of_comparing_a_name():
    forms = ['a == "per"', '"cmcl" != a', 'a in ("maddpg", "per")', 'a not in ["acl"]', 'set(x) <= {"maddpg", "per"}',
             'a in frozenset({"laber"})', 'a is "relo"', 'match a:\n    case "lp":\n        pass']
    for form in forms:
        assert name_comparisons(form, set(ALGORITHMS)), form
    assert name_comparisons('a == "uniform" or state["maddpg"] or f("per")', set(ALGORITHMS)) == []


def test_no_algorithm_name_is_compared_outside_the_registry_and_the_rule_files():
    """What a rule does is read from its Rule (its capabilities): the core and the services never branch on a
    name, in any form of comparison (AST-based, `name_comparisons`). A rule's own file may name itself."""
    names = set(ALGORITHMS)
    offenders = [f"{path.relative_to(ROOT)}:{line}" for folder in ("cmcl", "services")
                 for path in sorted((ROOT / folder).rglob("*.py")) if path.name != "registry.py"
                 and not (path.parent.name == "rules" and path.stem in names)
                 for line in name_comparisons(path.read_text(), names)]
    assert offenders == []


def feed(rb, agent, slots, **scores):
    return rb.feedback(agent, slots, rb.generations(slots), scores)


def test_relo_priority_is_the_clipped_reducible_loss_and_new_rows_enter_at_the_maximum():
    rb = filled(capacity=60, episodes=2, algorithms="relo", alpha=0.6)
    slots = np.array([0, 1, 2])
    assert feed(rb, 0, slots, td_abs=[3.0, 1.0, 2.0], target_td_abs=[1.0, 2.0, 2.0]) == (3, False)
    p = rb.sampling[0].priorities[slots]
    assert p.tolist() == pytest.approx([9.0 - 1.0 + EPS_P, EPS_P, EPS_P])  # clipped at 0 where target ≥ online
    assert rb.sampling[0].max_priority == pytest.approx(8.0 + EPS_P)
    new = rb.add(*chunk(4, 9, np.random.default_rng(3)))
    assert rb.sampling[0].priorities[new].tolist() == pytest.approx([8.0 + EPS_P] * 4)


def test_reducible_held_out_loss_ranks_the_learner_loss_against_the_teachers_error():
    rb = filled(capacity=40, episodes=1, ep_len=40, algorithms="rho", alpha=1.0)
    s = rb.valid_slots()
    rb.update_scores("difficulty", s, rb.generations(s), np.tile(np.linspace(0, 1, 40)[:, None], (1, N)))
    assert rb.recomputes
    rb.recompute_priorities(0.5)
    assert np.allclose(rb.sampling_distribution()[:, 0], 1 / 40)  # no learner loss yet: every row alike
    learner = np.sqrt(np.linspace(0, 1, 40))  # δ² equal to the teachers' error on rows 0..19, larger after
    learner[20:] = np.sqrt(np.linspace(0, 1, 40)[20:] + np.arange(20) / 10)
    assert feed(rb, 0, s[:30], td_abs=learner[:30]) == (30, True)
    rb.recompute_priorities(0.5)
    p = rb.sampling[0].priorities[:40]
    stored = rb.storage.scores  # float32 columns, as the rule reads them
    reducible = stored["td_abs"][:30, 0].astype(float) ** 2 - stored["difficulty"][:30, 0].astype(float)
    assert np.allclose(p[:30], rank01(reducible) + EPS_P)
    assert p[29] == p[:30].max() and np.allclose(p[30:], np.mean(p[:30]))  # unscored: the mean weight (α = 1)


def test_learning_progress_follows_the_change_of_the_held_out_error_and_revisits_stale_rows():
    rb = filled(capacity=30, episodes=1, ep_len=30, algorithms="lp", alpha=1.0)
    s, gens = rb.valid_slots(), rb.generations(rb.valid_slots())
    rb.update_scores("difficulty", s, gens, np.ones((30, N)))
    rb.recompute_priorities(0.5)  # first sight of the errors: no progress yet
    change = np.zeros((30, N))
    change[:10] = np.linspace(0.1, 1.0, 10)[:, None]  # rows 0..9 change, by growing amounts
    rb.update_scores("difficulty", s, gens, 1.0 + change)
    rb.recompute_priorities(0.5)
    p = rb.sampling_distribution()[:, 0]
    assert np.all(np.diff(p[:10]) > 0) and p[9] == p.max()  # rank of |Δē|
    assert np.allclose(p.sum(), 1.0)
    sampler = rb.sampling[0]
    drawn, _ = rb.sample(0, 5, np.random.default_rng(0), beta=0.0)
    rb.recompute_priorities(0.5)  # the rows not drawn are staler than those drawn
    stale = (sampler.draws - sampler.last_drawn[:30]).astype(float)
    assert stale[drawn].max() == 0 and stale.max() == 1
    state = sampler.state_dict()
    again = filled(capacity=30, episodes=1, ep_len=30, algorithms="lp", alpha=1.0)
    again.sampling[0].load_state_dict(state, 30)
    assert again.sampling[0].draws == sampler.draws and np.array_equal(again.sampling[0].progress, sampler.progress)
    bad = {**state, "last_drawn": np.full(30, sampler.draws + 5)}
    with pytest.raises(ValueError, match="last_drawn"):
        again.sampling[0].load_state_dict(bad, 30)
    assert 0 < STALENESS < 1


@pytest.mark.parametrize("algorithm", ["per", "relo", "cmcl"])
def test_a_uniform_floor_mixes_in_one_over_the_buffer(algorithm):
    u, size = 0.25, 60
    rb = filled(capacity=size, episodes=2, algorithms=algorithm, floor=u)
    base = filled(capacity=size, episodes=2, algorithms=algorithm)
    for buf in (rb, base):
        if algorithm == "cmcl":
            buf.update_scores("difficulty", buf.valid_slots(), buf.generations(buf.valid_slots()),
                              np.random.default_rng(1).exponential(1.0, (size, N)))
            buf.recompute_priorities(0.2)
        else:
            feed(buf, 0, np.arange(10), td_abs=np.full(10, 50.0), target_td_abs=np.zeros(10))
    p, p0 = rb.sampling_distribution()[:, 0], base.sampling_distribution()[:, 0]
    assert np.allclose(p, (1 - u) * p0 + u / size) and np.isclose(p.sum(), 1.0)
    slots, w = rb.sample(0, 200_000, np.random.default_rng(2), beta=1.0)
    freq = np.bincount(slots, minlength=size) / slots.size
    assert np.abs(freq - p).max() < 0.005
    assert np.allclose(w, (size * p[slots]) ** -1.0 / ((size * p[slots]) ** -1.0).max(), rtol=1e-5)


def test_without_a_floor_the_draws_are_those_of_the_rule_alone():
    """u = 0 draws no extra random numbers: a run without a floor samples exactly as before the floor existed."""
    a, b = filled(capacity=60, episodes=2, algorithms="per"), filled(capacity=60, episodes=2, algorithms="per",
                                                                     floor=0.0)
    ra, rb_ = np.random.default_rng(5), np.random.default_rng(5)
    assert np.array_equal(a.sample(0, 64, ra, 0.4)[0], b.sample(0, 64, rb_, 0.4)[0])
    assert ra.random() == rb_.random()


@pytest.mark.parametrize("algorithm", ["relo", "rho"])
def test_the_permuted_control_of_a_rule_keeps_its_priorities_and_shuffles_their_rows(algorithm):
    rb = filled(capacity=60, episodes=2, algorithms=algorithm, difficulty_transform="permuted")
    s = rb.valid_slots()
    rb.update_scores("difficulty", s, rb.generations(s), np.random.default_rng(0).exponential(1.0, (60, N)))
    feed(rb, 0, s, td_abs=np.random.default_rng(1).exponential(1.0, 60), target_td_abs=np.zeros(60))
    before = rb.sampling[0].priorities[:60].copy()
    if algorithm == "rho":  # its column is rebuilt from the scores, then shuffled
        plain = filled(capacity=60, episodes=2, algorithms=algorithm)
        plain.update_scores("difficulty", s, plain.generations(s), np.random.default_rng(0).exponential(1.0, (60, N)))
        feed(plain, 0, s, td_abs=np.random.default_rng(1).exponential(1.0, 60), target_td_abs=np.zeros(60))
        plain.recompute_priorities(0.5)
        before = plain.sampling[0].priorities[:60].copy()
    rb.recompute_priorities(0.5)
    after = rb.sampling[0].priorities[:60]
    assert np.allclose(np.sort(after), np.sort(before)) and not np.allclose(after, before)


def test_registry_specs_are_complete():
    for name, spec in REGISTRY.items():
        assert spec.name == name and spec.summary and spec.default_alpha >= 0
        assert isinstance(spec.needs(TeamConfig(algorithm=name)).learner_scores, tuple)


def test_laber_picks_candidates_in_proportion_to_their_priority_with_mean_over_p_weights():
    from cmcl.replay.rules.laber import select_candidates

    p = np.array([[1.0, 2.0, 3.0, 4.0], [4.0, 4.0, 1.0, 1.0]])
    u = np.random.default_rng(0).random((2, 100_000))
    idx, w = select_candidates(p, u)
    freq = np.stack([np.bincount(row, minlength=4) for row in idx]) / u.shape[1]
    assert np.abs(freq - p / p.sum(1, keepdims=True)).max() < 0.01
    assert np.allclose(w, p.mean(1, keepdims=True) / np.take_along_axis(p, idx, 1))
    with pytest.raises(ValueError, match="candidate priorities"):
        select_candidates(np.zeros((1, 3)), u[:1, :2])


def test_laber_minibatch_is_picked_by_the_current_critic_and_other_agents_take_their_first_draws():
    import torch

    from cmcl.learners.maddpg import MADDPG
    from cmcl.learners.network_steps import choose_minibatch
    from cmcl.replay.messages import LearnerBatch
    from cmcl.replay.rules.laber import select_candidates

    torch.manual_seed(0)
    n, m, b, od, ad = 2, 4, 8, 3, 2
    rng = np.random.default_rng(1)
    s = m * b
    rows = {"obs": rng.normal(size=(1, n, s, n, od)).astype(np.float32),
            "act": rng.uniform(-1, 1, (1, n, s, n, ad)).astype(np.float32),
            "rew": rng.normal(size=(1, n, s, n)).astype(np.float32),
            "next_obs": rng.normal(size=(1, n, s, n, od)).astype(np.float32),
            "done": np.zeros((1, n, s, n), np.float32)}
    slots = np.arange(n * s).reshape(1, n, s)
    batch = LearnerBatch(rows, np.ones((1, n, s), np.float32), slots, slots + 1000, rng.random((1, n, b)))
    maddpg = MADDPG(n, od, ad, hidden=16, seed=0)
    picked, chosen, gens = choose_minibatch(maddpg, batch, 0, True, [True, False], select_candidates)
    td = maddpg.td_abs(batch.minibatch(0, True)).astype(np.float64) + EPS_P
    cdf = np.cumsum(td[0]) / td[0].sum()
    expected = np.minimum(np.searchsorted(cdf, batch.select_u[0, 0], side="right"), s - 1)
    assert np.array_equal(chosen[0], slots[0, 0, expected]) and np.array_equal(gens, chosen + 1000)
    assert np.array_equal(chosen[1], slots[0, 1, :b])  # the agent of another rule: its first B draws, weights kept
    assert picked["obs"].shape == (n, b, n, od) and np.all(picked["is_weights"][1] == 1.0)
    assert np.allclose(picked["is_weights"][0], td[0].mean() / td[0][expected], rtol=1e-5)
