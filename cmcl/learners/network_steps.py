"""The learner side of each step of Algorithm 1 (ALGORITHM.md §3.8): what the networks do with rows from the replay.

Where it sits: one implementation, two schedulers. The service's learner, teacher and ICM roles call these on
their models, in one process (`--runner inline`) or as Ray actors (`services/roles/learner.py`, `teachers.py`,
`icm.py`). The replay side (what is drawn, what is written back) is `cmcl.replay.buffer_steps`.

  learner minibatch .. choose_minibatch    the batch's own, or a rule's learner-side pick among m·B candidates by
                                           fresh |δ| (LaBER's; shuffled across them under the permuted control);
                                           with the actors' own uniform rows when actor_batch = "uniform"
  learner update ..... learner_update      minibatch [N, S, ...] -> MADDPG step (eqs. 4–6), |δ| [N, S]
  rules' scores ...... rule_scores         the rules' own per-row learner scores of the update [N, S] each
  teacher fit ........ fit_teachers        rows [steps, B, F, S, ...] -> Adam steps of the fold teachers (eq. 9)
  teacher scores ..... teacher_errors      rows [M, ...] -> e [M, A_t, K'] (eq. 10)
  ICM fit ............ fit_icm             rows [steps, S, ...] -> Adam steps of L_I, L_F (eqs. 13–17)
  curiosity scores ... curiosity_values    rows [M, ...] -> ρ [M, A_c] (eq. 18)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from cmcl.learners.maddpg import MADDPG
from cmcl.learners.nets import joint_input
from cmcl.replay.messages import ACTOR_PREFIX, CURIOSITY_KEY, LearnerBatch
from cmcl.replay.priority import EPS_P
from cmcl.replay.rules.contract import LearnerScore
from cmcl.scorers.icm import ICM
from cmcl.scorers.teachers import TeacherEnsemble


def agent_major(rows: dict[str, np.ndarray], agents: np.ndarray, key: str) -> np.ndarray:
    """Each agent's own columns of joint rows, agent axis first: rows[key] [..., N, d] -> [A, ..., d]."""
    return np.ascontiguousarray(np.moveaxis(rows[key][..., agents, :], -2, 0))


def learner_update(maddpg: MADDPG, minibatch: dict[str, np.ndarray], icm_agents: np.ndarray | None = None,
                   intrinsic_reward_coef: float = 0.0) -> dict[str, Any]:
    """One batched MADDPG update of every agent on its own minibatch (eqs. 4–6).

    minibatch: obs [N, S, N, od], act, rew [N, S, N], next_obs, done [N, S, N], optional is_weights [N, S] and
    curiosity [N, S, N] (the rows' stored ρ). With intrinsic_reward_coef > 0 (ablation A6's reverse): r_v += coef·ρ_v
    on each curiosity agent's (icm_agents) own rows; the caller passes coef(t), the weight at this update
    (cmcl.config.ICMConfig.intrinsic_coef: icm.intrinsic_reward_decay).
    Returns the MADDPG stats (critic_loss [N], actor_loss [N], td_abs [N, S], ...), with the intrinsic reward also
    "intrinsic_reward": the mean coef·ρ added to a curiosity agent's own reward, over their own rows (a float).
    """
    rho = minibatch.pop(CURIOSITY_KEY, None)
    if intrinsic_reward_coef > 0 and rho is not None:
        a = icm_agents
        minibatch = {**minibatch, "rew": minibatch["rew"].copy()}
        added = intrinsic_reward_coef * rho[a, :, a]  # owner a's rows, agent a's own columns [A_c, S]
        minibatch["rew"][a, :, a] += added
        return {**maddpg.update(minibatch), "intrinsic_reward": float(added.mean())}
    return maddpg.update(minibatch)


def rule_scores(scores: Sequence[LearnerScore], stats: dict[str, Any], minibatch: dict[str, np.ndarray]
                ) -> dict[str, np.ndarray]:
    """The rules' own learner scores of one update ({name: float32[N, S]}, each `LearnerScore.of(stats,
    minibatch)`; stats: `learner_update`'s, minibatch: the rows it trained on)."""
    return {score.name: np.asarray(score.of(stats, minibatch), dtype=np.float32) for score in scores}


