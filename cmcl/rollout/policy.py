"""Numpy inference of the tanh actors: what rollout workers run, without loading torch.

Where it sits: rollout workers load the learner's published online actor (cmcl.learners.weights, "actor" part) with
`numpy_policy` and act with it. It computes exactly MADDPG.act for continuous actions (the actor's tanh output,
Gaussian noise, clip to [-1, 1]); parity tests tie the two. Two actors: `NumpyPolicy`, the stacked per-agent (or
shared) MLPs, and `NumpyEntityPolicy`, the entity actor of cmcl.learners.entity.nets (maddpg.networks = "entity"),
with maddpg.entity_nearest's selection of the nearest entities (`nearest_entities`) when k > 0 and
maddpg.entity_holder's holder margin of every landmark (`holder_margin`) as one more entity feature when set.
Keeping torch out of rollout workers (and the replay server) saves ~190 MB of private memory per process.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from cmcl.envs.entities import EntityLayout
from cmcl.learners.entity.holder_rules import SEATED_RADIUS, require_holder_rule

ENTITY_KEY = "encoder.entity.weight"  # present in the entity actor's weights only
# the holder margin of a landmark when no other agent is present (holder_margin): more than any margin a present
# agent leaves (|m| <= √2 ≈ 1.41, the arena's diagonal: the walls keep all in [-0.5, 0.5]^2), the viewer's alone
HOLDER_ALONE = 2.0


def _checked(weights: Mapping[str, np.ndarray], keys: list[str]) -> dict[str, np.ndarray]:
    """The named weights as contiguous finite float32 arrays; ValueError naming what is missing or non-finite."""
    missing = [k for k in keys if k not in weights]
    if missing:
        raise ValueError(f"actor weights lack {missing}, got {sorted(weights)}")
    out = {k: np.ascontiguousarray(weights[k], dtype=np.float32) for k in keys}
    if not all(np.isfinite(w).all() for w in out.values()):
        raise ValueError("actor weights must be finite")
    return out


class NumpyPolicy:
    """All agents' actors as stacked numpy weights: layers.k.weight float32[N, in, out], layers.k.bias [N, out]."""

    def __init__(self, weights: Mapping[str, np.ndarray], act_mask: np.ndarray | None = None):
        """act_mask: float32[N, act_dim] multiplied into every action (0 on padded entries), as MADDPG's."""
        self.act_mask = None if act_mask is None else np.asarray(act_mask, np.float32)
        count = len([k for k in weights if k.endswith(".weight")])
        if count < 1:
            raise ValueError(f"actor weights must hold layers.0..k.weight/.bias, got {sorted(weights)}")
        w = _checked(weights, [f"layers.{i}.{p}" for i in range(count) for p in ("weight", "bias")])
        self.weights = [w[f"layers.{i}.weight"] for i in range(count)]
        self.biases = [w[f"layers.{i}.bias"][:, None, :] for i in range(count)]

    def mean_action(self, obs: np.ndarray) -> np.ndarray:
        """obs float32[B, N, obs_dim] -> tanh(MLP(o)) float32[B, N, act_dim]."""
        x = np.ascontiguousarray(np.asarray(obs, dtype=np.float32).transpose(1, 0, 2))  # [N, B, obs_dim]
        x = _mlp(x, self.weights, self.biases)
        np.tanh(x, out=x)
        return x.transpose(1, 0, 2)

    def act(self, obs: np.ndarray, noise_std: float = 0.1, rng: np.random.Generator | None = None) -> np.ndarray:
        """obs float32[B, N, obs_dim] -> actions float32[B, N, act_dim] = clip(mean_action(o) + N(0, σ²), -1, 1)."""
        out = self.mean_action(obs)
        if noise_std > 0:
            rng = rng if rng is not None else np.random.default_rng()
            out = out + rng.normal(0.0, noise_std, size=out.shape).astype(np.float32)
        out = np.clip(out, -1.0, 1.0).astype(np.float32, copy=False)
        return out if self.act_mask is None else out * self.act_mask


def _mlp(x: np.ndarray, weights: list[np.ndarray], biases: list[np.ndarray]) -> np.ndarray:
    """ReLU MLP on stacked weights: x [G, R, in] @ w [G, in, out] + b [G, 1, out] per layer (no output activation)."""
    last = len(weights) - 1
    for i, (w, b) in enumerate(zip(weights, biases, strict=True)):
        x = np.matmul(x, w)
        x += b
        if i < last:
            np.maximum(x, 0.0, out=x)
    return x


