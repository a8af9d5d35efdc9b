"""A landmark-assignment signal for the entity actor (`maddpg.assignment_loss`; off by default).

Where it sits: with `maddpg.assignment_loss` = β > 0, :class:`cmcl.learners.maddpg.MADDPG`'s actor step adds
β · CE_v to owner v's actor loss (eq. 4), CE_v the mean over v's rows of the cross-entropy of the entity actor's
attention logits over the landmark slots (`EntityActor.act_and_attend`, the same pass that gives the actions)
toward the landmark a minimum-total-distance assignment gives agent v:

  from agent v's own observation row (its entity slots hold every landmark's and every other agent's position
  relative to v, world units; cmcl.envs.entities.spread_layout), the one-to-one assignment of the present agents
  (v itself at the origin, and the others) to the present landmarks that minimises the sum of the Euclidean
  distances (`scipy.optimize.linear_sum_assignment`, one call per row: `assigned_landmark`); the target is the
  index, among the landmark slots, of the landmark it gives v.

At N = 8 the unfinished worlds are crowded (two agents on one landmark while another is free); in an optimal assignment
no two agents share a landmark, so the signal says which landmark is v's to take. Whether it helps learning is not
shown: its one run at N = 8 (lab/RESULTS.md, "Tried against the crowding") still crowded. The targets depend on the
observation only (no gradient); the loss's gradient reaches the actor's encoder only (not its head, not the critic).
With entity_pool = "attention" a landmark's logit is a function of v's own features and that landmark's alone (it cannot
see the other agents, so at best it learns a per-landmark score such as nearness); "relational" lets the landmark
embeddings see the other agents first. pool = "mean" has no attention and is refused. Rows carried from fewer agents
(run.carry_replay): the absent agents and their landmarks (the layout's presence rule) take no part, and a row whose
owner is absent adds nothing. Each update reports per owner `assignment_loss` (the mean CE, unweighted) and
`assignment_accuracy` (the share of rows whose largest landmark logit is the target; NaN for an owner with none).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from cmcl.envs.entities import EntityLayout

__all__ = ["STATS", "AssignmentTerm", "assigned_landmark", "assignment_targets"]

STATS = ("assignment_loss", "assignment_accuracy")  # what an update returns per owner, float32[N] each


def assigned_landmark(agents: np.ndarray, landmarks: np.ndarray, agent_present: np.ndarray | None = None,
                      landmark_present: np.ndarray | None = None) -> np.ndarray:
    """The landmark that the minimum-total-distance one-to-one assignment of a row's present agents to its present
    landmarks gives the row's agent 0.

    agents float[R, A, 2] and landmarks float[R, L, 2]: positions (world units, any common origin); agent_present
    bool[R, A], landmark_present bool[R, L] (None: all present) -> int64[R], the landmark's index in [0, L), or -1
    where agent 0 is absent or left without a landmark (more present agents than landmarks). Costs are Euclidean
    distances; ties go as scipy's solver breaks them. One solver call per row (a Python loop over R).
    """
    from scipy.optimize import linear_sum_assignment  # here: a learner without the term never loads it

    r, a, _ = agents.shape
    cost = np.hypot(agents[:, :, None, 0] - landmarks[:, None, :, 0],
                    agents[:, :, None, 1] - landmarks[:, None, :, 1])  # [R, A, L]
    agent_present = np.ones((r, a), bool) if agent_present is None else np.asarray(agent_present, bool)
    landmark_present = (np.ones(landmarks.shape[:2], bool) if landmark_present is None
                        else np.asarray(landmark_present, bool))
    full = (agent_present.all(1) & landmark_present.all(1)).tolist()
    some = (agent_present[:, 0] & landmark_present.any(1)).tolist()
    target = [-1] * r
    for row in range(r):  # the solver's rows come back sorted: agent 0 is assigned iff rows[0] == 0
        if full[row]:
            rows, cols = linear_sum_assignment(cost[row])
            target[row] = int(cols[0]) if rows[0] == 0 else -1
        elif some[row]:  # agent 0 is the first present agent of the sub-problem
            lm = np.flatnonzero(landmark_present[row])
            rows, cols = linear_sum_assignment(cost[row][np.flatnonzero(agent_present[row])][:, lm])
            target[row] = int(lm[cols[0]]) if rows[0] == 0 else -1
    return np.asarray(target, np.int64)


def assignment_targets(layout: EntityLayout, obs: np.ndarray, count: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Each agent's assigned landmark from its own observation: obs float32[B, N, obs_dim] (row b, agent i's own
    observation; agent axis second, as `layout.split` takes it), count int64[B, N] (the present agents of each row,
    the first ones; None: all N) -> (target int64[B, N], the index among the landmark slots or -1 where agent i is
    absent; landmark_present bool[B, N, L]). Positions are the entity slots' first two features (relative to agent
    i, which sits at the origin); the slots' kinds come from the layout's type one-hot ("landmark") and
    entity_agent (another agent)."""
    landmark_slots, agent_slots = landmark_and_agent_slots(layout)
    _, ents, mask = layout.split(obs)  # [B, N, E, F], [B, N, E]
    b, n = obs.shape[:2]
    own = np.ones((b, n), bool)
    if count is not None:
        mask = layout.present_mask(count)
        own = np.arange(n) < count
    agents = np.concatenate([np.zeros((b, n, 1, 2), ents.dtype), ents[..., agent_slots, :2]], -2)  # [B, N, A, 2]
    agent_present = np.concatenate([own[..., None], mask[..., agent_slots]], -1)  # [B, N, A]
    landmark_present = np.ascontiguousarray(mask[..., landmark_slots])  # [B, N, L]
    target = assigned_landmark(agents.reshape(b * n, -1, 2), ents[..., landmark_slots, :2].reshape(b * n, -1, 2),
                               agent_present.reshape(b * n, -1), landmark_present.reshape(b * n, -1))
    return target.reshape(b, n), landmark_present