def choose_minibatch(maddpg: MADDPG, batch: LearnerBatch, i: int, importance_weights: bool, select: Sequence[bool],
                     pick: Any = None) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:
    """The i-th minibatch of `batch` as `learner_update` takes it, with its slots and generations int64[N, B] (the
    critic's rows: the ones the feedback is about).

    Without candidates (`batch.select_u` None) it is the batch's own. With m·B candidates per owner, the agents
    marked in `select` pick B of them with their rule's learner-side `pick` (cmcl.replay.rules.contract.Rule.pick,
    `AgentLayout.pick`; LaBER's: ∝ the current critic's |δ| + ε after one no-grad pass, their critic weighted by
    LaBER-mean's weights, cmcl.replay.rules.laber.select_candidates); the others take
    their first B draws (i.i.d. from their own sampler) with their own IS weights. Under the permuted control
    (`batch.select_order`, drawn by the buffer for the control's agents, the identity for the others) an agent picks
    with its candidates' |δ| + ε read in that order: shuffled across its candidates. With the actors' own rows
    (`batch.actor`, actor_batch = "uniform"), the minibatch also holds "actor_obs", "actor_act" (and
    "actor_present") [N, B, N, ·]: the uniform rows for the owners marked in `batch.actor.owners`, the critic's
    chosen rows for the others (`with_actor_rows`)."""
    mb = batch.minibatch(i, importance_weights)
    slots, generations = batch.slots[i], batch.generations[i]
    if batch.select_u is None:
        return with_actor_rows(mb, batch, i), slots, generations
    u = batch.select_u[i]  # [N, B]
    n, b = u.shape
    order = None if batch.select_order is None else batch.select_order[i]  # [N, m·B]
    idx, weights = pick(maddpg.td_abs(mb).astype(np.float64) + EPS_P, u, order)
    picking = np.asarray(select, dtype=bool)
    idx[~picking] = np.arange(b)
    picked = {k: np.take_along_axis(v, idx.reshape(n, b, *([1] * (v.ndim - 2))), axis=1) for k, v in mb.items()}
    if "is_weights" in picked:
        picked["is_weights"] = np.where(picking[:, None], weights, picked["is_weights"]).astype(np.float32)
    return (with_actor_rows(picked, batch, i), np.take_along_axis(slots, idx, axis=1),
            np.take_along_axis(generations, idx, axis=1))


def with_actor_rows(minibatch: dict[str, np.ndarray], batch: LearnerBatch, i: int) -> dict[str, np.ndarray]:
    """The critic's minibatch [N, B, ...] plus the actors' own rows of the i-th minibatch of `batch` under the keys
    ACTOR_PREFIX + "obs", "act" (and "present"): `batch.actor`'s rows for the owners it marks, the critic's for the
    others; the minibatch unchanged when `batch.actor` is None."""
    if batch.actor is None:
        return minibatch
    owners = np.asarray(batch.actor.owners, dtype=bool)
    out = dict(minibatch)
    for key, rows in batch.actor.rows.items():
        own = rows[i]  # [N, B, ...]
        out[ACTOR_PREFIX + key] = own if owners.all() else np.where(
            owners.reshape(-1, *([1] * (own.ndim - 1))), own, minibatch[key])
    return out


def teacher_fit_batch(fit: dict[str, np.ndarray], agents: np.ndarray, targets: MADDPG
                      ) -> tuple[torch.Tensor, torch.Tensor]:
    """Teacher inputs and regression targets of fit rows [steps, B, F, S, N, ·] (B = 1: one batch per fold shared
    by the A_t agents; B = A_t: one per agent): x float32[A_t, steps, F, S, in] (the joint critic input) and
    y float32[A_t, steps, F, S], the learner's TD targets from the target nets of `targets` (eq. 10), computed for
    every step in one pass (the target nets are fixed meanwhile)."""
    steps, b, f, s = fit["obs"].shape[:4]
    a_t = len(agents)
    if b not in (1, a_t):
        raise ValueError(f"fit rows must be [steps, B, F, S, ...] with B = 1 or A_t = {a_t}, got B = {b}")
    major = {k: np.moveaxis(fit[k], 1, 0).reshape(b, steps * f * s, *fit[k].shape[4:]) for k in fit}  # [B, T, ...]
    if b == 1:
        major = {k: v[0] for k, v in major.items()}  # [T, ...], shared by every agent
    y = torch.as_tensor(targets.td_targets(major["rew"], major["next_obs"], major.get("done"), agents=agents))
    x = joint_input(torch.as_tensor(major["obs"]), torch.as_tensor(major["act"]))  # [(B,) T, in]
    return (x.reshape(b, steps, f, s, x.shape[-1]).expand(a_t, -1, -1, -1, -1), y.reshape(a_t, steps, f, s))