def _masked_softmax(logits: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Softmax over the last axis of `logits` where `mask` (broadcast) holds; 0 elsewhere, and 0 for a row with
    nothing present."""
    logits = np.where(mask, logits, -np.inf)
    top = logits.max(-1, keepdims=True)
    weight = np.where(mask, np.exp(logits - np.where(np.isfinite(top), top, 0.0)), 0.0)
    return weight / np.maximum(weight.sum(-1, keepdims=True), np.finfo(np.float32).tiny)


def nearest_entities(entities: np.ndarray, mask: np.ndarray, k: int, types: slice) -> tuple[np.ndarray, np.ndarray]:
    """cmcl.learners.entity.nets.nearest_entities in numpy: the k nearest present entities of each kind, entities
    float32[..., E, F] (the first two features: the position relative to the agent; `types`: the type one-hot's
    columns), mask bool[..., E] -> float32[..., T·k', F], bool[..., T·k'] (k' = min(k, E)). Closest first within
    a kind, ties to the lower slot; a kind with fewer than k' present entities fills its picks with absent ones."""
    kinds = entities[..., types] > 0.5  # [..., E, T]
    dist = np.where(mask, np.square(entities[..., :2]).sum(-1), np.float32(np.inf))  # [..., E]
    dist = np.where(np.swapaxes(kinds, -1, -2), dist[..., None, :], np.float32(np.inf))  # [..., T, E]
    index = np.argsort(dist, axis=-1, kind="stable")[..., :min(int(k), entities.shape[-2])]  # [..., T, k']
    present = np.isfinite(np.take_along_axis(dist, index, -1))
    index = index.reshape(*index.shape[:-2], -1)
    return np.take_along_axis(entities, index[..., None], -2), present.reshape(index.shape)


def holder_margin(entities: np.ndarray, mask: np.ndarray, types: slice, rule: str = "nearest") -> np.ndarray:
    """cmcl.learners.entity.holder.holder_margin in numpy: for each present landmark l of a navigation view, entities
    float32[..., E, F'] (the first two features: r, the position relative to the viewing agent; `types`: the type
    one-hot's columns, landmark first, agent second), mask bool[..., E] -> float32[..., E, 1], m_l = min over the
    present agent entities j of ||r_j − r_l|| − ||r_l|| (< 0: another agent is closer to l than the viewer, it holds
    l; > 0: the viewer is the closest), HOLDER_ALONE with no agent entity present; 0 for agents and absent slots.
    rule "seated": an agent within SEATED_RADIUS of its nearest present landmark (the lowest slot on ties) counts
    for that landmark only (cmcl.learners.entity.holder)."""
    require_holder_rule(rule)
    pos = entities[..., :2]
    kinds = entities[..., types] > 0.5  # [..., E, T]
    landmark, agent = kinds[..., 0] & mask, kinds[..., 1] & mask  # [..., E]
    viewer = np.sqrt(np.square(pos).sum(-1))  # [..., E]: ||r_l||
    gap = np.sqrt(np.square(pos[..., :, None, :] - pos[..., None, :, :]).sum(-1))  # [..., E (l), E (j)]
    held = agent[..., None, :]  # [..., 1, E]
    if rule == "seated":  # an agent seated on one landmark holds no other
        to_landmarks = np.where(landmark[..., :, None], gap, np.float32(np.inf))  # [..., E (l), E (j)]
        first = to_landmarks.argmin(-2)[..., None, :]  # [..., 1, E]
        seated = to_landmarks.min(-2)[..., None, :] < SEATED_RADIUS
        held = held & (~seated | (np.arange(gap.shape[-2]).reshape(-1, 1) == first))
    nearest = np.where(held, gap, np.float32(np.inf)).min(-1)  # [..., E]
    margin = np.where(np.isfinite(nearest), nearest - viewer, np.float32(HOLDER_ALONE))
    return np.where(landmark, margin, np.float32(0.0)).astype(np.float32)[..., None]


class NumpyEntityPolicy(NumpyPolicy):
    """The entity actor (cmcl.learners.entity.nets.EntityActor) in numpy: one network for all agents; `nearest`
    k > 0 reads only the k nearest entities of each kind, as the learner's actor built with that k
    (maddpg.entity_nearest; the weights do not say it); `holder` appends every entity's holder margin
    (`holder_margin`, maddpg.entity_holder; navigation only) before the pick, as the learner's actor built with it
    (its entity layer then takes F + 1 inputs)."""

    def __init__(self, weights: Mapping[str, np.ndarray], layout: EntityLayout, act_mask: np.ndarray | None = None,
                 nearest: int = 0, holder: bool = False, holder_rule: str = "nearest"):
        self.act_mask = None if act_mask is None else np.asarray(act_mask, np.float32)
        self.holder_rule = require_holder_rule(holder_rule)
        self.layout = layout
        if int(nearest) < 0:
            raise ValueError(f"nearest must be >= 0 (0: every entity), got {nearest!r}")
        if holder and layout.type_names != ("landmark", "agent"):
            raise ValueError(f"the holder margin needs navigation's entities (landmark, agent), got "
                             f"{list(layout.type_names)}")
        raw = layout.entity_index.shape[2]
        self.nearest, self._type_cols = int(nearest), slice(raw, raw + len(layout.type_names))
        self.holder = bool(holder)
        heads = len([k for k in weights if k.startswith("head.layers.") and k.endswith(".weight")])
        self.attention = "encoder.query.weight" in weights  # maddpg.entity_pool = "attention" or "relational"
        self.relational = "encoder.relate_query.weight" in weights  # maddpg.entity_pool = "relational"
        parts = ("own", "entity", "query") if self.attention else ("own", "entity")
        parts += ("relate_query", "relate_key", "relate_out") if self.relational else ()
        names = [f"encoder.{part}.{p}" for part in parts for p in ("weight", "bias")]
        w = _checked(weights, names + [f"head.layers.{i}.{p}" for i in range(heads) for p in ("weight", "bias")])
        self.enc = {k.split(".")[1] + "." + k.split(".")[2]: v[0] for k, v in w.items() if k.startswith("encoder.")}
        self.weights = [w[f"head.layers.{i}.weight"] for i in range(heads)]
        self.biases = [w[f"head.layers.{i}.bias"][:, None, :] for i in range(heads)]
        self.hidden = self.enc["own.weight"].shape[1]
        width = layout.entity_dim + self.holder
        if self.enc["entity.weight"].shape[0] != width:
            raise ValueError(f"the entity layer takes {self.enc['entity.weight'].shape[0]} inputs, this layout "
                             f"{'with' if self.holder else 'without'} the holder margin gives {width} "
                             "(maddpg.entity_holder)")

    def _relate(self, h: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """EntityEncoder.relate: h float32[B, N, E, H], mask bool[B, N, E] -> the same shape."""
        e = self.enc
        q = h @ e["relate_query.weight"] + e["relate_query.bias"]  # [B, N, E, K]
        k = h @ e["relate_key.weight"] + e["relate_key.bias"]
        logits = np.matmul(q, np.swapaxes(k, -1, -2)) / np.float32(np.sqrt(q.shape[-1]))  # [B, N, E, E]
        beta = _masked_softmax(logits, mask[..., None, :])
        out = np.matmul(beta, h) @ e["relate_out.weight"] + e["relate_out.bias"]
        return h + np.maximum(out, 0.0)

    def mean_action(self, obs: np.ndarray, count: np.ndarray | None = None) -> np.ndarray:
        """obs float32[B, N, obs_dim] -> tanh(head(z)) float32[B, N, act_dim], z the encoder's [s, attention, mean]
        (or [s, mean]); count int64[B, N]: the present agents of each row (EntityActor's `count`; None: all N)."""
        own, ents, mask = self.layout.split(np.asarray(obs, dtype=np.float32))  # [B, N, S], [B, N, E, F], [B, N, E]
        if count is not None:
            mask = self.layout.present_mask(np.asarray(count, np.int64))
        if self.holder:  # every present agent counts, so before the pick
            ents = np.concatenate([ents, holder_margin(ents, mask, self._type_cols, self.holder_rule)], -1)
        if self.nearest:
            ents, mask = nearest_entities(ents, mask, self.nearest, self._type_cols)
        e = self.enc
        s = np.maximum(own @ e["own.weight"] + e["own.bias"], 0.0)  # [B, N, H]
        h = np.maximum(ents @ e["entity.weight"] + e["entity.bias"], 0.0)  # [B, N, E, H]
        if self.relational:
            h = self._relate(h, mask)
        count = mask.sum(-1, keepdims=True)
        mean = np.where(mask[..., None], h, 0.0).sum(-2) / np.maximum(count, 1)
        pools = [s, mean]
        if self.attention:
            q = (s @ e["query.weight"] + e["query.bias"]) / np.float32(np.sqrt(self.hidden))
            alpha = _masked_softmax(np.matmul(h, q[..., None])[..., 0], mask)  # [B, N, E]
            pools = [s, np.matmul(alpha[..., None, :], h)[..., 0, :], mean]  # [B, N, H] each
        z = np.concatenate(pools, -1).astype(np.float32)
        b, n = z.shape[:2]
        x = _mlp(z.reshape(1, b * n, -1), self.weights, self.biases)
        return np.tanh(x).reshape(b, n, -1)


def numpy_policy(weights: Mapping[str, np.ndarray], act_mask: np.ndarray | None = None,
                 entities: EntityLayout | None = None, nearest: int = 0, holder: bool = False,
                 holder_rule: str = "nearest") -> NumpyPolicy:
    """The numpy twin of a published actor: the entity actor when the weights are one (reading the `nearest`
    entities of each kind, maddpg.entity_nearest; 0: all; with the holder margin when `holder`,
    maddpg.entity_holder), else the stacked MLPs."""
    if ENTITY_KEY not in weights:
        if nearest:
            raise ValueError(f"nearest entities ({nearest!r}) need entity actor weights (maddpg.networks = 'entity')")
        if holder:
            raise ValueError("the holder margin needs entity actor weights (maddpg.networks = 'entity')")
        return NumpyPolicy(weights, act_mask)
    if entities is None:
        raise ValueError("entity actor weights need the task's entity layout (cmcl.envs.entities)")
    return NumpyEntityPolicy(weights, entities, act_mask, nearest, holder, holder_rule)
