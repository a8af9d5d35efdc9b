"""Stacked (ensemble) MLPs: many independent small MLPs run as one batched matmul per layer.

Where it sits in the flow: the building block of ``maddpg.py`` (member = agent: actors, critics and their
targets), ``teachers.py`` (member = (agent, fold) teacher critic) and ``icm.py`` (member = agent: encoder,
inverse and forward models). Every parameter carries a leading *member* axis, so one optimiser and one kernel
per layer serve all members, while members never share weights or gradients (the per-member loss terms are
summed before ``backward``; the gradient of member m only depends on member m's loss).

Shapes: a stacked layer holds ``weight float32[members, in, out]`` and ``bias float32[members, out]``.
``StackedMLP`` maps ``[members, B, in] -> [members, B, out]``; a 2-D input ``[B, in]`` is shared by all members.

Parameter sharing (``StackedMLP(share=True)``): every layer holds ONE weight ``[1, in, out]`` and, past the first
layer, one bias ``[1, out]``, broadcast to all members; only the first layer's bias stays per member. That bias is
exactly a learned agent-id embedding (W·[x; onehot(m)] = W_x·x + b_m), so members share one network yet can still
tell who they are. The member count then barely changes the parameter count (N·hidden extra), which is the
point at N = 8 or 16 (the scale study).

Grouped sharing (``StackedMLP(share=True, share_groups=G)``): G networks instead of one; member m uses network
``m % G``. With the teachers' layout (member ``a*K + i`` for agent a and fold i) and G = K, each fold keeps its own
network, shared by every agent, so the K-fold cross-validation stays intact (a fold's network never sees the other
folds' rows). Shared parameters then carry a leading axis of G, and G = 1 is the plain sharing above.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence

import numpy as np
import torch
from torch import nn

__all__ = [
    "StackedLinear",
    "adam_step_",
    "drop_grads_",
    "make_adam",
    "StackedMLP",
    "as_tensor",
    "clip_grad_norm_per_member_",
    "hard_update_",
    "joint_input",
    "soft_update_",
]


def make_adam(params: Iterable[torch.Tensor], lr: float) -> torch.optim.Adam:
    """Adam over (stacked) parameters; the fused CPU kernel when available (~3x faster step, same algorithm).

    Adam is elementwise, so one Adam over stacked [members, ...] parameters equals one Adam per member.
    """
    params = list(params)
    try:
        return torch.optim.Adam(params, lr=lr, fused=True)
    except (RuntimeError, TypeError):  # older torch without fused CPU Adam
        return torch.optim.Adam(params, lr=lr)


def adam_step_(opt: torch.optim.Adam) -> None:
    """``opt.step()`` with the same arithmetic and the same state, without torch.optim's per-step Python overhead.

    Once every parameter with a gradient has its Adam state (the first step, taken by ``opt.step()``, made it), a
    fused Adam of one parameter group is its two kernels: step counts + 1 (``torch._foreach_add_``), then
    ``torch._fused_adam_`` over every (parameter, grad, exp_avg, exp_avg_sq) — exactly what ``opt.step()`` runs
    (torch.optim.adam._fused_adam), so the updates are bit-identical and ``opt.state_dict()`` is unchanged. Any
    other optimiser state (no fused kernel, several groups, amsgrad, decoupled decay, grad scaling, step hooks)
    takes ``opt.step()`` itself.
    """
    group = opt.param_groups[0]
    if (len(opt.param_groups) != 1 or not group.get("fused") or group["amsgrad"] or group["decoupled_weight_decay"]
            or getattr(opt, "grad_scale", None) is not None or getattr(opt, "found_inf", None) is not None
            or opt._optimizer_step_pre_hooks or opt._optimizer_step_post_hooks):
        opt.step()
        return
    params = [p for p in group["params"] if p.grad is not None]
    states = [opt.state.get(p) for p in params]
    if not params or not all(states):
        opt.step()
        return
    steps = [st["step"] for st in states]
    torch._foreach_add_(steps, 1)
    beta1, beta2 = group["betas"]
    torch._fused_adam_(params, [p.grad for p in params], [st["exp_avg"] for st in states],
                       [st["exp_avg_sq"] for st in states], [], steps, amsgrad=False, lr=group["lr"], beta1=beta1,
                       beta2=beta2, weight_decay=group["weight_decay"], eps=group["eps"], maximize=group["maximize"],
                       grad_scale=None, found_inf=None)


def drop_grads_(params: Iterable[torch.Tensor]) -> None:
    """Every parameter's gradient set to None: ``opt.zero_grad(set_to_none=True)`` over them, without its overhead."""
    for p in params:
        p.grad = None


