"""Validation and the msgpack wire / disk format of rollout chunks and snapshots (DESIGN.md "State and recovery";
ALGORITHM.md §3.9).

Where it sits in the flow: the replay server runs `check_chunk` on every rollout `Chunk` before touching its
buffer (a bad chunk is refused as a unit, naming the field and the value; nothing is half-applied);
`encode_chunk` / `decode_chunk` carry a chunk as bytes (for a durable replay log). The replay server and the
inline loop write snapshots of their `state_dict()` and a restarted one reads them back through `read_snapshot`,
which validates the whole payload before returning.

Format: a msgpack map {"schema": SCHEMA_VERSION, "kind": "chunk" | "snapshot", "body": ...}.
Values in a body: dict (str keys), list, str, int, float, bool, None, and numpy arrays. An array is a msgpack
ext (type 1) whose data is msgpack [dtype name, shape list, raw little-endian C-order bytes]; only the dtypes
in ALLOWED_DTYPES are accepted (no object arrays, no pickle anywhere). Decoded arrays are fresh, writable,
native-byte-order copies (np.frombuffer on the payload, then copied), never views of the input bytes.

Every failure raises `CodecError` (a ValueError): bad schema version or kind, unknown dtype, shape/byte-count
mismatch, non-finite float (unless allow_nonfinite), too many bytes / elements / nesting levels, garbage bytes.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, fields

import msgpack
import numpy as np

from cmcl.io.atomic import atomic_write_bytes
from cmcl.messages import Chunk

SCHEMA_VERSION = 1
KINDS = ("chunk", "event", "snapshot")
EVENTS = ("updates", "teacher_steps", "icm_steps")  # replay-log events that move counters and rate limits
ALLOWED_DTYPES = {"float32": "<f4", "float64": "<f8", "int64": "<i8", "int32": "<i4",
                  "int8": "|i1", "uint8": "|u1", "bool": "|b1"}
_ND_EXT = 1
_MAX_NDIM = 32
CHUNK_ARRAYS = {"obs": ("float32", 3), "act": ("float32", 3), "rew": ("float32", 2), "next_obs": ("float32", 3),
                "done": ("float32", 1), "env_index": ("int64", 1)}  # Chunk field -> (dtype, dims)
CHUNK_MAX_ROWS = 1 << 20  # rows of one chunk (a worker's B worlds × episode length)
ACTION_BOUND = 1.0  # every action (continuous force or discrete probabilities) lies in [−1, 1]


class CodecError(ValueError):
    """Raised for any payload (or object to encode) that breaks the format; nothing was decoded."""


@dataclass(frozen=True)
class Limits:
    """Caps applied on decode: payload bytes, total array elements, nesting depth of dicts/lists."""

    max_bytes: int = 1 << 30
    max_elements: int = 1 << 28
    max_depth: int = 16


DEFAULT_LIMITS = Limits()
SNAPSHOT_LIMITS = Limits(max_bytes=8 << 30, max_elements=2 << 30)  # replay snapshots: a 1M-slot buffer fits


# ---------------------------------------------------------------------------------------------- encoding
def _encode_array(arr: np.ndarray, allow_nonfinite: bool, path: str) -> msgpack.ExtType:
    """ndarray -> ext(1, packb([dtype name, shape, raw bytes]))."""
    name = arr.dtype.name
    if name not in ALLOWED_DTYPES:
        raise CodecError(f"{path}: dtype {arr.dtype} is not allowed (allowed: {sorted(ALLOWED_DTYPES)})")
    if arr.dtype.kind == "f" and not allow_nonfinite and not np.all(np.isfinite(arr)):
        raise CodecError(f"{path}: float array contains NaN or inf")
    raw = np.ascontiguousarray(arr, dtype=np.dtype(ALLOWED_DTYPES[name])).tobytes()
    return msgpack.ExtType(_ND_EXT, msgpack.packb([name, list(arr.shape), raw], use_bin_type=True))


def _check_float(value: float, allow_nonfinite: bool, path: str) -> float:
    """A float scalar, refused when not finite (unless allowed)."""
    if not allow_nonfinite and not math.isfinite(value):
        raise CodecError(f"{path}: float {value!r} is not finite")
    return value


def _to_wire(obj, allow_nonfinite: bool, path: str = "body"):
    """Convert a nested value to msgpack-native types, refusing anything outside the format."""
    if isinstance(obj, np.ndarray):
        return _encode_array(obj, allow_nonfinite, path)
    if isinstance(obj, np.generic):
        if obj.dtype.name not in ALLOWED_DTYPES:
            raise CodecError(f"{path}: numpy scalar of dtype {obj.dtype} is not allowed")
        obj = obj.item()
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, float):
        return _check_float(obj, allow_nonfinite, path)
    if isinstance(obj, dict):
        bad = [k for k in obj if not isinstance(k, str)]
        if bad:
            raise CodecError(f"{path}: dict keys must be str, got {bad[0]!r}")
        return {k: _to_wire(v, allow_nonfinite, f"{path}.{k}") for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_to_wire(v, allow_nonfinite, f"{path}[{i}]") for i, v in enumerate(obj)]
    raise CodecError(f"{path}: type {type(obj).__name__} is not allowed")


def encode(kind: str, body, *, allow_nonfinite: bool = False) -> bytes:
    """Envelope {"schema", "kind", "body"} packed with msgpack; CodecError on anything not encodable."""
    if kind not in KINDS:
        raise CodecError(f"kind must be one of {KINDS}, got {kind!r}")
    wire = {"schema": SCHEMA_VERSION, "kind": kind, "body": _to_wire(body, allow_nonfinite)}
    try:
        return msgpack.packb(wire, use_bin_type=True)
    except (OverflowError, ValueError, TypeError) as exc:
        raise CodecError(f"cannot encode: {exc}") from exc


# ---------------------------------------------------------------------------------------------- decoding
class _Budget:
    """Running count of decoded array elements against Limits.max_elements."""

    def __init__(self, limits: Limits) -> None:
        self.limits, self.elements = limits, 0

    def take(self, n: int, path: str) -> None:
        self.elements += n
        if self.elements > self.limits.max_elements:
            raise CodecError(f"{path}: payload exceeds {self.limits.max_elements} array elements")


def _decode_array(data: bytes, budget: _Budget, allow_nonfinite: bool, path: str) -> np.ndarray:
    """ext payload -> validated native ndarray copy."""
    try:
        head = msgpack.unpackb(data, raw=False, strict_map_key=True, max_array_len=_MAX_NDIM + 3)
    except Exception as exc:  # noqa: BLE001 - any unpack failure is a bad payload
        raise CodecError(f"{path}: malformed array: {exc}") from exc
    if not (isinstance(head, list) and len(head) == 3 and isinstance(head[0], str)
            and isinstance(head[1], list) and isinstance(head[2], bytes)):
        raise CodecError(f"{path}: array header must be [dtype, shape, bytes]")
    name, shape, raw = head
    if name not in ALLOWED_DTYPES:
        raise CodecError(f"{path}: dtype {name!r} is not allowed (allowed: {sorted(ALLOWED_DTYPES)})")
    if len(shape) > _MAX_NDIM or not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape):
        raise CodecError(f"{path}: bad shape {shape!r}")
    n = math.prod(shape)
    budget.take(n, path)
    dtype = np.dtype(ALLOWED_DTYPES[name])
    if len(raw) != n * dtype.itemsize:
        raise CodecError(f"{path}: {len(raw)} bytes do not match shape {tuple(shape)} of {name}")
    flat = np.frombuffer(raw, dtype=dtype)
    if name == "bool" and flat.size and flat.view(np.uint8).max() > 1:
        raise CodecError(f"{path}: bool array holds bytes other than 0/1")
    if dtype.kind == "f" and not allow_nonfinite and not np.all(np.isfinite(flat)):
        raise CodecError(f"{path}: float array contains NaN or inf")
    return flat.reshape(shape).astype(dtype.newbyteorder("="), copy=True)


def _from_wire(obj, budget: _Budget, allow_nonfinite: bool, depth: int, path: str):
    """Walk the unpacked tree: arrays decoded, types and depth checked."""
    if depth > budget.limits.max_depth:
        raise CodecError(f"{path}: nesting deeper than {budget.limits.max_depth}")
    if isinstance(obj, msgpack.ExtType):
        if obj.code != _ND_EXT:
            raise CodecError(f"{path}: unknown ext type {obj.code}")
        return _decode_array(obj.data, budget, allow_nonfinite, path)
    if obj is None or isinstance(obj, bool | int | str):
        return obj
    if isinstance(obj, float):
        return _check_float(obj, allow_nonfinite, path)
    if isinstance(obj, dict):
        if not all(isinstance(k, str) for k in obj):
            raise CodecError(f"{path}: dict keys must be str")
        return {k: _from_wire(v, budget, allow_nonfinite, depth + 1, f"{path}.{k}") for k, v in obj.items()}
    if isinstance(obj, list):
        budget.take(len(obj), path)
        return [_from_wire(v, budget, allow_nonfinite, depth + 1, f"{path}[{i}]") for i, v in enumerate(obj)]
    raise CodecError(f"{path}: type {type(obj).__name__} is not allowed")


def decode(data, kind: str, *, limits: Limits = DEFAULT_LIMITS, allow_nonfinite: bool = False):
    """bytes -> body of an envelope of `kind`, fully validated (CodecError otherwise)."""
    found, body = unwrap(data, limits=limits, allow_nonfinite=allow_nonfinite)
    if found != kind:
        raise CodecError(f"payload kind is {found!r}, expected {kind!r}")
    return body


def unwrap(data, *, limits: Limits = DEFAULT_LIMITS, allow_nonfinite: bool = False) -> tuple[str, object]:
    """bytes -> (kind, body) of an envelope of any kind, fully validated (CodecError otherwise)."""
    if not isinstance(data, bytes | bytearray | memoryview):
        raise CodecError(f"payload must be bytes, got {type(data).__name__}")
    size = memoryview(data).nbytes
    if size > limits.max_bytes:
        raise CodecError(f"payload of {size} bytes exceeds the limit of {limits.max_bytes}")
    cap = max(16, min(size, limits.max_elements))
    try:
        wire = msgpack.unpackb(bytes(data), raw=False, strict_map_key=True, max_array_len=cap, max_map_len=cap)
    except Exception as exc:  # noqa: BLE001 - garbage, truncation, stack depth: all are bad payloads
        raise CodecError(f"malformed payload: {type(exc).__name__}: {exc}") from exc
    if not isinstance(wire, dict) or set(wire) != {"schema", "kind", "body"}:
        raise CodecError("payload must be a map with exactly the keys schema, kind, body")
    if type(wire["schema"]) is not int or wire["schema"] != SCHEMA_VERSION:
        raise CodecError(f"schema version {wire['schema']!r} is not supported (expected {SCHEMA_VERSION})")
    if wire["kind"] not in KINDS:
        raise CodecError(f"payload kind {wire['kind']!r} is not one of {KINDS}")
    return wire["kind"], _from_wire(wire["body"], _Budget(limits), allow_nonfinite, 1, "body")


# ---------------------------------------------------------------------------------------------- schemas
def _require_int(path: str, value) -> int:
    """value as an int >= 0 (Python or numpy integer), or CodecError naming `path`."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
        raise CodecError(f"{path}: expected an integer >= 0, got {value!r}")
    return int(value)