def fit_teachers(teachers: TeacherEnsemble, fit: dict[str, np.ndarray], agents: np.ndarray,
                 targets: MADDPG) -> float:
    """Adam steps of every teacher on batches of its own fold (eq. 9), one per leading index of the fit rows
    [steps, B, F, S, N, ·] (see `teacher_fit_batch`). Returns the last step's mean loss (NaN with no step)."""
    x, y = teacher_fit_batch(fit, agents, targets)
    loss = float("nan")
    for i in range(x.shape[1]):  # member (a, i) sees only the batch of its own fold
        loss = float(teachers.fit_step(x[:, i], y[:, i]).mean())
    return loss


def teacher_errors(teachers: TeacherEnsemble, rows: dict[str, np.ndarray], agents: np.ndarray, targets: MADDPG,
                   squared: bool | Sequence[bool] = True) -> np.ndarray:
    """e_{j,a,i} = (y_{a,j} − T_{a,i}(x_j))² (eq. 10; |·| if not squared) of every hosted teacher on joint rows
    obs [M, N, od], act, rew [M, N], next_obs, done [M, N] -> float32[M, A_t, K'] (K' teachers per agent hosted).
    squared: for all of them, or per teacher agent (`AgentLayout.teacher_error_squared`: its team's choice)."""
    y = targets.td_targets(rows["rew"], rows["next_obs"], rows.get("done"), agents=agents)  # [A_t, M]
    x = joint_input(torch.as_tensor(rows["obs"]), torch.as_tensor(rows["act"]))  # [M, in]
    return teachers.errors(x, y, squared=squared).transpose(1, 0, 2).copy()


def fit_icm(icm: ICM, fit: dict[str, np.ndarray], agents: np.ndarray) -> dict[str, np.ndarray | float]:
    """Adam steps of every curiosity agent's ICM on its own columns of uniform rows [steps, S, N, ·] (eq. 17);
    returns the last step's losses (inverse_loss [A_c], forward_loss [A_c], total)."""
    obs, act, nxt = (agent_major(fit, agents, k) for k in ("obs", "act", "next_obs"))  # [A_c, steps, S, ·]
    out: dict[str, np.ndarray | float] = {}
    for i in range(obs.shape[1]):
        out = icm.train_step(obs[:, i], act[:, i], nxt[:, i])
    return out


def curiosity_values(icm: ICM, rows: dict[str, np.ndarray], agents: np.ndarray) -> np.ndarray:
    """ρ_{j,v} = ½‖F_v(φ_v(o_{v,j}), a_{v,j}) − φ_v(o'_{v,j})‖² (eq. 18) of joint rows [M, N, ·] -> float32[M, A_c]."""
    return icm.curiosity(*(agent_major(rows, agents, k) for k in ("obs", "act", "next_obs"))).T.copy()


@torch.no_grad()
def online_td_abs(maddpg: MADDPG, rows: dict[str, np.ndarray]) -> np.ndarray:
    """|y − Q_v(s, a)| of every agent's online critic on joint rows -> float32[M, N] (ACL td_self scores)."""
    y = torch.as_tensor(maddpg.td_targets(rows["rew"], rows["next_obs"], rows.get("done")))  # [N, M]
    x = joint_input(torch.as_tensor(rows["obs"]), torch.as_tensor(rows["act"]))  # [M, in]
    q = maddpg.critic(x).squeeze(-1)  # shared rows [M, in] -> [N, M]
    return (y - q).abs().T.numpy().copy()