def landmark_and_agent_slots(layout: EntityLayout) -> tuple[np.ndarray, np.ndarray]:
    """The entity slots (int64[L], int64[A-1]) that show a landmark and another agent, the same for every agent;
    ValueError (one line) for a layout without landmarks or whose slots differ between agents."""
    if "landmark" not in layout.type_names:
        raise ValueError(f"maddpg.assignment_loss needs a task with landmarks (navigation, env.task = 'spread'); "
                         f"this layout's entities are {list(layout.type_names)}")
    kind = layout.entity_type[..., layout.type_names.index("landmark")] > 0.5  # [N, E]
    other = layout.entity_agent >= 0  # [N, E]
    if not ((kind == kind[0]).all() and (other == other[0]).all()):
        raise ValueError("maddpg.assignment_loss needs the landmark and agent slots at the same places for every "
                         "agent (navigation's layout)")
    return np.flatnonzero(kind[0]), np.flatnonzero(other[0])


class AssignmentTerm:
    """β · CE of the entity actor's attention over the landmark slots toward each owner's assigned landmark (module
    docstring). `last`: the newest step's stats, float32[N] each ("assignment_loss", "assignment_accuracy")."""

    def __init__(self, weight: float, layout: EntityLayout):
        self.weight, self.layout = float(weight), layout
        self.landmark_slots = torch.from_numpy(landmark_and_agent_slots(layout)[0])
        self.last: dict[str, np.ndarray] = {}

    @staticmethod
    def build(weight: float, networks: str, layout: EntityLayout | None, pool: str, nearest: int
              ) -> AssignmentTerm | None:
        """The term of a learner, None when `weight` is 0 (off: the learner computes nothing more); ValueError (one
        line) when it cannot be built: a weight not finite or < 0, networks other than "entity", pool "mean" (no
        attention to supervise), nearest > 0 (the slots are reordered per row) or a layout without landmarks."""
        if not (math.isfinite(weight) and weight >= 0):
            raise ValueError(f"maddpg.assignment_loss must be a finite number >= 0, got {weight!r}")
        if weight == 0:
            return None
        why = ("maddpg.networks = 'entity'" if networks != "entity" else
               "an attention pool (maddpg.entity_pool 'attention' or 'relational')" if pool == "mean" else
               "every entity slot (entity_nearest = 0)" if nearest else
               "an entity layout" if layout is None else "")
        if why:
            raise ValueError(f"maddpg.assignment_loss = {weight!r} needs {why}, got networks {networks!r}, pool "
                             f"{pool!r}, nearest {nearest!r}")
        return AssignmentTerm(weight, layout)

    def loss(self, logits: torch.Tensor, own_obs: torch.Tensor, count: torch.Tensor | None = None) -> torch.Tensor:
        """β · CE per owner float32[N] (0 for an owner without a row where it is present): logits float32[N, S, E]
        (`EntityActor.act_and_attend` on own_obs), own_obs float32[N, S, obs_dim] (owner v's own observations),
        count int64[N, S] or None. Sets `last`."""
        obs = own_obs.detach().numpy().transpose(1, 0, 2)  # [S, N, obs_dim]: agent axis second, as split takes it
        target, present = assignment_targets(self.layout, obs, None if count is None else count.numpy().T)
        target = torch.from_numpy(np.ascontiguousarray(target.T))  # [N, S]
        valid = target >= 0
        keep = torch.from_numpy(present.transpose(1, 0, 2)) | ~valid.unsqueeze(-1)  # [N, S, L]; no mask: no target
        lm = logits[..., self.landmark_slots].masked_fill(~keep, float("-inf"))  # [N, S, L]
        ce = -torch.log_softmax(lm, -1).gather(-1, target.clamp(min=0).unsqueeze(-1)).squeeze(-1)  # [N, S]
        rows = valid.sum(1)
        ce = torch.where(valid, ce, 0.0).sum(1) / rows.clamp(min=1)  # [N]
        hits = ((lm.detach().argmax(-1) == target) & valid).sum(1)
        accuracy = (hits.double() / rows.double()).float()  # NaN: no row
        self.last = dict(zip(STATS, (ce.detach().numpy().copy(), accuracy.numpy()), strict=True))
        return self.weight * ce
