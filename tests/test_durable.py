"""Exactly-once inserts, the durable replay store, and bad bytes at the chunk boundary."""

import dataclasses
import hashlib
import pickle
import re
import struct
from pathlib import Path

import msgpack
import numpy as np
import pytest

from cmcl.io import codec, records
from cmcl.io.durable import FRAME, LEGACY_MAGIC, ReplayStore, StoreError, frame, read_frames
from cmcl.replay.dedupe import InsertLedger
from cmcl.replay.messages import Chunk
from tests.test_codec import make_chunk

ROOT = Path(__file__).resolve().parents[1]


def test_ledger_accepts_each_seq_once_in_any_order_and_stays_bounded():
    ledger = InsertLedger()
    order = np.random.default_rng(0).permutation(100)
    assert all(ledger.accept("w:1", int(s)) for s in order)
    assert not any(ledger.accept("w:1", int(s)) for s in order), "every seq only once"
    assert ledger.watermark["w:1"] == 99 and not ledger.pending["w:1"]
    assert not ledger.seen("w:1", 100)
    bounded = InsertLedger(max_pending=8)
    assert bounded.accept("w:2", 0)
    for s in range(2, 12):  # seq 1 never arrives: the gap is given up once more than 8 seqs wait above it
        bounded.accept("w:2", s)
    assert bounded.gaps_given_up == 1 and len(bounded.pending["w:2"]) <= 8 and bounded.watermark["w:2"] == 11
    other = InsertLedger()
    other.load_state_dict(bounded.state_dict())
    assert other.state_dict() == bounded.state_dict()
    with pytest.raises(ValueError, match="above its watermark"):
        other.load_state_dict({"watermark": {"w": 5}, "pending": {"w": [3]}})
    with pytest.raises(ValueError, match="seq must be >= 0"):
        ledger.accept("w:3", -1)


def test_frames_round_trip_a_cut_drops_only_the_torn_frame_and_a_flip_loses_only_its_own_frame():
    payloads = [bytes([i]) * (10 + i) for i in range(5)]
    rows = [3, 0, 5, 7, 11]  # transitions per frame (0: an event)
    data = b"".join(frame(p, r) for p, r in zip(payloads, rows, strict=True))
    scan = read_frames(data)
    assert scan.frames == payloads and scan.problem is None and scan.spans[-1][1] == len(data)
    ends = np.cumsum([FRAME.size + len(p) for p in payloads])
    starts = ends - [FRAME.size + len(p) for p in payloads]
    for cut in range(len(data)):  # a crash can tear the log at any byte
        scan = read_frames(data[:cut])
        whole = int((ends <= cut).sum())
        assert scan.frames == payloads[:whole] and scan.lost_frames == 0 and scan.unknown_ranges == 0
        assert scan.torn_tail == (None if cut in (0, *ends) else starts[whole]), cut
    for pos in range(len(data)):  # a flipped bit anywhere loses the frame it hits, never another
        flipped = bytearray(data)
        flipped[pos] ^= 0x40
        scan = read_frames(bytes(flipped))
        hit = int((ends <= pos).sum())
        assert scan.frames == payloads[:hit] + payloads[hit + 1:], pos
        in_payload = pos >= starts[hit] + FRAME.size
        assert (scan.lost_frames, scan.lost_transitions, scan.unknown_ranges) == (
            (1, rows[hit], 0) if in_payload else (0, 0, 1)), pos
        assert scan.damaged == [(starts[hit], ends[hit])] and scan.torn_tail is None


def test_a_log_of_an_older_frame_format_is_refused_in_one_line_naming_it_and_the_last_commit():
    from cmcl.replay.snapshot import LAST_READER

    payloads = [bytes([i]) * 40 for i in range(2)]
    # the older frames: magic, payload bytes, SHA-256 (no transitions, no header CRC)
    legacy = [struct.pack("<4sQ32s", LEGACY_MAGIC, len(p), hashlib.sha256(p).digest()) + p for p in payloads]
    with pytest.raises(StoreError) as err:
        read_frames(b"".join(legacy) + frame(b"new", 2))
    assert str(err.value) == (f"replay log of frame format 'CMCL': written by an older version; commit {LAST_READER} "
                              "is the last that reads it")