def check_chunk(chunk, *, n_agents: int | None = None, obs_dim: int | None = None, act_dim: int | None = None,
                num_worlds: int | None = None, max_rows: int = CHUNK_MAX_ROWS) -> Chunk:
    """A rollout `Chunk` as the replay server accepts it, or CodecError naming the field and the value.

    Checks: exact dtypes (CHUNK_ARRAYS), shapes obs / next_obs [T, N, od], act [T, N, ad], rew [T, N], done and
    env_index [T], T <= max_rows, finite floats, actions in [−1, 1] (ACTION_BOUND), done in {0, 1}, env_index
    in [0, num_worlds) (the worlds of one worker) when given, else >= 0, writer / seq / policy_version integers
    >= 0, incarnation a non-empty string, and N / od / ad equal to the expected sizes when given.
    """
    if not isinstance(chunk, Chunk):
        raise CodecError(f"chunk: expected a Chunk, got {type(chunk).__name__}")
    for key, (dtype, ndim) in CHUNK_ARRAYS.items():
        arr = getattr(chunk, key)
        if not isinstance(arr, np.ndarray) or arr.dtype.name != dtype or arr.ndim != ndim:
            got = f"{arr.dtype} with shape {arr.shape}" if isinstance(arr, np.ndarray) else type(arr).__name__
            raise CodecError(f"chunk.{key}: expected {dtype} with {ndim} dims, got {got}")
    t, n, od = chunk.obs.shape
    ad = chunk.act.shape[2]
    expected = {"next_obs": (t, n, od), "act": (t, n, ad), "rew": (t, n), "done": (t,), "env_index": (t,)}
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


