"""Records at the replay boundary: rollout chunks (checked before anything is stored) and replay-log events.

Where it sits: `services.roles.replay_server.ReplayServer.insert` runs `check_chunk` on every `Chunk` (a bad chunk is
refused as a unit, naming the field and the value; nothing is half-applied); `encode_chunk` / `encode_event` are
the payloads of the durable replay log (`cmcl.io.durable`), read back by `decode_log_record`. All payloads use
the envelope of `cmcl.io.codec` (dtype allow-list, size caps, no pickle).
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from cmcl.io.codec import DEFAULT_LIMITS, CodecError, Limits, decode, encode, unwrap
from cmcl.replay.messages import Chunk

CHUNK_ARRAYS = {"obs": ("float32", 3), "act": ("float32", 3), "rew": ("float32", 2), "next_obs": ("float32", 3),
                "done": ("float32", 2), "env_index": ("int64", 1)}  # Chunk field -> (dtype, dims)
CHUNK_MAX_ROWS = 1 << 20  # rows of one chunk (a worker's B worlds × episode length)
ACTION_BOUND = 1.0  # every action (continuous force or discrete probabilities) lies in [−1, 1]
EVENTS = ("updates", "teacher_steps", "icm_steps")  # replay-log events that move counters and rate limits


def _require_int(path: str, value) -> int:
    """value as an int >= 0 (Python or numpy integer), or CodecError naming `path`."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise CodecError(f"{path}: expected an integer >= 0, got {value!r}")
    return int(value)


def check_chunk(chunk, *, n_agents: int | None = None, obs_dim: int | None = None, act_dim: int | None = None,
                num_worlds: int | None = None, max_rows: int = CHUNK_MAX_ROWS) -> Chunk:
    """A rollout `Chunk` as the replay server accepts it, or CodecError naming the field and the value.

    Checks: exact dtypes (CHUNK_ARRAYS), shapes obs / next_obs [T, N, od], act [T, N, ad], rew [T, N], done
    [T, N] (per agent; or [T], one per row, as chunks had before per-agent termination) and env_index [T],
    T <= max_rows, finite floats, actions in [−1, 1] (ACTION_BOUND), done in {0, 1}, env_index in [0, num_worlds)
    (the worlds of one worker) when given, else >= 0, writer / seq / policy_version integers >= 0, incarnation a
    non-empty string, and N / od / ad equal to the expected sizes when given.
    """
    if not isinstance(chunk, Chunk):
        raise CodecError(f"chunk: expected a Chunk, got {type(chunk).__name__}")
    for key, (dtype, ndim) in CHUNK_ARRAYS.items():
        arr = getattr(chunk, key)
        dims = (1, 2) if key == "done" else (ndim,)
        if not isinstance(arr, np.ndarray) or arr.dtype.name != dtype or arr.ndim not in dims:
            got = f"{arr.dtype} with shape {arr.shape}" if isinstance(arr, np.ndarray) else type(arr).__name__
            raise CodecError(f"chunk.{key}: expected {dtype} with {ndim} dims, got {got}")
    t, n, od = chunk.obs.shape
    ad = chunk.act.shape[2]
    expected = {"next_obs": (t, n, od), "act": (t, n, ad), "rew": (t, n), "done": (t, n)[: chunk.done.ndim],
                "env_index": (t,)}
    for key, shape in expected.items():
        if getattr(chunk, key).shape != shape:
            raise CodecError(f"chunk.{key}: shape {getattr(chunk, key).shape} does not match {shape}")
    for name, want, got in (("n_agents", n_agents, n), ("obs_dim", obs_dim, od), ("act_dim", act_dim, ad)):
        if want is not None and want != got:
            raise CodecError(f"chunk {name}: the chunk has {got}, the buffer expects {want}")
    if t > max_rows:
        raise CodecError(f"chunk: {t} rows exceed the cap of {max_rows}")
    for key in ("obs", "act", "rew", "next_obs", "done"):
        arr = getattr(chunk, key)
        if not np.isfinite(arr).all():
            raise CodecError(f"chunk.{key}: must be finite, got {float(arr[~np.isfinite(arr)].ravel()[0])!r}")
    if t and chunk.env_index.min() < 0:
        raise CodecError(f"chunk.env_index: must be >= 0, got {int(chunk.env_index.min())}")
    if t and num_worlds is not None and chunk.env_index.max() >= num_worlds:
        raise CodecError(f"chunk.env_index: must be < {num_worlds} (env.num_envs), got {int(chunk.env_index.max())}")
    if t and np.abs(chunk.act).max() > ACTION_BOUND:
        raise CodecError(f"chunk.act: actions must lie in [-{ACTION_BOUND:g}, {ACTION_BOUND:g}], got "
                         f"{float(chunk.act.ravel()[np.abs(chunk.act).argmax()])!r}")
    if t and not np.isin(chunk.done, (0.0, 1.0)).all():
        raise CodecError(f"chunk.done: must be 0 or 1, got {float(chunk.done[~np.isin(chunk.done, (0.0, 1.0))][0])!r}")
    for key in ("writer", "seq", "policy_version"):
        _require_int(f"chunk.{key}", getattr(chunk, key))
    if not isinstance(chunk.incarnation, str) or not chunk.incarnation:
        raise CodecError(f"chunk.incarnation: expected a non-empty string, got {chunk.incarnation!r}")
    return chunk


