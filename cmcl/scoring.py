"""One step of each CMCL part on a replay buffer: teacher fit, ICM fit, (re)scoring, learner update.

Where it sits: the steps of Algorithm 1 (ALGORITHM.md §3.8) as functions over the pure classes, shared by
`cmcl.loop` (which calls them in the synchronous order) and the service shells (which call them
asynchronously on their own actors). Data flow: scorers read buffer rows and write scores back keyed by
(slot, generation); the learner reads prioritized minibatches and, for PER, writes |δ| back.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from cmcl.learners.icm import ICM
from cmcl.learners.maddpg import MADDPG
from cmcl.learners.nets import joint_input
from cmcl.learners.teachers import TeacherEnsemble, cross_validated_difficulty, fold_batch_indices, make_fit_batch
from cmcl.replay.buffer import ReplayBuffer
from cmcl.system import AgentLayout

RESCORE_CHUNK = 2048  # rows per scoring pass (bounds memory of the A×K teacher forward)


@dataclass
class Scorers:
    """The models that produce replay scores; any of them may be None when no team needs it."""

    maddpg: MADDPG
    teachers: TeacherEnsemble | None
    icm: ICM | None
    difficulty_error: str = "squared"  # "squared" (eq. 10) or "abs" (§4.1 text)


def teacher_fit_step(replay: ReplayBuffer, scorers: Scorers, layout: AgentLayout, batch_size: int,
                     rng: np.random.Generator, shared: bool = True) -> np.ndarray | None:
    """One Adam step of every teacher on a batch drawn uniformly from its own fold (§3.2).

    shared: one batch per fold for all agents' teachers of that fold (one TD-target pass, as in the service);
    False: every (agent, fold) teacher draws its own batch (A times the target cost).

    Returns the pre-step loss float32[A_t, K], or None when there are no teachers or some fold is empty.
    """
    teachers = scorers.teachers
    if teachers is None:
        return None
    slots = replay.valid_slots()
    folds = replay.storage.fold[slots]
    if np.bincount(folds, minlength=teachers.num_folds).min() == 0:
        return None
    batches = 1 if shared else len(layout.teacher_agents)  # shared: one batch per fold serves every agent
    idx = fold_batch_indices(folds, teachers.num_folds, batch_size, rng, num_agents=batches)
    rows = replay.get(slots[idx.reshape(-1)])  # only the drawn rows: obs [A*K*S_T, N, od] ...
    local = np.arange(idx.size, dtype=np.int64).reshape(idx.shape)  # [A, K, S_T] into `rows`
    x, y = make_fit_batch(local, rows, layout.teacher_agents, scorers.maddpg.td_targets)
    return teachers.fit_step(x, y)


def icm_fit_step(replay: ReplayBuffer, scorers: Scorers, layout: AgentLayout, batch_size: int,
                 rng: np.random.Generator) -> dict[str, np.ndarray] | None:
    """One ICM step on S transitions drawn uniformly from the buffer (§3.4); None without an ICM."""
    if scorers.icm is None:
        return None
    slots = rng.integers(0, replay.size, batch_size)
    rows = replay.get(replay.valid_slots()[slots])
    a = layout.icm_agents
    obs, act, nxt = (np.ascontiguousarray(rows[k][:, a].swapaxes(0, 1)) for k in ("obs", "act", "next_obs"))
    out = scorers.icm.train_step(obs, act, nxt)  # [A_c, S, ·] inputs
    return {k: np.asarray(v) for k, v in out.items()}


def score_rows(rows: dict[str, np.ndarray], scorers: Scorers, layout: AgentLayout) -> dict[str, np.ndarray]:
    """Scores of joint rows (obs [M, N, od], act, rew [M, N], next_obs, fold [M]).

    Returns any of: "difficulty" float32[M, A_t] (c, sum over the K-1 teachers blind to the row),
    "curiosity" float32[M, A_c] (ρ, eq. 18), "td_abs" float32[M, N] (the online critics' |δ|, for ACL td_self).
    """
    out: dict[str, np.ndarray] = {}
    if scorers.teachers is not None:
        y = scorers.maddpg.td_targets(rows["rew"], rows["next_obs"], rows.get("done"), agents=layout.teacher_agents)
        x = joint_input(torch.as_tensor(rows["obs"]), torch.as_tensor(rows["act"]))  # [M, in]
        e = scorers.teachers.errors(x, y, squared=scorers.difficulty_error == "squared")  # [A_t, M, K]
        out["difficulty"] = cross_validated_difficulty(e, rows["fold"]).T.copy()
    if scorers.icm is not None:
        a = layout.icm_agents
        obs, act, nxt = (np.ascontiguousarray(rows[k][:, a].swapaxes(0, 1)) for k in ("obs", "act", "next_obs"))
        out["curiosity"] = scorers.icm.curiosity(obs, act, nxt).T.copy()
    if "td_abs" in layout.difficulty_source:
        out["td_abs"] = online_td_abs(scorers.maddpg, rows)
    return out


@torch.no_grad()
def online_td_abs(maddpg: MADDPG, rows: dict[str, np.ndarray]) -> np.ndarray:
    """|y − Q_v(s, a)| of every agent's online critic on joint rows -> float32[M, N]."""
    y = torch.as_tensor(maddpg.td_targets(rows["rew"], rows["next_obs"], rows.get("done")))  # [N, M]
    x = joint_input(torch.as_tensor(rows["obs"]), torch.as_tensor(rows["act"]))  # [M, in]
    q = maddpg.critic(x.unsqueeze(0).expand(maddpg.num_agents, -1, -1)).squeeze(-1)  # [N, M]
    return (y - q).abs().T.numpy().copy()


def write_scores(replay: ReplayBuffer, slots: np.ndarray, generations: np.ndarray,
                 scores: dict[str, np.ndarray], layout: AgentLayout) -> int:
    """Store score columns for (slot, generation) pairs; stale pairs are dropped. Returns rows accepted."""
    accepted = 0
    agents = {"difficulty": layout.teacher_agents, "curiosity": layout.icm_agents,
              "td_abs": np.arange(layout.num_agents)}
    for column, values in scores.items():
        accepted += replay.update_scores(column, slots, generations, values, agents=agents[column])
    return accepted


def rescore(replay: ReplayBuffer, scorers: Scorers, layout: AgentLayout, slots: np.ndarray | None = None,
            chunk: int = RESCORE_CHUNK) -> int:
    """Recompute every needed score of `slots` (default: the whole buffer) in chunks; returns rows accepted."""
    if scorers.teachers is None and scorers.icm is None and "td_abs" not in layout.difficulty_source:
        return 0
    slots = replay.valid_slots() if slots is None else np.asarray(slots, dtype=np.int64)
    accepted = 0
    for start in range(0, slots.size, chunk):
        part = slots[start:start + chunk]
        rows = replay.get(part)
        accepted += write_scores(replay, part, replay.generations(part), score_rows(rows, scorers, layout), layout)
    return accepted


def needs_scores(layout: AgentLayout) -> bool:
    """Whether any agent's priority needs score columns (teacher difficulty, curiosity or online |δ|)."""
    return bool(layout.teacher_agents.size or layout.icm_agents.size or "td_abs" in layout.difficulty_source)


def unscored_slots(replay: ReplayBuffer, layout: AgentLayout) -> np.ndarray:
    """int64[·] valid slots that lack a score some agent needs (new rows since the last scoring pass)."""
    size, scored = replay.size, replay.storage.scored
    missing = np.zeros(size, bool)
    td_agents = [a for a, src in enumerate(layout.difficulty_source) if src == "td_abs"]
    for column, agents in (("difficulty", layout.teacher_agents), ("curiosity", layout.icm_agents),
                           ("td_abs", td_agents)):
        if len(agents):
            missing |= ~scored[column][:size][:, agents].all(1)
    return replay.valid_slots()[missing]


def rolling_rescore(replay: ReplayBuffer, scorers: Scorers, layout: AgentLayout, cursor: int, rows: int
                    ) -> tuple[int, int]:
    """The scoring of one learner update, amortised: every never-scored row (A11: new rows are scored before they
    can be sampled), then up to `rows` more from a cursor that walks the buffer in slot order and wraps, so the
    whole buffer is rescored every capacity / rows updates (§3.8's periodic rescoring, spread over updates).

    Returns (rows accepted, the new cursor).
    """
    if not needs_scores(layout) or replay.size == 0:
        return 0, cursor
    new = unscored_slots(replay, layout)
    take = min(max(0, rows - new.size), replay.size)
    walk = (cursor + np.arange(take)) % replay.size
    slots = np.union1d(new, walk).astype(np.int64)
    return rescore(replay, scorers, layout, slots), int((cursor + take) % replay.size)


def owner_batch(replay: ReplayBuffer, slots: np.ndarray) -> dict[str, np.ndarray]:
    """Per-owner minibatch: slots int64[N, S] -> obs [N, S, N, od], act, rew [N, S, N], next_obs, done [N, S]."""
    n, s = slots.shape
    rows = replay.get(slots.reshape(-1))
    return {k: rows[k].reshape(n, s, *rows[k].shape[1:]) for k in ("obs", "act", "rew", "next_obs", "done")}


def learner_step(replay: ReplayBuffer, scorers: Scorers, layout: AgentLayout, batch_size: int,
                 rngs: Sequence[np.random.Generator], beta: float, intrinsic_reward_coef: float = 0.0
                 ) -> dict[str, np.ndarray]:
    """Sample one minibatch per agent, update all agents in one batched step, write PER |δ| back.

    beta: IS exponent for agents whose team corrects with importance weights (others use weights of 1).
    Returns the MADDPG update stats (critic_loss [N], actor_loss [N], td_abs [N, S], ...) plus "slots" [N, S].
    """
    betas = [beta if isw else 0.0 for isw in layout.importance_weights]
    slots, weights = replay.sample_all(batch_size, list(rngs), beta=betas)
    batch = owner_batch(replay, slots)
    generations = replay.generations(slots.reshape(-1)).reshape(slots.shape)
    if intrinsic_reward_coef > 0 and scorers.icm is not None:
        add_intrinsic_reward(batch, scorers.icm, layout, intrinsic_reward_coef)
    if any(layout.importance_weights):
        batch["is_weights"] = weights
    stats = scorers.maddpg.update(batch)
    for agent, mode in enumerate(layout.modes):
        if mode == "per":
            replay.update_priorities(agent, slots[agent], stats["td_abs"][agent], generations[agent])
        elif layout.difficulty_source[agent] == "td_abs":
            replay.update_scores("td_abs", slots[agent], generations[agent], stats["td_abs"][agent][:, None],
                                 agents=[agent])
    stats["slots"] = slots
    return stats


def add_intrinsic_reward(batch: dict[str, np.ndarray], icm: ICM, layout: AgentLayout, coef: float) -> None:
    """Ablation A6: r_v += coef·ρ_v on each curiosity agent's own minibatch (in place on a copy of rew)."""
    a = layout.icm_agents
    # batch[k][a, :, a] -> [A_c, S, ·]: owner a's rows, agent a's own columns
    rho = icm.curiosity(batch["obs"][a, :, a], batch["act"][a, :, a], batch["next_obs"][a, :, a])  # [A_c, S]
    batch["rew"] = batch["rew"].copy()
    batch["rew"][a, :, a] += coef * rho
