"""The MADDPG actor step's gradient by hand for per-agent stacked MLPs (ALGORITHM.md §2, eq. 4): the kernels autograd
runs for that step, in its order, without the autograd engine's bookkeeping (bit-identical, ~0.4 ms less per update).

Where it sits: :meth:`cmcl.learners.maddpg.MADDPG._actor_step` asks :func:`supports` and, when the networks allow it,
takes the loss and the actor's gradients from :func:`actor_loss_and_grads` instead of ``backward``; the clip and the
Adam step that follow are the same. The networks it allows: a per-agent :class:`~cmcl.learners.nets.StackedMLP`
actor with ReLU hidden layers and a tanh output, and such a critic with a linear output, every parameter per member
(no sharing); rows without absent agents, continuous actions without an action mask, no extra actor loss term.
Everything else takes autograd.
"""

from __future__ import annotations

import torch
from torch import nn

from cmcl.learners.nets import StackedMLP, joint_input

__all__ = ["actor_loss_and_grads", "supports"]


def _plain(net: nn.Module, out_act: type[nn.Module] | None) -> bool:
    """Whether `net` is a per-member (unshared) StackedMLP with ReLU hidden layers and output activation `out_act`."""
    return (isinstance(net, StackedMLP) and not net.share and isinstance(net.act, nn.ReLU)
            and (net.out_act is None if out_act is None else isinstance(net.out_act, out_act))
            and all(layer.weight.shape[0] == net.members and layer.bias.shape[0] == net.members
                    for layer in net.layers))


def supports(actor: nn.Module, critic: nn.Module) -> bool:
    """Whether :func:`actor_loss_and_grads` computes the actor step of these networks (module docstring)."""
    return _plain(actor, nn.Tanh) and _plain(critic, None)


@torch.no_grad()
def _forward(net: StackedMLP, x: torch.Tensor, last_act: bool) -> list[torch.Tensor]:
    """[x, h_1, ..., h_L]: the input and every layer's output after its activation (ReLU; tanh on the last if
    `last_act`), float32[N, B, width] each: the same ops as ``net(x)``."""
    outs = [x]
    last = len(net.layers) - 1
    for k, layer in enumerate(net.layers):
        h = torch.baddbmm(layer.bias.unsqueeze(1), outs[-1], layer.weight)
        outs.append(h.relu_() if k < last else (torch.tanh(h) if last_act else h))
    return outs


@torch.no_grad()
def _input_grad(net: StackedMLP, outs: list[torch.Tensor], grad: torch.Tensor,
                param_grads: list[torch.Tensor] | None) -> torch.Tensor:
    """Back through `net` from the gradient at its output (after the last activation's backward) to its input;
    with `param_grads` (a list) also every layer's weight and bias gradient, appended in parameter order."""
    grads: list[tuple[torch.Tensor, torch.Tensor]] = []
    for k in range(len(net.layers) - 1, -1, -1):
        layer = net.layers[k]
        if param_grads is not None:
            grads.append((torch.bmm(outs[k].transpose(1, 2), grad), grad.sum(1)))
        if k == 0 and param_grads is not None:
            break
        grad = torch.bmm(grad, layer.weight.transpose(1, 2))
        if k > 0:
            grad = torch.ops.aten.threshold_backward(grad, outs[k], 0)
    if param_grads is not None:
        for w, b in reversed(grads):
            param_grads += [w, b]
    return grad


@torch.no_grad()
def actor_loss_and_grads(actor: StackedMLP, critic: StackedMLP, obs: torch.Tensor, act: torch.Tensor,
                         own_obs: torch.Tensor, own_mask: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
    """Eq. 4's loss −mean_s Q_v(s, a_{−v}, π_v(o_v)) float32[N] and the gradient of its sum with respect to every actor
    parameter (in ``actor.parameters()`` order; each member's gradient is its own agent's).

    obs float32[N, S, N, obs_dim], act float32[N, S, N, act_dim] (owner v's rows), own_obs float32[N, S, obs_dim]
    (owner v's own observation), own_mask bool[N, 1, N, 1] (True at owner v's own action).
    """
    a_outs = _forward(actor, own_obs, last_act=True)
    pi = a_outs[-1]  # [N, S, act_dim]
    joint_act = torch.where(own_mask, pi.unsqueeze(2), act)  # [N, S, N, act_dim]
    c_outs = _forward(critic, joint_input(obs, joint_act), last_act=False)
    q = c_outs[-1].squeeze(-1)  # [N, S]
    loss = -q.mean(1)
    # d(sum_v loss_v)/dQ_v(s) = −1/S, as autograd's MeanBackward gives it
    grad_q = torch.full_like(c_outs[-1], -1.0).div_(q.shape[1])
    grad_x = _input_grad(critic, c_outs, grad_q, None)  # [N, S, in]
    n_obs = obs.shape[2] * obs.shape[3]
    grad_joint = grad_x[..., n_obs:].view(joint_act.shape)
    grad_pi = torch.where(own_mask, grad_joint, 0).sum(2)  # the where's and the unsqueeze's backward
    grad_pi = torch.ops.aten.tanh_backward(grad_pi, pi)
    grads: list[torch.Tensor] = []
    _input_grad(actor, a_outs, grad_pi, grads)
    return loss, grads
