"""The msgpack wire and disk format: envelopes of chunks, replay-log events and snapshots (DESIGN.md "State and
recovery"; ALGORITHM.md §3.9).

Where it sits in the flow: `cmcl.io.records` builds chunk and event payloads on it (and checks every chunk at the
replay boundary); the replay server and the inline loop write snapshots of their `state_dict()`, and a restarted
one reads them back through `read_snapshot` / `decode_snapshot`, which validate the whole payload before
returning.

Format: a msgpack map {"schema": SCHEMA_VERSION, "kind": one of KINDS, "body": ...}.
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
KINDS = ("chunk", "event", "snapshot")
ALLOWED_DTYPES = {"float32": "<f4", "float64": "<f8", "int64": "<i8", "int32": "<i4",
                  "int8": "|i1", "uint8": "|u1", "bool": "|b1"}
_ND_EXT = 1
_MAX_NDIM = 32


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
