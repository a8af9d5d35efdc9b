"""msgpack codec: round trips and refusal of every kind of bad payload (DESIGN.md "State and recovery")."""

import dataclasses
import os

import msgpack
import numpy as np
import pytest

from cmcl.io import codec, records
from cmcl.io.codec import CodecError, Limits
from cmcl.replay.messages import Chunk

T, N, OD, AD = 6, 2, 3, 2


def make_chunk(rng=None, **over):
    rng = rng or np.random.default_rng(0)
    fields = {"obs": rng.normal(size=(T, N, OD)).astype(np.float32),
              "act": rng.uniform(-1, 1, size=(T, N, AD)).astype(np.float32),
              "rew": rng.normal(size=(T, N)).astype(np.float32),
              "next_obs": rng.normal(size=(T, N, OD)).astype(np.float32), "done": np.zeros(T, np.float32),
              "env_index": np.arange(T, dtype=np.int64) % 3, "writer": 2, "incarnation": "5f0c", "seq": 17,
              "policy_version": 4}
    fields.update(over)
    return Chunk(**fields)


def raw_array(dtype_name, shape, raw):
    """An array ext built by hand (to forge bad headers)."""
    return msgpack.ExtType(1, msgpack.packb([dtype_name, shape, raw], use_bin_type=True))


def envelope(body, kind="snapshot", schema=codec.SCHEMA_VERSION):
    return msgpack.packb({"schema": schema, "kind": kind, "body": body}, use_bin_type=True)


def test_chunk_round_trip():
    c = make_chunk()
    out = records.decode_chunk(records.encode_chunk(c), n_agents=N, obs_dim=OD, act_dim=AD)
    for k in records.CHUNK_ARRAYS:
        assert getattr(out, k).dtype == getattr(c, k).dtype and np.array_equal(getattr(out, k), getattr(c, k))
        assert getattr(out, k).flags.writeable and getattr(out, k).flags.owndata
    assert (out.writer, out.incarnation, out.seq, out.policy_version) == (2, "5f0c", 17, 4)
    assert (out.rows, out.worlds, out.writer_key) == (T, 3, "2:5f0c")


def test_a_chunk_carries_done_per_agent_or_one_per_row():
    per_agent = (np.arange(T * N).reshape(T, N) % 2).astype(np.float32)
    for done in (per_agent, per_agent[:, 0]):  # [T, N], or [T] as every chunk had before per-agent termination
        out = records.decode_chunk(records.encode_chunk(make_chunk(done=done)), n_agents=N)
        assert np.array_equal(out.done, done)


def test_chunk_dtypes_are_exact_on_both_sides():
    with pytest.raises(CodecError, match=r"chunk.obs: expected float32 with 3 dims, got float64"):
        records.encode_chunk(make_chunk(obs=np.zeros((T, N, OD))))
    body = {f.name: getattr(make_chunk(), f.name) for f in dataclasses.fields(Chunk)}
    body["obs"] = body["obs"].astype(np.float64)  # forged: wrong dtype on the wire
    with pytest.raises(CodecError, match="chunk.obs: expected float32"):
        records.decode_chunk(codec.encode("chunk", body))
    body["obs"], body["extra"] = body["obs"].astype(np.float32), 1
    with pytest.raises(CodecError, match="expected the fields"):
        records.decode_chunk(codec.encode("chunk", body))


@pytest.mark.parametrize("over, match", [
    ({"rew": np.zeros((T, N + 1), np.float32)}, r"chunk.rew: shape"),
    ({"done": np.zeros(T + 1, np.float32)}, r"chunk.done: shape"),
    ({"done": np.zeros((T, N + 1), np.float32)}, r"chunk.done: shape"),
    ({"done": np.zeros((T, N, 1), np.float32)}, r"chunk.done: expected float32 with 2 dims"),
    ({"env_index": -np.ones(T, np.int64)}, "chunk.env_index: must be >= 0, got -1"),
    ({"policy_version": -1}, "chunk.policy_version: expected an integer >= 0, got -1"),
    ({"writer": "rollout-0"}, "chunk.writer"),
    ({"incarnation": ""}, "chunk.incarnation"),
    ({"act": np.zeros((T, N, AD), dtype=object)}, "chunk.act: expected float32"),
    ({"rew": np.full((T, N), np.inf, np.float32)}, "chunk.rew: must be finite, got inf"),
])
def test_chunk_schema_errors(over, match):
    with pytest.raises(CodecError, match=match):
        records.check_chunk(make_chunk(**over))
    with pytest.raises(CodecError, match=match):
        records.encode_chunk(make_chunk(**over))


def test_chunk_expected_sizes_and_caps():
    data = records.encode_chunk(make_chunk())
    with pytest.raises(CodecError, match="obs_dim: the chunk has 3, the buffer expects 4"):
        records.decode_chunk(data, obs_dim=OD + 1)
    with pytest.raises(CodecError, match="exceed the cap"):
        records.check_chunk(make_chunk(), max_rows=T - 1)
    with pytest.raises(CodecError, match="expected a Chunk, got dict"):
        records.check_chunk({"obs": 1})
    with pytest.raises(CodecError, match="kind"):
        codec.decode_snapshot(data)


def test_snapshot_round_trip_all_dtypes():
    obj = {"a": {name: np.arange(6).reshape(2, 3).astype(name) for name in codec.ALLOWED_DTYPES},
           "s": "text", "i": -3, "f": 0.25, "b": True, "none": None, "l": [1, "x", np.float64(2.5)],
           "scalar": np.int64(7), "empty": np.zeros((0, 4), np.float32)}
    out = codec.decode_snapshot(codec.encode_snapshot(obj))
    for name, arr in obj["a"].items():
        assert out["a"][name].dtype == arr.dtype and np.array_equal(out["a"][name], arr)
    assert out["empty"].shape == (0, 4)
    assert (out["s"], out["i"], out["f"], out["b"], out["none"], out["l"], out["scalar"]) == \
        ("text", -3, 0.25, True, None, [1, "x", 2.5], 7)


