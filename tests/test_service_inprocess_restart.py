"""The service classes run in-process without Ray, restarted: what a new replay server, learner or teacher restores
from its snapshot, log or checkpoint (buffer, scores, counters, dedupe table, sampler streams, weights), and what a
torn, corrupt or bad file costs. The data flow itself is tests/test_service_inprocess_flow.py."""

import numpy as np
import pytest

from cmcl.io.durable import ReplayStore, StoreError
from cmcl.replay.messages import DIFFICULTY, Scorer
from services.roles.learner import Learner
from services.roles.replay_server import ReplayServer
from services.roles.rollout import RolloutWorker
from tests.in_process import in_process_config, roles


def test_snapshot_restores_buffer_scores_counters_and_dedupe(tmp_path):
    cfg = in_process_config("cmcl")
    replay, learner, worker, teachers, icm = roles(cfg)
    chunk = None
    for _ in range(3):
        chunk, _ = worker.rollout(None)
        replay.insert(chunk)
    scores, _ = teachers[0].score(replay.work(Scorer(DIFFICULTY, (0,)), 2)[0], learner.publish())
    replay.write(scores)
    replay.sample(2)
    replay.store = ReplayStore(tmp_path / "replay")
    replay.snapshot()
    restored = ReplayServer(cfg, store_dir=str(tmp_path / "replay"))
    assert restored.status().env_steps == 360 and restored.status().updates == 2
    np.testing.assert_array_equal(restored.replay.storage.obs, replay.replay.storage.obs)
    for name, value in replay.scoring.difficulty.state_dict().items():
        np.testing.assert_array_equal(restored.scoring.difficulty.state_dict()[name], value)
    assert "duplicate" in restored.insert(chunk).error, "dedupe table survives a restart"


@pytest.mark.parametrize("algorithm", ["per", "cmcl"])
def test_a_restored_server_continues_the_sampler_streams(tmp_path, algorithm):
    """The generators are in the snapshot: the restored server draws the minibatch the first one would have drawn
    next, not the first incarnation's opening draws again."""
    cfg = in_process_config(algorithm)
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    opening = replay.sample(1)[0].slots
    replay.store = ReplayStore(tmp_path / "replay")
    replay.snapshot()
    restored = ReplayServer(cfg, store_dir=str(tmp_path / "replay"))
    after, again = replay.sample(1)[0].slots, restored.sample(1)[0].slots
    np.testing.assert_array_equal(again, after)
    assert not np.array_equal(again, opening)


def test_learner_and_teacher_restart_from_their_checkpoints(tmp_path):
    cfg = in_process_config("cmcl")
    replay, learner, worker, teachers, _ = roles(cfg)
    for _ in range(3):
        replay.insert(worker.rollout(None)[0])
    learner = Learner(cfg, 0, str(tmp_path / "learner.pt"))
    learner.update(replay.sample(4)[0])
    learner.save()
    again = Learner(cfg, 0, str(tmp_path / "learner.pt"))
    assert again.resumed and again.version == 1 and again.report().learner.updates == 4
    for key, value in learner.publish()["weights"]["actor"].items():
        np.testing.assert_array_equal(again.publish()["weights"]["actor"][key], value)


def test_no_acknowledged_chunk_is_lost_across_a_restart(tmp_path):
    cfg = in_process_config("acl")
    store = str(tmp_path / "replay")
    replay, worker = ReplayServer(cfg, store_dir=store), RolloutWorker(cfg, 0, 0)
    chunks = [worker.rollout(None)[0] for _ in range(3)]
    replay.insert(chunks[0])
    assert ReplayServer(cfg, store_dir=store).replay.size == 120, "the log alone restores, before any snapshot"
    replay.insert(chunks[1])
    replay.snapshot()
    replay.insert(chunks[2])  # acknowledged after the snapshot: only in the log
    replay.sample(3)
    replay.work(Scorer(DIFFICULTY, (1,)), 2)
    restored = ReplayServer(cfg, store_dir=store)  # a crash: a new process on the same store
    assert restored.resumed and restored.counters["restored_records"] == 3  # a chunk, 3 updates, 2 fit steps
    assert (restored.counters["updates"], restored.teacher_steps) == (3, [0, 2, 0]), "counters never go back"
    assert restored.pacing.state_dict() == replay.pacing.state_dict()
    for key in ("obs", "act", "rew", "episode", "fold"):
        np.testing.assert_array_equal(getattr(restored.replay.storage, key), getattr(replay.replay.storage, key))
    assert restored.status().env_steps == replay.status().env_steps == 360
    assert restored.status().lam == replay.status().lam
    assert all("duplicate" in restored.insert(c).error for c in chunks), "a retried chunk is not stored twice"