def encode_chunk(chunk: Chunk) -> bytes:
    """A valid `Chunk` (see `check_chunk`) -> bytes, e.g. for a durable replay log."""
    check_chunk(chunk)
    return encode("chunk", {f.name: getattr(chunk, f.name) for f in fields(Chunk)})


def decode_chunk(data, *, limits: Limits = DEFAULT_LIMITS, **expected: int) -> Chunk:
    """bytes -> a validated `Chunk`; `expected` may give n_agents / obs_dim / act_dim / num_worlds (see
    `check_chunk`)."""
    return _chunk_from_body(decode(data, "chunk", limits=limits), **expected)


def _chunk_from_body(body, **expected: int) -> Chunk:
    """A decoded chunk body (exactly the Chunk fields; policy_version optional) -> a checked Chunk."""
    names = {f.name for f in fields(Chunk)}
    if not isinstance(body, dict) or set(body) - names or names - {"policy_version"} - set(body):
        got = sorted(body) if isinstance(body, dict) else type(body).__name__
        raise CodecError(f"chunk body: expected the fields {sorted(names)}, got {got}")
    return check_chunk(Chunk(**body), **expected)


def _check_event(body) -> dict:
    """A replay-log event {"name" in EVENTS, "count" int >= 0, "folds" [int >= 0]}, or CodecError."""
    if not isinstance(body, dict) or set(body) != {"name", "count", "folds"} or body["name"] not in EVENTS:
        raise CodecError(f"event: expected {{name in {EVENTS}, count, folds}}, got {body!r}")
    _require_int("event.count", body["count"])
    if not isinstance(body["folds"], list):
        raise CodecError(f"event.folds: expected a list, got {body['folds']!r}")
    for f in body["folds"]:
        _require_int("event.folds", f)
    return body


def encode_event(name: str, count: int, folds: list[int] | tuple[int, ...] = ()) -> bytes:
    """A replay-log event: `count` learner updates / teacher fit steps (of `folds`) / ICM fit steps handed out."""
    return encode("event", _check_event({"name": name, "count": int(count), "folds": [int(f) for f in folds]}))


def decode_log_record(data, *, limits: Limits = DEFAULT_LIMITS) -> Chunk | dict:
    """One replay-log payload -> a validated Chunk or event dict (CodecError otherwise)."""
    kind, body = unwrap(data, limits=limits)
    if kind == "event":
        return _check_event(body)
    if kind != "chunk":
        raise CodecError(f"a replay-log record must be a chunk or an event, got {kind!r}")
    return _chunk_from_body(body)
