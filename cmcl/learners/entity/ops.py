"""The entity networks' layers of one group as one fused GEMM + bias + ReLU kernel (docs/PERFORMANCE.md):
the numbers of StackedLinear + relu_ to float32's last bits (tests/test_entity_nets.py compares them).

Where it sits: cmcl.learners.entity.nets runs every layer through :func:`dense` (the heads through :func:`mlp`)
unless its encoder's ``fused`` is False. Only layers of one group (G = 1: the learner's entity actor and critic,
the entity ICM) take the fused kernel; the teachers' G = K groups keep StackedLinear.

:func:`dense` computes x @ W + b (then ReLU) as one oneDNN GEMM with the bias and the ReLU in its epilogue
(``torch.ops.mkldnn._linear_pointwise``, the kernel torch.compile's CPU fusion emits; F.linear + relu_ in a torch
build without it). StackedLinear's baddbmm first copies the broadcast bias into a fresh [rows, out] tensor, runs
MKL's GEMM over it and then a separate ReLU pass: at the entity layer ([rows·E, F] @ [F, H], F = 4 to 10; 122,880
rows in the target actor at N = 8) three passes over the largest tensor of the update where the fused kernel makes
one, and MKL's GEMM with so short an inner dimension is slow on this machine's AMD EPYC. The backward pass is
ReLU's threshold, two GEMMs and a sum, as autograd's.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

from cmcl.learners.nets import StackedLinear, StackedMLP

__all__ = ["dense", "mlp"]


@functools.cache
def _onednn() -> bool:
    """Whether this torch build has the fused oneDNN linear (+ ReLU) and it computes what F.linear does."""
    try:
        x, w = torch.arange(6.0).view(2, 3), torch.ones(4, 3)
        out = torch.ops.mkldnn._linear_pointwise(x, w, torch.full((4,), -3.5), "relu", [], "")
        return bool(torch.equal(out, F.linear(x, w, torch.full((4,), -3.5)).relu()))
    except (AttributeError, RuntimeError, NotImplementedError):
        return False


def _linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, relu: bool) -> torch.Tensor:
    """x float32[R, in], weight float32[in, out], bias float32[out] -> (relu of) x @ weight + bias [R, out]."""
    if _onednn():
        return torch.ops.mkldnn._linear_pointwise(x, weight.T, bias, "relu" if relu else "none", [], "")
    out = F.linear(x, weight.T, bias)
    return out.relu_() if relu else out


class _Dense(torch.autograd.Function):
    """:func:`_linear` with its gradient: x float32[R, in], weight float32[1, in, out] (StackedLinear's, one group),
    bias float32[1, out], relu bool -> float32[R, out]."""

    @staticmethod
    def forward(ctx, x, weight, bias, relu):
        out = _linear(x, weight[0], bias[0], relu)
        ctx.relu = relu
        ctx.save_for_backward(x, weight, out if relu else None)
        return out

    @staticmethod
    def backward(ctx, grad):
        x, weight, out = ctx.saved_tensors
        if ctx.relu:
            grad = torch.ops.aten.threshold_backward(grad, out, 0)  # as ReluBackward: 0 where the output is 0
        gx = grad @ weight[0].T if ctx.needs_input_grad[0] else None
        gw = (x.T @ grad).unsqueeze(0) if ctx.needs_input_grad[1] else None
        gb = grad.sum(0, keepdim=True) if ctx.needs_input_grad[2] else None
        return gx, gw, gb, None


def dense(layer: StackedLinear, x: torch.Tensor, relu: bool = False) -> torch.Tensor:
    """``layer(x)`` (then ReLU) for one group: x float32[1, R, in] -> float32[1, R, out]. Any other layer or
    input (G > 1 groups, a subset of members) runs StackedLinear as it is."""
    if layer.weight.shape[0] != 1 or layer.bias.shape[0] != 1 or x.dim() != 3 or x.shape[0] != 1:
        out = layer(x)
        return out.relu_() if relu else out
    flat = x[0].contiguous()
    grad = torch.is_grad_enabled() and (x.requires_grad or layer.weight.requires_grad or layer.bias.requires_grad)
    out = _Dense.apply(flat, layer.weight, layer.bias, relu) if grad else _linear(flat, layer.weight[0],
                                                                                 layer.bias[0], relu)
    return out.unsqueeze(0)


def mlp(net: StackedMLP, x: torch.Tensor, fused: bool = True) -> torch.Tensor:
    """``net(x)`` with every layer through :func:`dense` (its ReLUs fused): x float32[G, R, in] -> [G, R, out];
    fused False: ``net(x)`` itself."""
    if not fused:
        return net(x)
    relu, last = isinstance(net.act, torch.nn.ReLU), len(net.layers) - 1
    for k, layer in enumerate(net.layers):
        x = dense(layer, x, relu and k < last)
        if k < last and not relu:
            x = net.act(x)
    return net.out_act(x) if net.out_act is not None else x