def test_a_corrupt_frame_moves_the_log_aside_whole_and_keeps_every_good_frame(tmp_path):
    store = ReplayStore(tmp_path / "s")
    for i in range(5):
        store.append(bytes([i]) * 100, transitions=10 * (i + 1))
    store.close()
    log = tmp_path / "s" / "log-000000.bin"
    damaged = bytearray(log.read_bytes())
    damaged[2 * (FRAME.size + 100) + FRAME.size + 50] ^= 0xFF  # the payload of the third frame (30 transitions)
    log.write_bytes(bytes(damaged))
    state, frames, damage = ReplayStore(tmp_path / "s").load()
    assert state is None and frames == [bytes([i]) * 100 for i in (0, 1, 3, 4)]
    assert damage.copy == tmp_path / "s" / "log-000000.bin.damaged-1" and damage.copy.read_bytes() == damaged
    assert "1 corrupt frame(s) skipped (30 transitions lost)" in str(damage) and str(damage.copy) in str(damage)
    again = ReplayStore(tmp_path / "s")
    assert again.load()[1:] == (frames, None), "the new log holds exactly the good frames"
    again.append(b"after", 1)
    again.close()
    assert ReplayStore(tmp_path / "s").recover_log() is None and len(list((tmp_path / "s").glob("*.damaged-*"))) == 1


def test_store_snapshots_switch_atomically_and_missing_files_are_named(tmp_path):
    store = ReplayStore(tmp_path / "s")
    store.append(b"one")
    store.snapshot({"x": np.arange(3)})
    store.append(b"two")
    store.close()
    again = ReplayStore(tmp_path / "s")
    state, frames, damage = again.load()
    assert state["x"].tolist() == [0, 1, 2] and frames == [b"two"] and damage is None
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["log-000001.bin", "manifest.json",
                                                                  "snapshot-000001.msgpack"]
    (tmp_path / "s" / "snapshot-000001.msgpack").unlink()
    with pytest.raises(StoreError, match="snapshot-000001.msgpack: missing"):
        ReplayStore(tmp_path / "s").load()
    (tmp_path / "s" / "manifest.json").write_text("{not json")
    with pytest.raises(StoreError, match="manifest.json: unreadable"):
        ReplayStore(tmp_path / "s").load()


def test_random_bytes_truncations_bombs_and_pickles_are_refused_by_the_chunk_decoder():
    rng = np.random.default_rng(0)
    good = records.encode_chunk(make_chunk())
    refused, tried = np.zeros(4, int), np.zeros(4, int)
    for i in range(10_000):
        kind = i % 4
        if kind == 0:  # random bytes
            data = rng.bytes(int(rng.integers(0, 400)))
        elif kind == 1:  # a truncated good payload
            data = good[:int(rng.integers(0, len(good)))]
        elif kind == 2:  # random bit flips in a good payload
            flipped = bytearray(good)
            for pos in rng.integers(0, len(good), int(rng.integers(1, 8))):
                flipped[pos] ^= 1 << int(rng.integers(0, 8))
            data = bytes(flipped)
        else:  # random msgpack structures
            data = msgpack.packb({"schema": 1, "kind": "chunk", "body": {"obs": int(rng.integers(0, 9)),
                                                                      "x": rng.bytes(5)}}, use_bin_type=True)
        tried[kind] += 1
        try:
            chunk = records.decode_chunk(data)
        except codec.CodecError:
            refused[kind] += 1
            continue
        assert kind == 2 and isinstance(chunk, Chunk)  # a flip inside a float can leave a valid chunk
    assert (refused[[0, 1, 3]] == tried[[0, 1, 3]]).all(), (refused, tried)
    assert refused[2] > tried[2] // 2, "most flips hit a header, a shape, a range or a finiteness check"
    bomb = msgpack.packb({"schema": 1, "kind": "chunk", "body": {"obs": msgpack.ExtType(
        1, msgpack.packb(["float32", [1 << 40, 1 << 40], b""], use_bin_type=True))}}, use_bin_type=True)
    with pytest.raises(codec.CodecError):
        records.decode_chunk(bomb)
    with pytest.raises(codec.CodecError):
        records.decode_chunk(pickle.dumps(dataclasses.asdict(make_chunk())))
    with pytest.raises(codec.CodecError, match="exceeds"):
        records.decode_chunk(good, limits=codec.Limits(max_bytes=len(good) - 1))


def unsafe_lines(text: str) -> list[str]:
    """Lines that load pickles: pickle / marshal imports, allow_pickle=True, torch.load without weights_only=True."""
    banned = re.compile(r"^\s*(import|from) (pickle|marshal|dill|cloudpickle)\b|allow_pickle\s*=\s*True")
    return [line for line in text.splitlines()
            if banned.search(line) or ("torch.load(" in line and "weights_only=True" not in line)]


def test_no_pickle_on_any_boundary_the_project_owns():
    hits = [f"{path.relative_to(ROOT)}: {line.strip()}"
            for path in [*ROOT.glob("cmcl/**/*.py"), *ROOT.glob("services/**/*.py"), *ROOT.glob("bench/*.py")]
            for line in unsafe_lines(path.read_text())]
    assert not hits, hits
    assert unsafe_lines("x = torch.load(f)\nimport pickle\nnp.load(p, allow_pickle=True)") == [
        "x = torch.load(f)", "import pickle", "np.load(p, allow_pickle=True)"], "the scan finds each kind"
    assert not unsafe_lines('torch.load(Path(p), map_location="cpu", weights_only=True)')
