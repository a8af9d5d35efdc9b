"""K-fold teacher critics and cross-validated difficulty (ALGORITHM.md §3.2, A2/A3/A13/A19).

Where it sits in the flow: every learner update (or, in the service, every teacher-actor step) draws one batch
per (agent, fold) from that fold only (:func:`fold_batch_indices`), builds inputs and the learner's TD targets
(:func:`make_fit_batch`, targets from ``MADDPG.td_targets`` — the learner's TARGET nets, never the teachers) and
calls :meth:`TeacherEnsemble.fit_step`. Rescoring runs :meth:`TeacherEnsemble.errors` on buffer rows and
:func:`cross_validated_difficulty` turns the errors into c_{v,j} (sum over the K-1 teachers that never saw j);
``priority.py`` normalises c and computes KP.

All A x K teachers are ONE :class:`~cmcl.learners.nets.StackedMLP` with A*K members, member index ``a*K + i`` for agent
slot a (0..A-1, the agents that use teachers) and fold i (0..K-1). Folds are 0-based: f(j) in {0..K-1}.
Teacher input = the centralized critic input (all obs then all actions, flattened; see ``nets.joint_input``).
Public boundary: numpy or torch in (converted once, float32 / int64); numpy out.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import torch

from cmcl.learners.nets import StackedMLP, as_tensor, clip_grad_norm_per_member_, joint_input, make_adam

__all__ = ["TeacherEnsemble", "cross_validated_difficulty", "fold_batch_indices", "make_fit_batch"]

ArrayLike = np.ndarray | torch.Tensor


def fold_batch_indices(
    fold: np.ndarray, num_folds: int, batch_size: int, rng: np.random.Generator, num_agents: int = 1
) -> np.ndarray:
    """Uniform draws (with replacement) of buffer rows from each fold, vectorised over agents and folds.

    fold int64[M] (0..K-1, the fold of every stored row) -> idx int64[A, K, S_T] with fold[idx[a, i]] == i.
    Raises ValueError if some fold is empty.
    """
    fold = np.asarray(fold, dtype=np.int64)
    counts = np.bincount(fold, minlength=num_folds)[:num_folds]  # [K]
    if fold.size == 0 or (counts == 0).any() or fold.min() < 0 or fold.max() >= num_folds:
        raise ValueError(f"every fold 0..{num_folds - 1} needs rows; counts per fold = {counts.tolist()}")
    order = np.argsort(fold, kind="stable")  # rows grouped by fold
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])  # [K]
    u = rng.random((num_agents, num_folds, batch_size))
    pos = starts[None, :, None] + np.minimum((u * counts[None, :, None]).astype(np.int64), counts[None, :, None] - 1)
    return order[pos]


def make_fit_batch(
    idx: np.ndarray,
    data: Mapping[str, ArrayLike],
    agents: Sequence[int] | np.ndarray,
    td_targets: Callable[..., np.ndarray],
) -> tuple[torch.Tensor, torch.Tensor]:
    """Teacher minibatches from buffer rows: x float32[A, K, S_T, in_dim], y float32[A, K, S_T].

    idx int64[A, K, S_T] (from :func:`fold_batch_indices`, one index set per agent slot as in §3.2), or
    int64[1, K, S_T] to share fold batches across the A agents (cheaper: one target pass; option, not the §3.2
    default). data holds joint rows ``obs [M, N, od], act [M, N, ad], rew [M, N], next_obs [M, N, od]`` and
    optionally ``done [M]``; agents int[A] are the agent ids of the teacher slots; td_targets is
    ``MADDPG.td_targets`` (the learner's target nets).
    """
    agents = np.asarray(agents)
    a_n, (b_n, k_n, s_n) = len(agents), idx.shape
    if b_n not in (1, a_n):
        raise ValueError(f"idx must be [A={a_n} or 1, K, S], got {idx.shape}")
    flat = torch.as_tensor(np.asarray(idx).reshape(b_n, k_n * s_n), dtype=torch.int64)  # [B, K*S]
    if b_n == 1 and a_n > 1:
        flat = flat[0]  # joint rows shared by every agent: y [A, K*S], x [K*S, in] broadcast
    obs, act = as_tensor(data["obs"])[flat], as_tensor(data["act"])[flat]  # [(B,) K*S, N, *]
    rew, next_obs = as_tensor(data["rew"])[flat], as_tensor(data["next_obs"])[flat]
    done = data.get("done")
    done = None if done is None else as_tensor(done)[flat]
    y = as_tensor(td_targets(rew, next_obs, done, agents=agents))  # [A, K*S]
    x = joint_input(obs, act)  # [(B,) K*S, in]
    return x.reshape(-1, k_n, s_n, x.shape[-1]).expand(a_n, -1, -1, -1), y.reshape(a_n, k_n, s_n)


def cross_validated_difficulty(e: ArrayLike, fold: ArrayLike, reduce: str = "sum") -> np.ndarray:
    """c_{a,j} = sum (or mean) over teachers i != f(j) of e_{a,j,i} (eq. 11, mask M[j,i] = 1[f(j) != i]).

    e float32[A, M, K] (teacher errors), fold int64[M] (0..K-1) -> c float32[A, M].
    """
    e_t = as_tensor(e)
    k = e_t.shape[-1]
    mask = as_tensor(fold, torch.int64).unsqueeze(1) != torch.arange(k).unsqueeze(0)  # [M, K]
    c = (e_t * mask).sum(-1)
    if reduce == "mean":
        c = c / max(k - 1, 1)
    elif reduce != "sum":
        raise ValueError(f"reduce must be 'sum' or 'mean', got {reduce!r}")
    return c.numpy()


class TeacherEnsemble:
    """A x K teacher critics (2 hidden ReLU layers, scalar output), trained online on their own folds.

    Args:
        num_agents: A, agents that use teachers (ACL/CMCL agents).
        in_dim: teacher input width = N*(obs_dim + act_dim).
        num_folds: K.  hidden: hidden width (int) or widths.  lr: Adam rate (= critic lr, A13).
        grad_clip: optional per-teacher gradient-norm clip (None: none; §3.2 specifies plain Adam).
        chunk_size: rows per forward pass in :meth:`errors` (bounds memory at A*K*chunk*hidden floats).
        seed: initial weights (every teacher independently initialised).
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
    ):
        self.num_agents, self.num_folds, self.in_dim = int(num_agents), int(num_folds), int(in_dim)
        self.grad_clip, self.chunk_size = grad_clip, int(chunk_size)
        widths = (hidden, hidden) if isinstance(hidden, int) else tuple(hidden)
        self.net = StackedMLP(self.num_agents * self.num_folds, self.in_dim, widths, 1, seed=seed)
        self.opt = make_adam(self.net.parameters(), lr)
        self.steps = 0

    def fit_step(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """One Adam step for every teacher on its own fold batch.

        x float32[A, K, S_T, in_dim], y float32[A, K, S_T] -> pre-step MSE loss float32[A, K].
        """
        x_t, y_t = as_tensor(x), as_tensor(y)
        a_n, k_n, s_n, _ = x_t.shape
        if (a_n, k_n) != (self.num_agents, self.num_folds):
            raise ValueError(f"x must be [A={self.num_agents}, K={self.num_folds}, S, in], got {tuple(x_t.shape)}")
        pred = self.net(x_t.reshape(a_n * k_n, s_n, -1)).squeeze(-1)  # [A*K, S]
        loss = (pred - y_t.reshape(a_n * k_n, s_n)).pow(2).mean(1)  # [A*K]
        self.opt.zero_grad(set_to_none=True)
        loss.sum().backward()
        if self.grad_clip is not None:
            clip_grad_norm_per_member_(self.net.parameters(), self.grad_clip)
        self.opt.step()
        self.steps += 1
        return loss.detach().reshape(a_n, k_n).numpy()

    @torch.no_grad()
    def predict(self, x: ArrayLike) -> np.ndarray:
        """Teacher outputs on shared rows: x float32[M, in_dim] -> float32[A, M, K] (chunked)."""
        x_t = as_tensor(x)
        parts = [self.net(x_t[s : s + self.chunk_size]).squeeze(-1) for s in range(0, x_t.shape[0], self.chunk_size)]
        p = torch.cat(parts, dim=1) if parts else torch.zeros(self.num_agents * self.num_folds, 0)  # [A*K, M]
        return p.reshape(self.num_agents, self.num_folds, -1).permute(0, 2, 1).contiguous().numpy()

    def errors(self, x: ArrayLike, y: ArrayLike, squared: bool = True) -> np.ndarray:
        """Per-teacher errors e_{a,j,i} = (y_{a,j} - T_{a,i}(x_j))^2 (or |.|): x [M, in_dim], y [A, M] -> [A, M, K]."""
        d = as_tensor(y).unsqueeze(-1) - torch.from_numpy(self.predict(x))
        return (d.pow(2) if squared else d.abs()).numpy()

    def difficulty(
        self, x: ArrayLike, y: ArrayLike, fold: ArrayLike, squared: bool = True, reduce: str = "sum"
    ) -> np.ndarray:
        """Convenience: :meth:`errors` then :func:`cross_validated_difficulty` -> c float32[A, M]."""
        return cross_validated_difficulty(self.errors(x, y, squared), fold, reduce)

    def state_dict(self) -> dict:
        """{"net": stacked teacher weights [A*K, in, out]/[A*K, out], "opt": Adam state, "steps": int}."""
        return {"net": self.net.state_dict(), "opt": self.opt.state_dict(), "steps": int(self.steps)}

    def load_state_dict(self, state: Mapping) -> None:
        """Restore :meth:`state_dict` output (same A, K, in_dim, hidden)."""
        self.net.load_state_dict(state["net"])
        self.opt.load_state_dict(state["opt"])
        self.steps = int(state["steps"])