def as_tensor(x: np.ndarray | torch.Tensor, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Numpy array or tensor -> CPU tensor of ``dtype`` (zero-copy for float32 numpy)."""
    return torch.as_tensor(x, dtype=dtype)


def joint_input(obs: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
    """Centralized-critic input: all observations then all actions, flattened.

    obs float32[..., N, obs_dim], act float32[..., N, act_dim] -> float32[..., N*obs_dim + N*act_dim].
    """
    return torch.cat([obs.flatten(-2), act.flatten(-2)], dim=-1)


class StackedLinear(nn.Module):
    """``members`` independent ``nn.Linear(in_dim, out_dim)`` layers as one batched matmul.

    Init matches ``nn.Linear``'s default per member: weight and bias ~ U(-1/sqrt(in_dim), 1/sqrt(in_dim))
    (kaiming_uniform with a=sqrt(5) reduces to this bound), drawn independently for every member.
    """

    def __init__(self, members: int, in_dim: int, out_dim: int, generator: torch.Generator | None = None,
                 shared_weight: bool = False, shared_bias: bool = False, groups: int = 1):
        super().__init__()
        if groups < 1 or members % groups:
            raise ValueError(f"groups must divide members={members}, got {groups}")
        self.members, self.in_dim, self.out_dim = members, in_dim, out_dim
        bound = 1.0 / math.sqrt(in_dim) if in_dim > 0 else 0.0
        w = torch.empty(groups if shared_weight else members, in_dim, out_dim).uniform_(-bound, bound,
                                                                                        generator=generator)
        b = torch.empty(groups if shared_bias else members, out_dim).uniform_(-bound, bound, generator=generator)
        self.weight = nn.Parameter(w)  # [members, in, out], or [groups, in, out] when shared
        self.bias = nn.Parameter(b)  # [members, out], or [groups, out] when shared

    def forward(self, x: torch.Tensor, members: torch.Tensor | None = None) -> torch.Tensor:
        """x [m, B, in] (or shared [B, in]) -> [m, B, out]; ``members`` (int64[m]) selects a subset of members.
        A shared weight or bias ([1, ...]) is broadcast to every member; one of G > 1 groups is tiled so that
        member j uses group j % G. With G groups, x may also be one input per group [G, B, in] (every member of
        group g reads x[g]) or shared [B, in]: the matmul then runs once per group, not once per member."""
        w, b = self.weight, self.bias
        groups = w.shape[0]
        if members is None and 1 < groups < self.members and (x.dim() == 2 or x.shape[0] == groups):
            per_group = torch.matmul(x, w)  # [G, B, out]: the members of a group share weight and input
            return self._tiled(per_group) + self._tiled(b).unsqueeze(1)
        w, b = self._tiled(w), self._tiled(b)  # [members, in, out], [members, out]; gradients sum into the groups
        m = (self.members if members is None else len(members)) if x.dim() == 2 else x.shape[0]
        if members is not None:
            w = w if w.shape[0] == 1 else w[members]
            b = b if b.shape[0] == 1 else b[members]
        if x.dim() == 2 and w.shape[0] == m and b.shape[0] == m and not x.requires_grad:
            # shared rows (data, not a graph's output), per-member weights: one baddbmm on a view, the same numbers
            # as matmul's, which would copy x m times and add the bias in another pass
            x = x.expand(m, *x.shape)
        if x.dim() == 3 and w.shape[0] == x.shape[0] and b.shape[0] == x.shape[0]:
            return torch.baddbmm(b.unsqueeze(1), x, w)
        out = torch.matmul(x, w) + b.unsqueeze(1)  # [B, in] or [m, B, in] @ [m or 1, in, out]
        return out.expand(m, *out.shape[1:]) if out.shape[0] != m else out

    def _tiled(self, grouped: torch.Tensor) -> torch.Tensor:
        """A per-group tensor [G, ...] with 1 < G < members tiled to [members, ...] (member j gets group j % G);
        a per-member or a single shared ([1, ...], broadcast) tensor is returned as it is."""
        groups = grouped.shape[0]
        if 1 < groups < self.members:
            return grouped.repeat(self.members // groups, *([1] * (grouped.dim() - 1)))
        return grouped

    def extra_repr(self) -> str:
        return f"members={self.members}, in_dim={self.in_dim}, out_dim={self.out_dim}"


def _make_act(act: Callable[[], nn.Module] | nn.Module | None) -> nn.Module | None:
    """Instantiate an activation given as a module class/factory (``nn.ReLU``) or a module instance.

    ``nn.ReLU`` becomes ``nn.ReLU(inplace=True)``: it only ever follows a fresh matmul output (saves an allocation).
    """
    if act is None or isinstance(act, nn.Module):
        return act
    if act is nn.ReLU:
        return nn.ReLU(inplace=True)
    return act()


class StackedMLP(nn.Module):
    """``members`` independent MLPs ``in_dim -> hidden... -> out_dim`` evaluated together.

    Args:
        members: number of independent networks (agents, or agents x folds).
        in_dim, out_dim: input / output width.
        hidden: hidden widths, e.g. (64, 64) (an int means one hidden layer).
        activation: hidden activation, a module class such as ``nn.ReLU``.
        out_act: output activation (``nn.Tanh`` for actors) or None.
        seed / generator: source of the initial weights (a generator wins over a seed).
        share: one network for all members, with a per-member first-layer bias (module docstring).
        share_groups: with ``share``, G networks, member m using network m % G (module docstring).
    """

    def __init__(
        self,
        members: int,
        in_dim: int,
        hidden: Sequence[int] | int = (64, 64),
        out_dim: int = 1,
        activation: Callable[[], nn.Module] | nn.Module = nn.ReLU,
        out_act: Callable[[], nn.Module] | nn.Module | None = None,
        seed: int | None = None,
        generator: torch.Generator | None = None,
        share: bool = False,
        share_groups: int = 1,
    ):
        super().__init__()
        if generator is None and seed is not None:
            generator = torch.Generator().manual_seed(int(seed))
        widths = [in_dim, *([hidden] if isinstance(hidden, int) else list(hidden)), out_dim]
        self.members, self.in_dim, self.out_dim, self.share = members, in_dim, out_dim, bool(share)
        self.layers = nn.ModuleList(
            StackedLinear(members, a, b, generator, shared_weight=self.share, shared_bias=self.share and k > 0,
                          groups=int(share_groups) if self.share else 1)
            for k, (a, b) in enumerate(zip(widths[:-1], widths[1:], strict=True))
        )
        self.act = _make_act(activation)
        self.out_act = _make_act(out_act)

    def forward(self, x: torch.Tensor, members: torch.Tensor | None = None) -> torch.Tensor:
        """x float32[m, B, in_dim] or shared [B, in_dim] -> float32[m, B, out_dim] (m = members or len(subset)).
        With ``share_groups`` G > 1, x may also be one input per group, float32[G, B, in_dim] (StackedLinear)."""
        last = len(self.layers) - 1
        for k, layer in enumerate(self.layers):
            x = layer(x, members)
            if k < last:
                x = self.act(x)
        return self.out_act(x) if self.out_act is not None else x

    def member_module(self, m: int) -> nn.Sequential:
        """A plain ``nn.Sequential`` copy of member ``m`` (tests and the loop baseline)."""
        mods: list[nn.Module] = []
        last = len(self.layers) - 1
        for k, layer in enumerate(self.layers):
            lin = nn.Linear(layer.in_dim, layer.out_dim)
            with torch.no_grad():
                lin.weight.copy_(layer.weight[m % layer.weight.shape[0]].T)
                lin.bias.copy_(layer.bias[m % layer.bias.shape[0]])
            mods.append(lin)
            if k < last:
                mods.append(type(self.act)())
        if self.out_act is not None:
            mods.append(type(self.out_act)())
        return nn.Sequential(*mods)


@torch.no_grad()
def soft_update_(target: nn.Module | Sequence[nn.Module], source: nn.Module | Sequence[nn.Module], tau: float) -> None:
    """Polyak update in place (eq. 6): theta' <- tau * theta + (1 - tau) * theta' for every (stacked) parameter;
    one module or matching sequences of modules (every pair's parameters in one ``torch._foreach_lerp_``)."""
    targets = [target] if isinstance(target, nn.Module) else list(target)
    sources = [source] if isinstance(source, nn.Module) else list(source)
    torch._foreach_lerp_([p for t in targets for p in t.parameters()], [p for s in sources for p in s.parameters()],
                         tau)


@torch.no_grad()
def hard_update_(target: nn.Module, source: nn.Module) -> None:
    """Copy every parameter of ``source`` into ``target`` (same architecture)."""
    for t, s in zip(target.parameters(), source.parameters(), strict=True):
        t.copy_(s)


@torch.no_grad()
def clip_grad_norm_per_member_(params: Iterable[torch.Tensor], max_norm: float, eps: float = 1e-6) -> torch.Tensor:
    """Clip each member's gradient L2 norm to ``max_norm`` separately (in place); returns pre-clip norms [members].

    Equivalent to calling ``torch.nn.utils.clip_grad_norm_(member_m_params, max_norm)`` for every member m:
    the norm of member m runs over slice m of every parameter's gradient, coef = min(1, max_norm/(norm+eps)).
    Every parameter must have the member axis first; parameters without a gradient are skipped. When some are
    shared (``StackedMLP(share=True)``, leading axis G < members), the members of each group (m % G) form one
    network: one norm per group over every gradient of that group is clipped, and returned once per member.
    """
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return torch.zeros(0)
    members, groups = max(g.shape[0] for g in grads), min(g.shape[0] for g in grads)
    # a gradient with leading axis L = r*G viewed as [r, G, -1]: slice [:, i] is everything of group i
    views = [g.view(g.shape[0] // groups, groups, -1) for g in grads]
    sq = torch.stack([s.sum((0, 2)) for s in torch._foreach_mul(views, views)]).sum(0)  # [G]; g·g is g.pow(2)
    norms = sq.sqrt()
    coef = (max_norm / (norms + eps)).clamp_(max=1.0).view(1, groups, 1)
    torch._foreach_mul_(views, [coef] * len(views))
    return norms if members == groups else norms.repeat(members // groups)
