"""K-fold teacher critics (ALGORITHM.md §3.2, A2/A3/A13/A19): the networks of eqs. (9) and (10).

Where it sits in the flow: at every learner update (or, in the service, every teacher-actor step) the replay draws
one batch per fold from that fold only (`cmcl.replay.buffer_steps.fold_batch_slots`);
`cmcl.learners.network_steps.fit_teachers` regresses every teacher on the learner's TD targets
(``MADDPG.td_targets``, the learner's TARGET nets, never the teachers) with :meth:`TeacherEnsemble.fit_step` (eq. 9).
Scoring runs :meth:`TeacherEnsemble.errors` on buffer rows (eq. 10, `cmcl.learners.network_steps.teacher_errors`)
and `cmcl.scorers.difficulty` turns the errors into c_{v,j}
(eq. 11: the sum over the K-1 teachers that never saw j); ``cmcl.replay.priority`` normalises c and computes KP.

All A x K teachers are ONE :class:`~cmcl.learners.nets.StackedMLP` with A*K members, member index ``a*K + i`` for agent
slot a (0..A-1, the agents that use teachers) and fold i (0..K-1). Folds are 0-based: f(j) in {0..K-1}.
With ``networks = "shared"`` the A teachers of each fold are one network (``StackedMLP(share=True, share_groups=K)``:
member ``a*K + i`` uses network i), each agent keeping its own first-layer bias; the K folds stay separate networks,
so a fold's network is still fitted on its own fold only and the cross-validation of eq. (11) holds.
With ``networks="entity"`` each fold is one :class:`~cmcl.learners.entity.nets.EntityCritic` for all agents (group
axis K: fold i's network only ever reads fold i's rows), teacher (a, i) being fold i's Q of agent ``agents[a]``;
its parameter count does not depend on N, and with ``entity_nearest`` = k > 0 it reads only the k nearest entities of
each kind, with ``entity_holder`` each entity row with its holder margin, as the learner's critic does.
Teacher input = the centralized critic input (all obs then all actions, flattened; see ``nets.joint_input``).
Public boundary: numpy or torch in (converted once, float32 / int64); numpy out.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch

from cmcl.envs.entities import EntityLayout
from cmcl.learners.entity.nets import EntityCritic
from cmcl.learners.nets import StackedMLP, adam_step_, as_tensor, clip_grad_norm_per_member_, drop_grads_, make_adam
from cmcl.learners.networks import network_kind
from cmcl.learners.state_check import require_same_shapes

__all__ = ["TeacherEnsemble"]

ArrayLike = np.ndarray | torch.Tensor


class TeacherEnsemble:
    """A x K teacher critics (2 hidden ReLU layers, scalar output), trained online on their own folds.

    Args:
        num_agents: A, agents that use teachers (ACL/CMCL agents).
        in_dim: teacher input width = N*(obs_dim + act_dim).
        num_folds: K.  hidden: hidden width (int) or widths.  lr: Adam rate (= critic lr, A13).
        grad_clip: optional per-teacher gradient-norm clip (None: none; §3.2 specifies plain Adam).
        chunk_size: rows per forward pass in :meth:`errors` (bounds memory at A*K*chunk*hidden floats).
        seed: initial weights (every teacher independently initialised).
        networks: "per_agent" (default), "shared" (one network per fold for all A agents, a per-(agent, fold)
            first-layer bias; parameters ~A times fewer, for N = 8 / 16) or "entity" (module docstring).
        agents: int64[A], the agents the teachers stand for (entity teachers read their Q); default 0..A-1.
        entity_layout, act_dim, entity_pool: the observation's entity layout, the action width and the encoder's
            pooling (entity teachers only).
        entity_nearest: k > 0: entity teachers read only the k nearest entities of each kind, as the learner's
            critic does (maddpg.entity_nearest); 0: every entity.
        entity_holder: entity teachers read every entity row with its holder margin, as the learner's critic does
            (maddpg.entity_holder; navigation only), by entity_holder_rule (maddpg.holder_rule).
    """

    def __init__(
        self,
        num_agents: int,
        *,
        in_dim: int,
        num_folds: int = 5,
        hidden: int | Sequence[int] = 64,
        lr: float = 1e-3,
        grad_clip: float | None = None,
        chunk_size: int = 1024,
        seed: int = 0,
        networks: str = "per_agent",
        agents: Sequence[int] | np.ndarray | None = None,
        entity_layout: EntityLayout | None = None,
        act_dim: int = 2,
        entity_pool: str = "attention",
        entity_nearest: int = 0,
        entity_holder: bool = False,
        entity_holder_rule: str = "nearest",
    ):
        self.num_agents, self.num_folds, self.in_dim = int(num_agents), int(num_folds), int(in_dim)
        self.grad_clip, self.chunk_size = grad_clip, int(chunk_size)
        widths = (hidden, hidden) if isinstance(hidden, int) else tuple(hidden)
        self.networks = network_kind(networks)
        self.agents = torch.arange(self.num_agents) if agents is None else torch.as_tensor(np.asarray(agents))
        if self.networks == "entity":
            if entity_layout is None or in_dim != entity_layout.num_agents * (entity_layout.obs_dim + act_dim):
                raise ValueError(f"entity teachers need the entity layout whose joint input is in_dim={in_dim}")
            if len(set(widths)) != 1:
                raise ValueError(f"entity teachers take one hidden width, got {widths}")
            self.net = EntityCritic(entity_layout, act_dim, widths[0], torch.Generator().manual_seed(int(seed)),
                                    groups=self.num_folds, pool=entity_pool, nearest=entity_nearest,
                                    holder=entity_holder, holder_rule=entity_holder_rule)
        else:
            self.net = StackedMLP(self.num_agents * self.num_folds, self.in_dim, widths, 1, seed=seed,
                                  share=self.networks == "shared", share_groups=self.num_folds)
        self.opt = make_adam(self.net.parameters(), lr)
        self.steps = 0

    def fit_step(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """One Adam step for every teacher on its own fold batch: L = mean (y − T(x))² (eq. 9).

        x float32[A, K, S_T, in_dim], y float32[A, K, S_T] -> pre-step MSE loss float32[A, K].
        """
        x_t, y_t = as_tensor(x), as_tensor(y)
        a_n, k_n, s_n, _ = x_t.shape
        if (a_n, k_n) != (self.num_agents, self.num_folds):
            raise ValueError(f"x must be [A={self.num_agents}, K={self.num_folds}, S, in], got {tuple(x_t.shape)}")
        if self.networks == "entity":  # fold i's network on every agent's rows of fold i: [K, A*S] -> [A*K, S]
            pred = self._entity_q(x_t.transpose(0, 1).reshape(k_n, a_n * s_n, -1)).view(k_n, a_n, s_n)
            pred = pred.transpose(0, 1).reshape(a_n * k_n, s_n)
        elif self.networks == "shared" and x_t.stride(0) == 0:  # one fold batch for all agents (fit_batch "shared")
            pred = self.net(x_t[0]).squeeze(-1)  # [K, S, in] per fold network -> [A*K, S], first layer once per fold
        else:
            pred = self.net(x_t.reshape(a_n * k_n, s_n, -1)).squeeze(-1)  # [A*K, S]
        loss = (pred - y_t.reshape(a_n * k_n, s_n)).pow(2).mean(1)  # [A*K]
        params = list(self.net.parameters())
        drop_grads_(params)
        loss.sum().backward()
        if self.grad_clip is not None:
            clip_grad_norm_per_member_(params, self.grad_clip)
        adam_step_(self.opt)
        self.steps += 1
        return loss.detach().reshape(a_n, k_n).numpy()

    @torch.no_grad()
    def predict(self, x: ArrayLike) -> np.ndarray:
        """Teacher outputs on shared rows: x float32[M, in_dim] -> float32[A, M, K] (chunked)."""
        x_t = as_tensor(x)
        net = self._entity_rows if self.networks == "entity" else (lambda rows: self.net(rows).squeeze(-1))
        parts = [net(x_t[s : s + self.chunk_size]) for s in range(0, x_t.shape[0], self.chunk_size)]
        p = torch.cat(parts, dim=1) if parts else torch.zeros(self.num_agents * self.num_folds, 0)  # [A*K, M]
        return p.reshape(self.num_agents, self.num_folds, -1).permute(0, 2, 1).contiguous().numpy()

    def _entity_q(self, x: torch.Tensor) -> torch.Tensor:
        """Fold inputs float32[K, A*S, in] (agent-major within each fold) -> each fold's Q of its agent [K, A*S]."""
        rows = x.shape[1] // self.num_agents
        agent = self.agents.repeat_interleave(rows).unsqueeze(0).expand(self.num_folds, -1)
        return self.net.joint_q(x, agent)

    def _entity_rows(self, x: torch.Tensor) -> torch.Tensor:
        """Shared rows float32[M, in] -> every teacher's output [A*K, M] (member a*K + i), as the stacked MLP's."""
        m = x.shape[0]
        q = self._entity_q(x.unsqueeze(0).expand(self.num_folds * self.num_agents, m, -1)
                           .reshape(self.num_folds, self.num_agents * m, -1))  # [K, A*M]
        return q.view(self.num_folds, self.num_agents, m).transpose(0, 1).reshape(-1, m)

    def errors(self, x: ArrayLike, y: ArrayLike, squared: bool | Sequence[bool] = True) -> np.ndarray:
        """Errors e_{a,j,i} = (y_{a,j} - T_{a,i}(x_j))^2 (eq. 10; or |.|): x [M, in], y [A, M] -> [A, M, K].
        squared: one choice for every agent, or one per agent (its team's priority.difficulty_error)."""
        d = as_tensor(y).unsqueeze(-1) - torch.from_numpy(self.predict(x))
        square = np.broadcast_to(np.asarray(squared, dtype=bool), (d.shape[0],))
        if square.all() or not square.any():
            return (d.pow(2) if square.all() else d.abs()).numpy()
        return torch.where(torch.from_numpy(square.copy()).view(-1, 1, 1), d.pow(2), d.abs()).numpy()

    def state_dict(self) -> dict:
        """{"net": stacked teacher weights [A*K, in, out]/[A*K, out], "opt": Adam state, "steps": int}."""
        return {"net": self.net.state_dict(), "opt": self.opt.state_dict(), "steps": int(self.steps)}

    def load_state_dict(self, state: Mapping) -> None:
        """Restore :meth:`state_dict` output (same A, K, in_dim, hidden, sharing: checked first, by name)."""
        require_same_shapes("checkpoint teachers", {"net": self.net}, state,
                            "teachers.networks, teachers.num_folds, teachers.hidden or "
                            "agents")
        self.net.load_state_dict(state["net"])
        self.opt.load_state_dict(state["opt"])
        self.steps = int(state["steps"])
