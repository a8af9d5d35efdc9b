"""msgpack wire and disk format for transition chunks, score updates and snapshots (DESIGN.md "State and
recovery"; ALGORITHM.md §3.9).

Where it sits in the flow: rollout workers encode transition chunks, teachers / ICM encode score updates, the
replay server decodes both before touching its buffer and writes snapshots of its `state_dict()`; a restarted
server reads the snapshot back. Everything that crosses a boundary goes through `decode_*`, which validates
the whole payload before returning, so a bad payload is refused as a unit and nothing is half-applied.

Format: a msgpack map {"schema": SCHEMA_VERSION, "kind": "chunk" | "scores" | "snapshot", "body": ...}.
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
from dataclasses import dataclass

import msgpack
import numpy as np

from cmcl.io.atomic import atomic_write_bytes

SCHEMA_VERSION = 1
KINDS = ("chunk", "scores", "snapshot")
ALLOWED_DTYPES = {"float32": "<f4", "float64": "<f8", "int64": "<i8", "int32": "<i4",
                  "int8": "|i1", "uint8": "|u1", "bool": "|b1"}
_ND_EXT = 1
_MAX_NDIM = 32
CHUNK_ARRAYS = {"obs": "float32", "act": "float32", "rew": "float32", "next_obs": "float32",
                "done": "float32", "episode": "int64"}
SCORE_COLUMNS = ("difficulty", "curiosity", "td_abs")


class CodecError(ValueError):
    """Raised for any payload (or object to encode) that breaks the format; nothing was decoded."""


@dataclass(frozen=True)
class Limits:
    """Caps applied on decode: payload bytes, total array elements, nesting depth of dicts/lists."""

    max_bytes: int = 1 << 30
    max_elements: int = 1 << 28
    max_depth: int = 16


DEFAULT_LIMITS = Limits()


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
    if wire["kind"] != kind:
        raise CodecError(f"payload kind is {wire['kind']!r}, expected {kind!r}")
    return _from_wire(wire["body"], _Budget(limits), allow_nonfinite, 1, "body")


# ---------------------------------------------------------------------------------------------- schemas
def _require_array(body: dict, key: str, dtype: str, ndim: int) -> np.ndarray:
    arr = body.get(key)
    if not isinstance(arr, np.ndarray):
        raise CodecError(f"{key}: missing or not an array")
    if arr.dtype.name != dtype or arr.ndim != ndim:
        raise CodecError(f"{key}: expected {dtype} with {ndim} dims, got {arr.dtype} with shape {arr.shape}")
    return arr


def _require_int(body: dict, key: str, default=None) -> int:
    val = body.get(key, default)
    if type(val) is not int or val < 0:
        raise CodecError(f"{key}: expected an integer >= 0, got {val!r}")
    return val


def _check_chunk(body, n_agents, obs_dim, act_dim) -> dict:
    """Schema of a transition chunk (see `encode_chunk`); returns the body."""
    if not isinstance(body, dict):
        raise CodecError("chunk body must be a map")
    arrs = {k: _require_array(body, k, dt, {"obs": 3, "act": 3, "next_obs": 3, "rew": 2}.get(k, 1))
            for k, dt in CHUNK_ARRAYS.items()}
    t, n, od = arrs["obs"].shape
    ad = arrs["act"].shape[2]
    expected = {"obs": (t, n, od), "next_obs": (t, n, od), "act": (t, n, ad), "rew": (t, n), "done": (t,),
                "episode": (t,)}
    for k, shp in expected.items():
        if arrs[k].shape != shp:
            raise CodecError(f"{k}: shape {arrs[k].shape} does not match {shp}")
    for name, want, got in (("n_agents", n_agents, n), ("obs_dim", obs_dim, od), ("act_dim", act_dim, ad)):
        if want is not None and want != got:
            raise CodecError(f"{name}: chunk has {got}, expected {want}")
    if t and arrs["episode"].min() < 0:
        raise CodecError("episode: must be >= 0")
    _require_int(body, "policy_version", 0)
    _require_int(body, "seq", 0)
    if not isinstance(body.get("writer", ""), str):
        raise CodecError("writer: expected a string")
    return body


def encode_chunk(chunk: dict) -> bytes:
    """Transition chunk -> bytes. chunk: obs/next_obs float32[T,N,od], act float32[T,N,ad], rew float32[T,N],
    done float32[T], episode int64[T] (other numeric dtypes are cast), optional policy_version int,
    writer str, seq int (writer-side sequence number for idempotent ingest)."""
    body = {}
    for k, dt in CHUNK_ARRAYS.items():
        if k not in chunk:
            raise CodecError(f"{k}: missing")
        arr = np.asarray(chunk[k])
        if arr.dtype.kind not in "fiub":
            raise CodecError(f"{k}: dtype {arr.dtype} is not allowed")
        body[k] = arr.astype(dt)
    for k, default in (("policy_version", 0), ("writer", ""), ("seq", 0)):
        v = chunk.get(k, default)
        body[k] = v.item() if isinstance(v, np.generic) else v
    _check_chunk(body, None, None, None)
    return encode("chunk", body)


def decode_chunk(data, *, n_agents=None, obs_dim=None, act_dim=None, limits: Limits = DEFAULT_LIMITS) -> dict:
    """bytes -> validated chunk dict (exact dtypes, consistent shapes, finite, optional expected sizes)."""
    return _check_chunk(decode(data, "chunk", limits=limits), n_agents, obs_dim, act_dim)


def _check_scores(body) -> dict:
    """Schema of a score update (see `encode_scores`)."""
    if not isinstance(body, dict):
        raise CodecError("scores body must be a map")
    if body.get("column") not in SCORE_COLUMNS:
        raise CodecError(f"column: expected one of {SCORE_COLUMNS}, got {body.get('column')!r}")
    slots = _require_array(body, "slots", "int64", 1)
    gens = _require_array(body, "generations", "int64", 1)
    agents = _require_array(body, "agents", "int64", 1)
    values = _require_array(body, "values", "float32", 2)
    m = slots.shape[0]
    if gens.shape != (m,) or values.shape != (m, agents.shape[0]):
        raise CodecError(f"values {values.shape} / generations {gens.shape} do not match {m} slots "
                         f"and {agents.shape[0]} agents")
    if (m and (slots.min() < 0 or gens.min() < 0)) or (agents.size and agents.min() < 0):
        raise CodecError("slots, generations and agents must be >= 0")
    if values.size and values.min() < 0:
        raise CodecError("values: must be >= 0")
    _require_int(body, "model_version", 0)
    return body


def encode_scores(column: str, slots, generations, values, agents, model_version: int = 0) -> bytes:
    """Score update -> bytes. slots/generations int64[M], values float32[M, A], agents int64[A]."""
    body = {"column": column, "slots": np.asarray(slots, np.int64), "generations": np.asarray(generations, np.int64),
            "values": np.asarray(values, np.float32), "agents": np.asarray(agents, np.int64),
            "model_version": int(model_version)}
    _check_scores(body)
    return encode("scores", body)


def decode_scores(data, *, limits: Limits = DEFAULT_LIMITS) -> dict:
    """bytes -> validated score-update dict with the keys of `encode_scores`."""
    return _check_scores(decode(data, "scores", limits=limits))


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