def test_big_endian_and_non_contiguous_inputs():
    a = np.arange(12, dtype=">f4").reshape(3, 4)[:, ::2]
    out = codec.decode_snapshot(codec.encode_snapshot({"a": a}))["a"]
    assert out.dtype == np.float32 and np.array_equal(out, a)


@pytest.mark.parametrize("value, match", [
    (np.array([object(), 1], dtype=object), "dtype object"),
    (np.zeros(3, np.float16), "dtype float16"),
    (np.zeros(2, np.complex128), "dtype complex128"),
    (np.array(["a", "b"]), "dtype <U1"),
    (b"raw bytes", "type bytes"),
    ({1: 2}, "keys must be str"),
    (np.array([1.0, np.nan]), "NaN"),
    (float("inf"), "not finite"),
    (2**70, "cannot encode"),
])
def test_encode_refuses(value, match):
    with pytest.raises(CodecError, match=match):
        codec.encode_snapshot({"x": value})


def test_nonfinite_allowed_when_asked():
    data = codec.encode_snapshot({"x": np.array([np.nan, np.inf])}, allow_nonfinite=True)
    with pytest.raises(CodecError, match="NaN"):
        codec.decode_snapshot(data)
    out = codec.decode_snapshot(data, allow_nonfinite=True)
    assert np.isnan(out["x"][0]) and np.isinf(out["x"][1])


@pytest.mark.parametrize("body, match", [
    ({"x": raw_array("complex128", [1], b"\0" * 16)}, "dtype 'complex128' is not allowed"),
    ({"x": raw_array("object", [1], b"\0" * 8)}, "dtype 'object' is not allowed"),
    ({"x": raw_array("float32", [3, 4], b"\0" * 40)}, r"40 bytes do not match shape \(3, 4\)"),
    ({"x": raw_array("float32", [-1], b"")}, "bad shape"),
    ({"x": raw_array("bool", [2], b"\x01\x02")}, "bool array"),
    ({"x": msgpack.ExtType(1, b"\xc1garbage")}, "malformed array"),
    ({"x": msgpack.ExtType(7, b"")}, "unknown ext type 7"),
    ({"x": raw_array("float64", [1], np.array([np.nan]).tobytes())}, "NaN"),
])
def test_decode_refuses_forged_arrays(body, match):
    with pytest.raises(CodecError, match=match):
        codec.decode_snapshot(envelope(body))


def test_bad_envelopes():
    good = codec.encode_snapshot({"a": 1})
    with pytest.raises(CodecError, match="schema version 2"):
        codec.decode_snapshot(envelope({"a": 1}, schema=2))
    with pytest.raises(CodecError, match="schema version True"):
        codec.decode_snapshot(envelope({"a": 1}, schema=True))
    with pytest.raises(CodecError, match="exactly the keys"):
        codec.decode_snapshot(msgpack.packb({"schema": 1, "kind": "snapshot", "body": {}, "x": 1}))
    with pytest.raises(CodecError, match="kind is 'chunk'"):
        codec.decode_snapshot(envelope({}, kind="chunk"))
    for bad in (good[:-3], good[:5], b"", b"\xc1\xc1\xc1", good + b"\x00", os.urandom(64)):
        with pytest.raises(CodecError):
            codec.decode_snapshot(bad)
    with pytest.raises(CodecError, match="payload must be bytes"):
        codec.decode_snapshot("not bytes")


def test_size_caps():
    data = codec.encode_snapshot({"x": np.zeros(1000, np.float32)})
    with pytest.raises(CodecError, match="exceeds the limit"):
        codec.decode_snapshot(data, limits=Limits(max_bytes=1000))
    with pytest.raises(CodecError, match="array elements"):
        codec.decode_snapshot(data, limits=Limits(max_elements=999))
    deep = {"x": 1}
    for _ in range(20):
        deep = {"d": deep}
    with pytest.raises(CodecError, match="nesting deeper"):
        codec.decode_snapshot(codec.encode_snapshot(deep))
    fake_len = envelope({"x": []})[:-1] + b"\xdd\xff\xff\xff\xff"  # array claiming 2**32-1 items
    with pytest.raises(CodecError):
        codec.decode_snapshot(fake_len)
    assert codec.decode_snapshot(data, limits=Limits(max_elements=1000))["x"].size == 1000


def test_atomic_write_and_read(tmp_path):
    path = tmp_path / "replay.msgpack"
    n = codec.write_snapshot_atomic(path, {"v": np.arange(5), "tag": "one"})
    assert n == path.stat().st_size
    codec.write_snapshot_atomic(path, {"v": np.arange(3), "tag": "two"})
    out = codec.read_snapshot(path)
    assert out["tag"] == "two" and out["v"].tolist() == [0, 1, 2]
    with pytest.raises(CodecError):
        codec.write_snapshot_atomic(path, {"v": np.array([np.nan])})
    assert codec.read_snapshot(path)["tag"] == "two"  # failed write left the old file intact
    assert sorted(os.listdir(tmp_path)) == ["replay.msgpack"]  # no temp files left behind
    with pytest.raises(CodecError, match="exceeds"):
        codec.read_snapshot(path, limits=Limits(max_bytes=10))
    path.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(CodecError):
        codec.read_snapshot(path)
