"""MADDPG for all agents of a run, every agent's networks stacked into one batched module (ALGORITHM.md §2).

Where it sits in the flow: the learner samples one minibatch per agent ("batch owner", §2/§3.6), stacks them as
``[N, S, ...]`` and calls :meth:`MADDPG.update`; rollout workers call :meth:`MADDPG.act` with weights shipped by
:meth:`MADDPG.actor_weights`; the teachers (§3.2) and the rescoring pass take their regression targets from
:meth:`MADDPG.td_targets` (the learner's TARGET actors and critics on the NEXT observations, A2/A19).

Members are agents: ``actor`` maps o_v [obs_dim] -> a_v [act_dim] (tanh, or Gumbel-softmax logits when
``discrete``); ``critic`` maps the joint input (all obs, then all actions, flattened) -> Q_v. Every agent has the
same obs_dim (shorter observations zero-padded by the env) and act_dim.

Public boundary: inputs may be numpy arrays or torch tensors (converted once, float32; per-owner minibatches by
`owner_batch` below); outputs are numpy.
Data conventions: joint rows ``obs[M, N, obs_dim], act[M, N, act_dim], rew[M, N], next_obs[M, N, obs_dim],
done[M, N]`` (per agent; ``[M]`` per row); per-owner stacks add a leading owner axis: ``obs[N, S, N, obs_dim]``,
``rew[N, S, N]``, ``done[N, S, N]`` (or the owner's own ``[N, S]``); with rows carried from fewer agents
(run.carry_replay) an optional ``present[N, S, N]`` bool masks the absent agents (cmcl.learners.agent_presence).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from cmcl.envs.entities import EntityLayout
from cmcl.learners import actor_grad
from cmcl.learners.agent_presence import AgentPresence, row_mean
from cmcl.learners.entity.assignment import AssignmentTerm
from cmcl.learners.entity.holder import require_holder_rule
from cmcl.learners.nets import (
    adam_step_,
    as_tensor,
    clip_grad_norm_per_member_,
    drop_grads_,
    joint_input,
    make_adam,
    soft_update_,
)
from cmcl.learners.networks import build_networks, network_kind
from cmcl.learners.normalised_td import normalised_td_error
from cmcl.learners.state_check import (
    require_same_holder,
    require_same_holder_rule,
    require_same_nearest,
    require_same_shapes,
)
from cmcl.learners.weights import load_published
from cmcl.replay.messages import ACTOR_PREFIX

__all__ = ["MADDPG"]

ArrayLike = np.ndarray | torch.Tensor


class OwnerBatch(NamedTuple):
    """A per-owner minibatch as tensors (unpacks as the tuple ``obs, act, rew, next_obs, done, weights, presence``)."""

    obs: torch.Tensor  # float32[N, S, N, obs_dim]
    act: torch.Tensor  # float32[N, S, N, act_dim]
    rew: torch.Tensor  # float32[N, S, N] or the owner's own [N, S]
    next_obs: torch.Tensor  # float32[N, S, N, obs_dim]
    done: torch.Tensor  # float32[N, S] or [N, S, N]; zeros when the batch has none
    weights: torch.Tensor | None  # is_weights float32[N, S] (critic only), None: unweighted
    presence: AgentPresence | None  # None: every agent of every row

def owner_batch(batch: Mapping[str, np.ndarray | torch.Tensor], num_agents: int, networks: str) -> OwnerBatch:
    """The critic's rows of a per-owner minibatch dict as tensors; ValueError on an obs that is not
    [N=num_agents, S, N, obs_dim], or on rows with absent agents for ``networks`` other than "entity"."""
    obs, act = as_tensor(batch["obs"]), as_tensor(batch["act"])
    n, s = obs.shape[0], obs.shape[1]
    if obs.dim() != 4 or n != num_agents or obs.shape[2] != num_agents:
        raise ValueError(f"obs must be [N={num_agents}, S, N, obs_dim], got {tuple(obs.shape)}")
    done = batch.get("done")
    done = torch.zeros(n, s) if done is None else as_tensor(done)
    w = batch.get("is_weights")
    presence = AgentPresence.of_batch(batch.get("present"), num_agents)
    if presence is not None and networks != "entity":
        raise ValueError(f"rows with absent agents (run.carry_replay) need entity networks, not {networks!r}")
    return OwnerBatch(obs, act, as_tensor(batch["rew"]), as_tensor(batch["next_obs"]), done,
                      None if w is None else as_tensor(w), presence)

def actor_rows(batch: Mapping[str, np.ndarray | torch.Tensor], obs: torch.Tensor, act: torch.Tensor,
               presence: AgentPresence | None, num_agents: int) -> tuple:
    """The actor step's rows (obs [N, B, N, obs_dim], act [N, B, N, act_dim], presence): the batch's "actor_obs",
    "actor_act" (and "actor_present") when it has them (actor_batch = "uniform"), else the critic's (obs, act,
    presence) as given. ValueError when their shapes do not match the critic's rows but for B."""
    if ACTOR_PREFIX + "obs" not in batch:
        return obs, act, presence
    a_obs, a_act = as_tensor(batch[ACTOR_PREFIX + "obs"]), as_tensor(batch[ACTOR_PREFIX + "act"])
    if a_obs.dim() != 4 or a_obs.shape[0] != num_agents or a_obs.shape[2:] != obs.shape[2:] \
            or a_act.shape[:2] != a_obs.shape[:2] or a_act.shape[2:] != act.shape[2:]:
        raise ValueError(f"actor_obs / actor_act must be [N={num_agents}, B, N, ·] like obs / act, got "
                         f"{tuple(a_obs.shape)} and {tuple(a_act.shape)}")
    return a_obs, a_act, AgentPresence.of_batch(batch.get(ACTOR_PREFIX + "present"), num_agents)


