"""Checkpoints are checked against their manifest before decoding: a missing, truncated or bit-flipped file is
refused by name and the previous generation is used; the roles and the inline resume do so too."""

import json

import numpy as np
import pytest
import torch

from cmcl.io.rundir import RunDirectory, load_checkpoint, save_torch_atomic
from cmcl.io.verified import CheckpointError, VerifiedFile
from services.common import load_state, save_state


def flip(path, at=0.5):
    data = bytearray(path.read_bytes())
    data[int(len(data) * at)] ^= 0x10
    path.write_bytes(bytes(data))


def test_two_generations_are_kept_and_each_kind_of_damage_falls_back_to_the_previous(tmp_path):
    vf = VerifiedFile(tmp_path / "learner.pt")
    assert vf.load().payload is None and vf.load().refused == [], "no checkpoint yet: a fresh start, nothing refused"
    for i in range(4):
        vf.save(f"payload {i}".encode() * 100)
    assert sorted(p.name for p in tmp_path.glob("learner-*.pt")) == ["learner-000003.pt", "learner-000004.pt"]
    assert vf.load().payload == b"payload 3" * 100 and vf.load().generation == 4
    newest = tmp_path / "learner-000004.pt"
    for damage in ("flip", "truncate", "missing"):
        good = newest.read_bytes()
        if damage == "flip":
            flip(newest)
        elif damage == "truncate":
            newest.write_bytes(good[:-7])
        else:
            newest.unlink()
        loaded = vf.load()
        assert loaded.payload == b"payload 2" * 100 and loaded.generation == 3, damage
        reason = {"flip": "SHA-256 differs", "truncate": "truncated", "missing": "missing"}[damage]
        assert len(loaded.refused) == 1 and "learner-000004.pt" in loaded.refused[0] and reason in loaded.refused[0]
        newest.write_bytes(good)
    flip(tmp_path / "learner-000003.pt")
    flip(newest)
    assert vf.load().payload is None and len(vf.load().refused) == 2, "both generations bad: nothing is used"
    vf.manifest.write_text("{not json")
    assert vf.load().payload is None and "not a checkpoint manifest" in vf.load().refused[0]
    vf.save(b"after a bad manifest")
    assert vf.load().payload == b"after a bad manifest", "a save repairs an unreadable manifest"


def test_a_role_checkpoint_refused_is_reported_and_the_previous_one_restored(tmp_path, capsys):
    path = str(tmp_path / "icm.pt")
    save_state(path, {"version": torch.tensor(1)})
    save_state(path, {"version": torch.tensor(2)})
    flip(tmp_path / "icm-000002.pt", at=0.9)
    state, refused = load_state(path)
    assert int(state["version"]) == 1 and len(refused) == 1
    assert "checkpoint refused" in capsys.readouterr().err


def test_the_inline_resume_skips_a_corrupt_checkpoint_for_the_one_before(tmp_path):
    from cmcl.loop.__main__ import main

    run = tmp_path / "run"
    sets = ["--set", f"run.dir={run}", "--set", "run.episodes=64", "--set", "run.checkpoint_every=32",
            "--set", "env.num_envs=16", "--set", "maddpg.warmup=64", "--set", "maddpg.batch_size=16"]
    assert main(["--config", "configs/spread_maddpg.toml", *sets, "--quiet"]) == 0
    checkpoints = sorted((run / "checkpoints").glob("ckpt_*.pt"))
    assert [p.name for p in checkpoints] == ["ckpt_00000032.pt", "ckpt_00000064.pt"]
    flip(checkpoints[-1])
    with pytest.raises(CheckpointError, match="ckpt_00000064.pt: SHA-256 differs"):
        load_checkpoint(checkpoints[-1])
    assert main(["--resume", str(run), "--set", "run.episodes=80", "--quiet"]) == 0
    episodes = [r["episodes"] for r in RunDirectory.open(run).rows("episode")]
    assert episodes == list(range(1, 81)), "resumed at episode 32: rows after it rewritten once"


def test_a_checkpoint_without_manifest_and_a_bad_manifest(tmp_path):
    path = tmp_path / "ckpt.pt"
    save_torch_atomic(path, {"w": torch.ones(3)})
    assert json.dumps(load_checkpoint(path)["w"].tolist()) == "[1.0, 1.0, 1.0]"
    (tmp_path / "ckpt.pt.sha256").write_text("zz")
    with pytest.raises(CheckpointError, match="not a checkpoint manifest"):
        load_checkpoint(path)
    (tmp_path / "ckpt.pt.sha256").unlink()  # written before manifests existed: decoded without the check
    np.testing.assert_array_equal(load_checkpoint(path)["w"].numpy(), np.ones(3))