def test_a_torn_log_tail_is_cut_and_a_bad_snapshot_refused(tmp_path):
    cfg = in_process_config("maddpg")
    store = tmp_path / "replay"
    replay, worker = ReplayServer(cfg, store_dir=str(store)), RolloutWorker(cfg, 0, 0)
    for _ in range(2):
        replay.insert(worker.rollout(None)[0])
    log = store / "log-000000.bin"
    with open(log, "r+b") as f:  # a crash in the middle of the second frame
        f.truncate(log.stat().st_size - 100)
    restored = ReplayServer(cfg, store_dir=str(store))
    assert restored.replay.size == 120 and restored.rejected == {"log_truncated": 1}
    assert restored.insert(worker.rollout(None)[0]).accepted == 120, "appends continue after the good frames"
    restored.snapshot()
    snapshot = next(store.glob("snapshot-*.msgpack"))
    data = bytearray(snapshot.read_bytes())
    data[len(data) // 2] ^= 0xFF
    snapshot.write_bytes(bytes(data))
    with pytest.raises(StoreError, match="SHA-256 does not match"):
        ReplayServer(cfg, store_dir=str(store))


def test_a_snapshot_of_an_older_version_is_refused_in_one_line_naming_the_field_and_the_last_commit(tmp_path):
    """A snapshot without a part this version writes (the sampler streams, kept since a later version) or of the
    buffer's older format: refused as a bad snapshot is, naming what it lacks and the commit that reads it."""
    from cmcl.replay.snapshot import LAST_READER
    from services.roles.replay_server import SNAPSHOT_KEYS

    cfg = in_process_config("maddpg")
    replay, worker = ReplayServer(cfg), RolloutWorker(cfg, 0, 0)
    replay.insert(worker.rollout(None)[0])
    state = replay.state_dict()
    assert tuple(state) == SNAPSHOT_KEYS
    for name, older in (("replay server snapshot without 'sampler_rngs'",
                         {k: v for k, v in state.items() if k != "sampler_rngs"}),
                        ("replay snapshot format 1 (this version reads 2)",
                         {**state, "replay": {k: v for k, v in state["replay"].items() if k != "format"}})):
        store = tmp_path / name.split()[2]
        ReplayStore(store).snapshot(older)
        with pytest.raises(StoreError) as err:
            ReplayServer(cfg, store_dir=str(store))
        assert str(err.value) == f"{name}: written by an older version; commit {LAST_READER} is the last that reads it"


def test_a_corrupt_frame_costs_only_its_own_transitions_and_the_log_is_moved_aside(tmp_path, capsys):
    """One flipped byte in the first frame used to truncate the log there and lose every chunk after."""
    cfg = in_process_config("maddpg")  # capacity 360: two chunks of 120 stay in the log
    store = tmp_path / "replay"
    replay, worker = ReplayServer(cfg, store_dir=str(store)), RolloutWorker(cfg, 0, 0)
    chunks = [worker.rollout(None)[0] for _ in range(2)]
    for chunk in chunks:
        assert replay.insert(chunk).accepted == 120
    log = store / "log-000000.bin"
    damaged = bytearray(log.read_bytes())
    damaged[len(damaged) // 4] ^= 0xFF  # inside the first chunk's frame
    log.write_bytes(bytes(damaged))
    restored = ReplayServer(cfg, store_dir=str(store))
    assert restored.replay.size == 120 and restored.rejected == {"log_truncated": 1}
    assert "duplicate" in restored.insert(chunks[1]).error, "the chunk after the bad frame is kept"
    assert restored.insert(chunks[0]).accepted == 120, "the lost one is not marked stored: a retry is taken"
    err = capsys.readouterr().err
    assert "1 corrupt frame(s) skipped (120 transitions lost)" in err and "log-000000.bin.damaged-1" in err
    assert (store / "log-000000.bin.damaged-1").read_bytes() == bytes(damaged), "moved aside whole, not cut"


def test_the_log_never_holds_more_than_one_buffer_of_transitions(tmp_path):
    cfg = in_process_config("maddpg")  # capacity 360 = 3 chunks of 120
    store = tmp_path / "replay"
    replay, worker = ReplayServer(cfg, store_dir=str(store)), RolloutWorker(cfg, 0, 0)
    for _ in range(2):
        replay.insert(worker.rollout(None)[0])
    assert replay.store.generation == 0 and replay.logged_rows == 240
    replay.insert(worker.rollout(None)[0])  # the third reaches the capacity: a snapshot, then an empty log
    assert replay.store.generation == 1 and replay.logged_rows == 0
    assert (store / "log-000001.bin").stat().st_size == 0
    assert ReplayServer(cfg, store_dir=str(store)).replay.size == 360