class MADDPG:
    """Stacked MADDPG learner (continuous tanh actions by default; Gumbel-softmax option, A17).

    Args:
        num_agents: N, agents whose actors/critics this learner owns (all agents of the world).
        obs_dim, act_dim: per-agent observation / action widths (act_dim 5 for the discrete MPE variant).
        hidden: hidden width of the 2-layer ReLU MLPs (int) or a tuple of widths.
        actor_lr, critic_lr: Adam learning rates.  gamma: discount.  tau: Polyak rate of the targets.
        grad_clip: per-agent gradient-norm clip (actor and critic).  discrete: Gumbel-softmax actors.
        gumbel_temperature: temperature of the Gumbel-softmax sample.  logit_l2: L2 on actor logits (discrete).
        seed: initial weights and the internal noise generator.
        networks: "per_agent" (the paper's, default), "shared" (one actor and one critic network for all agents,
            each agent keeping its own first-layer bias, an agent-id embedding; cmcl.learners.nets) or "entity": one
            attention actor and one permutation-invariant critic for all agents (cmcl.learners.entity.nets;
            ``hidden`` must be an int, the width H). With one network the gradient clip applies to it, and the
            per-agent grad norms report its norm for every agent.
        entity_layout: how the flat observation splits into entities (cmcl.envs.entities); needed by "entity".
        entity_pool: the entity encoder's pooling, "attention" or "mean" (cmcl.learners.entity.nets).
        entity_nearest: k > 0: the entity actor and critic read only the k nearest entities of each kind
            (entity_nets.nearest_entities; cheaper per update at large N, another model); 0 (default): every
            entity. The config's maddpg.entity_nearest; rollout workers' numpy twin of the actor
            (cmcl.rollout.policy.NumpyEntityPolicy, `nearest`) picks the same entities. The weights do not depend
            on k, so the state dict records it and loading it into a learner of another k is refused (a warm start,
            which copies the networks only, may change k: cmcl.run.warm_start).
        entity_holder: every entity row of the entity actor and critic (and their targets) ends with its holder
            margin (entity_nets.holder_margin: < 0 when another agent is closer to that landmark than the viewer;
            navigation only; one more input of the entity layer); False (default): not computed. The config's
            maddpg.entity_holder; the numpy twin takes it as `holder`. The state dict records it, and loading or
            warm-starting a state of the other value is refused, naming it (the entity layers' shapes differ).
        holder_rule: which other agents count as holding a landmark in that margin, "nearest" (default) or "seated"
            (cmcl.learners.entity.holder; maddpg.holder_rule). The state dict records it; loading a state of the
            other rule is refused (a warm start may change it: the weights fit either way).
        act_mask: float32[N, act_dim], 1 on the action entries each agent has and 0 on zero padding (agents whose
            action sizes differ); every actor output is multiplied by it, so the critics only ever see zeros there.
            None: every entry is used.
        assignment_loss: β > 0 adds β · the cross-entropy of the entity actor's attention over the landmarks toward
            a minimum-total-distance assignment to the actor loss (cmcl.learners.entity.assignment; entity networks with
            an attention pool, navigation only, entity_nearest 0); 0 (default): off, nothing more is computed.
    """

    def __init__(
        self,
        num_agents: int,
        obs_dim: int,
        act_dim: int = 2,
        hidden: int | Sequence[int] = 64,
        actor_lr: float = 1e-3,
        critic_lr: float = 1e-3,
        gamma: float = 0.99,
        tau: float = 0.01,
        grad_clip: float = 0.5,
        discrete: bool = False,
        gumbel_temperature: float = 1.0,
        logit_l2: float = 1e-3,
        seed: int = 0,
        act_mask: np.ndarray | None = None,
        networks: str = "per_agent",
        entity_layout: EntityLayout | None = None,
        entity_pool: str = "attention",
        target_scores: bool = False,
        entity_nearest: int = 0,
        assignment_loss: float = 0.0,
        entity_holder: bool = False,
        holder_rule: str = "nearest",
    ):
        self.num_agents, self.obs_dim, self.act_dim = int(num_agents), int(obs_dim), int(act_dim)
        # also return |y − Q_target(s, a)| per sampled row (ReLo's target loss; cmcl.replay.registry's
        # Needs.learner_scores)
        self.target_scores = bool(target_scores)
        self.gamma, self.tau, self.grad_clip = float(gamma), float(tau), float(grad_clip)
        self.discrete, self.temperature, self.logit_l2 = bool(discrete), float(gumbel_temperature), float(logit_l2)
        widths = (hidden, hidden) if isinstance(hidden, int) else tuple(hidden)
        init_seed, noise_seed = np.random.SeedSequence(seed).generate_state(2)
        gen = torch.Generator().manual_seed(int(init_seed))
        n = self.num_agents
        self.networks = network_kind(networks)
        self.entity_nearest, self.entity_holder = int(entity_nearest), bool(entity_holder)
        self.holder_rule = require_holder_rule(holder_rule)
        self.actor, self.critic = build_networks(self.networks, n, obs_dim, act_dim, widths, discrete, gen,
                                                 entity_layout, entity_pool, entity_nearest, self.entity_holder,
                                                 self.holder_rule)
        self.assignment = AssignmentTerm.build(float(assignment_loss), self.networks, entity_layout, entity_pool,
                                               entity_nearest)
        self.target_actor = copy.deepcopy(self.actor).requires_grad_(False)
        self.target_critic = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_opt = make_adam(self.actor.parameters(), actor_lr)
        self.critic_opt = make_adam(self.critic.parameters(), critic_lr)
        self.noise_gen = torch.Generator().manual_seed(int(noise_seed))
        self.updates = 0
        self._agents = torch.arange(n)
        self._own_mask = torch.eye(n, dtype=torch.bool).view(n, 1, n, 1)  # [owner, 1, agent, 1]
        self.act_mask = None if act_mask is None else torch.as_tensor(act_mask, dtype=torch.float32).view(n, 1, -1)

    @staticmethod
    def _owners_own(x: torch.Tensor) -> torch.Tensor:
        """Each owner's own column of per-owner rows, as a view (no copy): x [N, S, N, ...] -> [N, S, ...], row v being
        x[v, :, v] (owner v's own reward, done or observation)."""
        return x.diagonal(0, 0, 2).movedim(-1, 0)

    # ------------------------------------------------------------------ targets
    def _q(self, net: nn.Module, x: torch.Tensor, members: torch.Tensor | None = None,
           count: torch.Tensor | None = None) -> torch.Tensor:
        """A critic's Q on joint inputs (shared rows [M, in] -> [A, M]; per-owner [N, S, in] -> [N, S]); count: the
        present agents of each row ([M] or [N, S]; entity networks only)."""
        return (net(x, members) if count is None else net(x, members, count=count)).squeeze(-1)

    def _td_targets_t(
        self, rew: torch.Tensor, next_obs: torch.Tensor, done: torch.Tensor | None, agents: torch.Tensor | None,
        count: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """y = r + gamma (1 - done) Q'_v(s', pi'(o')) with TARGET nets (eqs. 5, 10; no grad); see :meth:`td_targets`;
        count: the present agents of each row ([M] or per owner [N, S]), None for all."""
        ag = self._agents if agents is None else agents
        if next_obs.dim() == 4 and next_obs.shape[0] != len(ag):
            raise ValueError(f"per-owner next_obs has {next_obs.shape[0]} owners but {len(ag)} agents are selected")
        with torch.no_grad():
            a_next = self._joint_actions(self.target_actor, next_obs, True, count)
            x = joint_input(next_obs, a_next)
            q = self._q(self.target_critic, x, None if agents is None else ag, count)
            if next_obs.dim() == 3:  # joint rows: x [M, in] shared by the selected critics -> q [A, M]
                r = rew.T[ag]
                d = torch.zeros(rew.shape[0]) if done is None else done
                d = d.T[ag] if d.dim() == 2 else d.unsqueeze(0)  # each agent's own done [A, M] (or the row's)
                return r + self.gamma * (1.0 - d) * q
            own = self._owners_own if agents is None else (lambda t: t[torch.arange(len(ag)), :, ag])
            r = own(rew) if rew.dim() == 3 else rew  # owner's own reward [A, S]
            d = torch.zeros_like(r) if done is None else done
            d = own(d) if d.dim() == 3 else d  # owner's own done [A, S]
            return r + self.gamma * (1.0 - d) * q

    def td_targets(
        self,
        rew: ArrayLike,
        next_obs: ArrayLike,
        done: ArrayLike | None = None,
        agents: Sequence[int] | np.ndarray | None = None,
    ) -> np.ndarray:
        """Critic/teacher regression targets from the learner's target networks on the NEXT observations.

        Joint rows: rew [M, N], next_obs [M, N, obs_dim], done [M, N] (per agent) or [M] (per row)
                    -> y float32[A, M] (row a = agent agents[a]).
        Per-owner:  rew [A, S, N] (or the owner's own [A, S]), next_obs [A, S, N, obs_dim], done [A, S, N] (or the
                    owner's own [A, S]) -> y float32[A, S], owner a being agent agents[a].
        ``agents`` defaults to all N agents. ``done`` defaults to 0 (always the case in the built-in tasks, §2);
        agent a's target uses its own done (an agent that terminates before the others cuts only its bootstrap).
        Discrete actors use a Gumbel-softmax sample of the target logits (as openai/maddpg).
        """
        ag = None if agents is None else torch.as_tensor(np.asarray(agents), dtype=torch.int64)
        d = None if done is None else as_tensor(done)
        return self._td_targets_t(as_tensor(rew), as_tensor(next_obs), d, ag).numpy()

    # ------------------------------------------------------------------ update
    def _td_errors(self, obs: torch.Tensor, act: torch.Tensor, rew: torch.Tensor, next_obs: torch.Tensor,
                   done: torch.Tensor, presence: AgentPresence | None, x: torch.Tensor | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """TD targets y [N, S] and errors y − Q_v(s, a) [N, S] of the current critic (eq. 5; not masked by presence)
        on per-owner rows, and the rows' present-agent counts int64[N, S] (None: all present); x: the rows' joint
        input joint_input(obs, act) float32[N, S, in] when the caller has built it, else None."""
        count = None if presence is None else presence.count
        y = self._td_targets_t(rew, next_obs, done, None, count)
        x = joint_input(obs, act) if x is None else x
        return y, y - self._q(self.critic, x, None, count), count

    def _critic_step(self, obs, act, rew, next_obs, done, w, presence: AgentPresence | None = None
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """One batched critic step on (y − Q_v(s, a))² (eq. 5), over the rows where owner v is present. Returns
        (loss [N], delta [N, S] (0 where the owner is absent), grad norm [N], normalised TD error [N]:
        cmcl.learners.normalised_td)."""
        x = joint_input(obs, act)  # [N, S, in], built once for the critic and (ReLo) the target critic
        y, delta, count = self._td_errors(obs, act, rew, next_obs, done, presence, x)  # [N, S], [N, S]
        delta = delta if presence is None else delta * presence.own
        if self.target_scores:  # the same target against the target critic, before the step moves it (ReLo)
            with torch.no_grad():
                target_delta = y - self._q(self.target_critic, x, None, count)
            self.last_target_td = (target_delta if presence is None else target_delta * presence.own).abs()
        loss = row_mean(delta.pow(2), w, presence)  # [N]
        unexplained = normalised_td_error(y, delta.detach(), presence)
        params = list(self.critic.parameters())
        drop_grads_(params)
        self._total(loss, presence).backward()
        norms = self._clip(params)
        adam_step_(self.critic_opt)
        return loss.detach(), delta.detach(), norms, unexplained

    def _actor_step(self, obs: torch.Tensor, act: torch.Tensor, presence: AgentPresence | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        """One batched actor step (eq. 4): owner v's own action -> pi_v(o_v), others from the buffer; over the rows
        where owner v is present.

        Returns (loss [N], pre-clip grad norm [N]). Only actor parameters receive gradients. With the assignment
        term (`assignment`), the step minimises loss + β · CE (cmcl.learners.entity.assignment); the loss returned is
        eq. 4's.
        Per-agent MLPs with continuous actions take the gradient from cmcl.learners.actor_grad (the same numbers).
        """
        own_obs = self._owners_own(obs)  # [N, S, obs_dim]
        params = list(self.actor.parameters())
        if (presence is None and self.act_mask is None and self.assignment is None and not self.discrete
                and actor_grad.supports(self.actor, self.critic)):  # the same step without autograd's bookkeeping
            loss, grads = actor_grad.actor_loss_and_grads(self.actor, self.critic, obs, act, own_obs, self._own_mask)
            for p, g in zip(params, grads, strict=True):
                p.grad = g
            norms = self._clip(params)
            adam_step_(self.actor_opt)
            return loss, norms
        count = None if presence is None else presence.count
        out, logits = (None, None) if self.assignment is None else self.actor.act_and_attend(own_obs, count=count)
        pi, raw = self._policy(self.actor, own_obs, True, count, out)  # [N, S, act_dim]
        if self.networks == "entity":  # the buffer's actions fill the entity slots; pi_v enters Q_v as its own
            q = self.critic.q_own_action(obs, act, pi, count)  # [N, S], as the joint path below, fewer backward ops
        else:
            joint_act = torch.where(self._own_mask, pi.unsqueeze(2), act)  # [N, S, N, act_dim]
            q = self._q(self.critic, joint_input(obs, joint_act), None, count)
        loss = -row_mean(q, None, presence)  # [N]
        if self.discrete:
            l2 = raw.pow(2).mean((1, 2)) if presence is None else row_mean(raw.pow(2).mean(2), None, presence)
            loss = loss + self.logit_l2 * l2
        total = loss if self.assignment is None else loss + self.assignment.loss(logits, own_obs, count)
        drop_grads_(params)
        self._total(total, presence).backward(inputs=params)
        norms = self._clip(params)
        adam_step_(self.actor_opt)
        return loss.detach(), norms

    def _total(self, loss: torch.Tensor, presence: AgentPresence | None = None) -> torch.Tensor:
        """The scalar to differentiate from per-agent losses [N]: their sum (each member's gradient is its own
        agent's), their mean for the one entity network (its gradient then has one agent's scale for the clip),
        over the owners present in some row when agents are absent."""
        if presence is not None:
            return presence.total(loss)
        return loss.mean() if self.networks == "entity" else loss.sum()

    def _clip(self, params) -> torch.Tensor:
        """Clip the gradients per member (one norm for a shared network); pre-clip norms float32[N]."""
        norms = clip_grad_norm_per_member_(params, self.grad_clip)
        return norms.expand(self.num_agents) if norms.numel() == 1 else norms

    def update(self, batch: Mapping[str, ArrayLike]) -> dict[str, np.ndarray]:
        """One MADDPG step for all agents on per-owner minibatches (§2): critic (eq. 5), actor (eq. 4), targets (eq. 6).

        batch: obs [N, S, N, obs_dim], act [N, S, N, act_dim], rew [N, S, N] (or own [N, S]),
               next_obs [N, S, N, obs_dim], optional done [N, S] or per agent [N, S, N] (owner v reads its own
               column), optional is_weights [N, S] (critic only), optional actor_obs [N, B, N, obs_dim],
               actor_act [N, B, N, act_dim] (and actor_present [N, B, N]): the actor step's own rows (actor_batch =
               "uniform"; absent: the actor trains on the critic's rows).
        Returns numpy: critic_loss [N] (pre-step, weighted), critic_loss_normalised [N] (pre-step, unweighted mean
        squared TD error over the variance of the targets y, nan where y has none: normalised_td), actor_loss [N],
        td_abs |y - Q| [N, S] (pre-step, for PER), critic_grad_norm [N], actor_grad_norm [N] (pre-clip), and with
        `target_scores` target_td_abs |y − Q_target| [N, S] (pre-step, ReLo), and with the assignment term
        assignment_loss [N] (its unweighted CE) and assignment_accuracy [N] (cmcl.learners.entity.assignment).
        """
        obs, act, rew, next_obs, done, w, presence = owner_batch(batch, self.num_agents, self.networks)
        c_loss, delta, c_norm, unexplained = self._critic_step(obs, act, rew, next_obs, done, w, presence)
        a_loss, a_norm = self._actor_step(*actor_rows(batch, obs, act, presence, self.num_agents))
        soft_update_((self.target_critic, self.target_actor), (self.critic, self.actor), self.tau)
        self.updates += 1
        return {
            "critic_loss": c_loss.numpy(),
            "critic_loss_normalised": unexplained.numpy(),
            "actor_loss": a_loss.numpy(),
            "td_abs": delta.abs().numpy(),
            "critic_grad_norm": c_norm.numpy(),
            "actor_grad_norm": a_norm.numpy(),
            **({"target_td_abs": self.last_target_td.numpy()} if self.target_scores else {}),
            **({} if self.assignment is None else self.assignment.last),
        }

    @torch.no_grad()
    def td_abs(self, batch: Mapping[str, ArrayLike]) -> np.ndarray:
        """|y − Q_v(s, a)| of every row of a per-owner batch under the current critic, nothing updated ->
        float32[N, S] (0 where the owner is absent). LaBER scores its candidates with it."""
        obs, act, rew, next_obs, done, _, presence = owner_batch(batch, self.num_agents, self.networks)
        _, delta, _ = self._td_errors(obs, act, rew, next_obs, done, presence)
        return (delta if presence is None else delta * presence.own).abs().numpy()

    @torch.no_grad()
    def critic_loss(self, batch: Mapping[str, ArrayLike]) -> np.ndarray:
        """Per-agent (weighted) critic MSE on a per-owner batch without updating anything -> float32[N]."""
        obs, act, rew, next_obs, done, w, presence = owner_batch(batch, self.num_agents, self.networks)
        _, delta, _ = self._td_errors(obs, act, rew, next_obs, done, presence)
        return row_mean(delta.pow(2), w, presence).numpy()

    # ------------------------------------------------------------------ actions (exploration, TD targets, actor step)
    def _policy(self, net: nn.Module, obs: torch.Tensor, sample: bool, count: torch.Tensor | None = None,
                out: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """obs [N, B, obs_dim] (count: the present agents of each row, int64[N, B], entity networks only)
        -> (actions [N, B, act_dim], raw outputs [N, B, act_dim]).

        Continuous: the tanh output is the action. Discrete: Gumbel-softmax sample of the logits (``sample``),
        else their softmax; padded entries (act_mask 0) get probability 0 (and raw output 0). `out`: net's output
        on obs float32[N, B, act_dim] when the caller already has it (the actor step's assignment loss), else None.
        """
        if out is None:
            out = net(obs) if count is None else net(obs, count=count)
        if self.act_mask is not None:
            out = out * self.act_mask
        if not self.discrete:
            return out, out
        raw, out = out, self._padded_logits(out, self.act_mask)
        if sample:
            u = torch.rand(out.shape, generator=self.noise_gen).clamp_(1e-10, 1.0 - 1e-7)
            return F.softmax((out - torch.log(-torch.log(u))) / self.temperature, dim=-1), raw
        return F.softmax(out, dim=-1), raw

    @staticmethod
    def _padded_logits(logits: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """Logits with −inf on the padded entries (mask 0, broadcast against logits): a softmax gives them 0."""
        return logits if mask is None else logits.masked_fill(mask == 0, float("-inf"))

    def _joint_actions(self, net: nn.Module, obs: torch.Tensor, sample: bool,
                       count: torch.Tensor | None = None) -> torch.Tensor:
        """Every agent's action from its own obs: obs [..., N, obs_dim] (count int64[...]) -> act [..., N, act_dim]."""
        lead = obs.shape[:-2]
        x = obs.reshape(-1, self.num_agents, self.obs_dim).transpose(0, 1)  # [N, B, obs_dim]
        rows = None if count is None else count.reshape(1, -1).expand(self.num_agents, -1)  # [N, B]
        a, _ = self._policy(net, x, sample, rows)
        return a.transpose(0, 1).reshape(*lead, self.num_agents, self.act_dim)

    @torch.no_grad()
    def act(self, obs: ArrayLike, noise_std: float = 0.1, rng: np.random.Generator | None = None) -> np.ndarray:
        """Exploration actions: obs float32[B, N, obs_dim] -> float32[B, N, act_dim].

        Continuous: clip(pi_v(o_v) + N(0, noise_std^2), -1, 1). Discrete: a Gumbel-softmax sample when
        noise_std > 0, the softmax otherwise. Noise comes from ``rng`` (numpy) if given, else the internal
        torch generator.
        """
        o = as_tensor(obs)
        x = o.transpose(0, 1)  # [N, B, obs_dim]
        out = self.actor(x).transpose(0, 1)  # [B, N, act_dim]
        if self.discrete:
            out = self._padded_logits(out, None if self.act_mask is None else self.act_mask.transpose(0, 1))
            if noise_std > 0:
                g = (
                    torch.from_numpy(rng.gumbel(size=out.shape).astype(np.float32))
                    if rng is not None
                    else -torch.log(-torch.log(torch.rand(out.shape, generator=self.noise_gen).clamp_(1e-10, 1 - 1e-7)))
                )
                out = (out + g) / self.temperature
            return F.softmax(out, dim=-1).numpy()
        if noise_std > 0:
            noise = (
                torch.from_numpy(rng.normal(0.0, noise_std, size=out.shape).astype(np.float32))
                if rng is not None
                else torch.randn(out.shape, generator=self.noise_gen) * noise_std
            )
            out = out + noise
        out = out.clamp_(-1.0, 1.0)
        if self.act_mask is not None:
            out = out * self.act_mask.transpose(0, 1)
        return out.numpy()

    # ------------------------------------------------------------------ weights and state (rollouts, checkpoints)
    def actor_weights(self) -> dict[str, np.ndarray]:
        """Online actor parameters as numpy copies, e.g. {"layers.0.weight": float32[N, obs_dim, 64], ...}."""
        return {k: v.detach().numpy().copy() for k, v in self.actor.state_dict().items()}

    def load_actor_weights(self, weights: Mapping[str, np.ndarray | torch.Tensor]) -> None:
        """Load :meth:`actor_weights` output into the ONLINE actor (rollout workers); targets untouched. Keys, shapes
        and finiteness are checked first (ValueError), as for every published part (cmcl.learners.weights)."""
        load_published(self, {"actor": weights}, ("actor",))

    def state_dict(self) -> dict:
        """Nets, targets, optimisers, noise generator state and update counter (torch.load(weights_only=True) safe).

        Layout: {"actor", "critic", "target_actor", "target_critic": module state dicts with stacked
        tensors [N, in, out] / [N, out]; "actor_opt", "critic_opt": Adam state dicts; "noise_gen": uint8 tensor;
        "updates": int; "entity_nearest": int, the k of maddpg.entity_nearest (the weights do not show it);
        "entity_holder": bool, maddpg.entity_holder; "holder_rule": str, maddpg.holder_rule}.
        """
        return {
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "target_actor": self.target_actor.state_dict(),
            "target_critic": self.target_critic.state_dict(),
            "actor_opt": self.actor_opt.state_dict(),
            "critic_opt": self.critic_opt.state_dict(),
            "noise_gen": self.noise_gen.get_state(),
            "updates": int(self.updates),
            "entity_nearest": int(self.entity_nearest),
            "entity_holder": bool(self.entity_holder),
            "holder_rule": str(self.holder_rule),
        }

    def load_state_dict(self, state: Mapping) -> None:
        """Restore everything saved by :meth:`state_dict` (same architecture required: checked first, by name)."""
        parts = ("actor", "critic", "target_actor", "target_critic")
        require_same_holder("checkpoint maddpg", self.entity_holder, state)
        require_same_shapes("checkpoint maddpg", {name: getattr(self, name) for name in parts}, state,
                            "maddpg.networks, maddpg.hidden, agents or observation sizes")
        require_same_nearest("checkpoint maddpg", self.entity_nearest, state)
        require_same_holder_rule("checkpoint maddpg", self.holder_rule, state)
        for name in parts:
            getattr(self, name).load_state_dict(state[name])
        self.actor_opt.load_state_dict(state["actor_opt"])
        self.critic_opt.load_state_dict(state["critic_opt"])
        self.noise_gen.set_state(state["noise_gen"])
        self.updates = int(state["updates"])