def encode_snapshot(obj: dict, *, allow_nonfinite: bool = False) -> bytes:
    """Nested dict (arrays, scalars, strings, lists) -> bytes, e.g. `ReplayBuffer.state_dict()`."""
    if not isinstance(obj, dict):
        raise CodecError("snapshot must be a dict")
    return encode("snapshot", obj, allow_nonfinite=allow_nonfinite)


def decode_snapshot(data, *, limits: Limits = DEFAULT_LIMITS, allow_nonfinite: bool = False) -> dict:
    """bytes -> nested dict; arrays are writable native copies."""
    body = decode(data, "snapshot", limits=limits, allow_nonfinite=allow_nonfinite)
    if not isinstance(body, dict):
        raise CodecError("snapshot body must be a map")
    return body


def write_snapshot_atomic(path: str | os.PathLike, obj: dict, *, allow_nonfinite: bool = False) -> int:
    """Encode `obj` and write it atomically: temp file in the same directory, fsync, os.replace, fsync dir.

    Returns the number of bytes written. A crash leaves either the old file or the new one, never a mix.
    """
    return atomic_write_bytes(path, encode_snapshot(obj, allow_nonfinite=allow_nonfinite))


def read_snapshot(path: str | os.PathLike, *, limits: Limits = DEFAULT_LIMITS, allow_nonfinite: bool = False) -> dict:
    """Read and decode a snapshot file; CodecError if it is larger than limits.max_bytes or malformed."""
    size = os.path.getsize(path)
    if size > limits.max_bytes:
        raise CodecError(f"{path}: {size} bytes exceeds the limit of {limits.max_bytes}")
    with open(path, "rb") as fh:
        data = fh.read(limits.max_bytes + 1)
    return decode_snapshot(data, limits=limits, allow_nonfinite=allow_nonfinite)
