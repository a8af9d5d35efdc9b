"""Checkpoints are checked against their manifest before decoding: a missing, truncated or bit-flipped file is
refused by name and the previous generation is used; the roles and a resume do so too."""

import json
import shutil
from pathlib import Path

import pytest
import torch

from cmcl.io.checkpoint_files import load_checkpoint, save_torch_atomic
from cmcl.io.verified import CheckpointError, VerifiedFile
from cmcl.run.rundir import RunDirectory
from services.runtime.common import load_state, save_state


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


def test_a_checkpoint_without_its_digest_file_or_with_a_bad_one_is_refused(tmp_path):
    path = tmp_path / "ckpt.pt"
    save_torch_atomic(path, {"w": torch.ones(3)})
    assert json.dumps(load_checkpoint(path)["w"].tolist()) == "[1.0, 1.0, 1.0]"
    (tmp_path / "ckpt.pt.sha256").write_text("zz")
    with pytest.raises(CheckpointError, match="not a checkpoint digest"):
        load_checkpoint(path)
    (tmp_path / "ckpt.pt.sha256").unlink()  # never trusted without a checksum, never decoded
    with pytest.raises(CheckpointError, match=r"ckpt.pt: no ckpt.pt.sha256 beside it, so it cannot be verified"):
        load_checkpoint(path)


@pytest.mark.parametrize("manifest", ["missing", "unreadable"])
def test_a_lost_manifest_is_rebuilt_from_the_files_and_never_costs_a_generation(tmp_path, manifest):
    """With the manifest gone, resume used to start afresh and its first save wrote generation 1 and
    deleted the intact generations 2 and 3."""
    vf = VerifiedFile(tmp_path / "learner.pt")
    for i in (1, 2, 3):
        vf.save(f"policy {i}".encode() * 100)
    if manifest == "missing":
        vf.manifest.unlink()
    else:
        vf.manifest.write_text("{not json")
    loaded = vf.load()
    assert (loaded.payload, loaded.generation) == (b"policy 3" * 100, 3), loaded.refused
    assert vf.save(b"policy 4").name == "learner-000004.pt", "numbered above every generation on disk"
    assert sorted(p.name for p in tmp_path.glob("learner-*.pt")) == ["learner-000003.pt", "learner-000004.pt"]
    assert json.loads(vf.manifest.read_text())["previous"]["generation"] == 3, "the manifest is rebuilt"
    flip(tmp_path / "learner-000004.pt")
    assert vf.load().payload == b"policy 3" * 100, "the previous generation still backs the newest"


def test_a_new_save_numbers_above_a_corrupt_newest_and_deletes_only_after_it_verifies(tmp_path):
    vf = VerifiedFile(tmp_path / "icm.pt")
    for i in (1, 2, 3):
        vf.save(f"state {i}".encode())
    vf.manifest.unlink()
    flip(tmp_path / "icm-000003.pt")
    assert vf.load().generation == 2 and "icm-000003.pt: SHA-256 differs" in vf.load().refused[0]
    assert vf.save(b"state 4").name == "icm-000004.pt"
    assert sorted(p.name for p in tmp_path.glob("icm-*.pt")) == ["icm-000002.pt", "icm-000004.pt"]


def test_a_resume_over_checkpoint_files_that_cannot_be_verified_is_refused_naming_them(tmp_path, capsys):
    """Files written before digest files existed, their manifest lost: refused, never started afresh over."""
    from cmcl.config import load_config
    from cmcl.run.flags import RunRequest, train_in_run

    run = RunDirectory.create(tmp_path / "run", load_config(None))
    learner = VerifiedFile(run.service_paths()["learner"])
    for i in (1, 2, 3):
        learner.save(f"policy {i}".encode())
    for generation in (2, 3):
        (run.service_dir / f"learner-{generation:06d}.pt.sha256").unlink(missing_ok=True)  # none before them
    learner.manifest.unlink()
    trained = []
    code = train_in_run(RunRequest(runner="service", resume_dir=str(run.path)), lambda *a: trained.append(a) or 0)
    err = capsys.readouterr().err
    assert code == 2 and not trained and err.count("\n") == 1
    assert "learner-000003.pt, learner-000002.pt" in err and "cannot be verified" in err
    assert sorted(p.name for p in run.service_dir.glob("learner-*.pt")) == ["learner-000002.pt", "learner-000003.pt"]


def test_resume_finds_the_trained_policy_when_the_learner_manifest_is_lost(tmp_path):
    import io

    from services.launch import resume_notice

    run = RunDirectory(tmp_path)
    learner = VerifiedFile(run.service_paths()["learner"])
    for version in (1, 2, 3):
        buffer = io.BytesIO()
        torch.save({"maddpg": {"w": torch.zeros(2)}, "version": version}, buffer)
        learner.save(buffer.getvalue())
    learner.manifest.unlink()
    assert run.runners() == {"service"}
    notice = resume_notice(run)
    assert "afresh" not in notice and notice.endswith("learner-000003.pt (policy version 3)"), notice


@pytest.fixture(scope="module")
def inline_run(tmp_path_factory):
    """A tiny run of the inline runner (the service's roles in one process) checkpointed at episodes 8 and 12: two
    generations of every role's verified file."""
    from services.launch import train_in_process
    from tests.tiny import make_tiny_config

    config = make_tiny_config("cmcl", service=True, dir=str(tmp_path_factory.mktemp("inline") / "run"), episodes=8)
    run = RunDirectory.create(config.run.dir, config)
    train_in_process(config, run)
    train_in_process(run.config(("run.episodes=12",)), run, resume=True)
    return Path(config.run.dir)


def truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


# a role's newest file (generation 2) damaged or gone: the role starts from generation 1 (its manifest holds the
# digests, a missing .sha256 beside it is no damage)
DAMAGE = {
    "learner: a flipped bit": lambda service: flip(service / "learner-000002.pt"),
    "learner: truncated": lambda service: truncate(service / "learner-000002.pt"),
    "learner: missing": lambda service: (service / "learner-000002.pt").unlink(),
    "teachers: a flipped bit": lambda service: flip(service / "teacher_0-1-2-000002.pt"),
    "icm: truncated": lambda service: truncate(service / "icm-000002.pt"),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_an_inline_resume_refuses_a_damaged_role_checkpoint_for_the_one_before(inline_run, tmp_path, damage,
                                                                               capsys):
    from cmcl.__main__ import main

    run = RunDirectory(shutil.copytree(inline_run, tmp_path / "run"))
    DAMAGE[damage](run.service_dir)
    assert main(["resume", "--runner", "inline", str(run.path), "--more-episodes", "4", "--quiet", "--no-eval"]) == 0
    out, err = capsys.readouterr()
    refused = [line for line in err.splitlines() if line.startswith("checkpoint refused: ")]
    assert len(refused) == 1 and "-000002.pt" in refused[0], err
    role = damage.split(":")[0]
    if role == "learner":
        assert "from checkpoints/service/learner-000001.pt" in out, out
    assert [r["episodes"] for r in run.rows("episode")] == list(range(1, 17)), "the run goes on from episode 12"


def test_an_inline_resume_over_a_damaged_replay_snapshot_ends_in_one_line_naming_it(inline_run, tmp_path, capsys):
    """The replay store keeps one snapshot (and its log): one that fails its digest cannot be replaced by an older
    one, so the resume is refused naming the file, and the run is left as it was."""
    from cmcl.__main__ import main

    run = RunDirectory(shutil.copytree(inline_run, tmp_path / "run"))
    snapshot = run.service_replay_dir / "snapshot-000002.msgpack"
    flip(snapshot)
    assert main(["resume", "--runner", "inline", str(run.path), "--more-episodes", "4", "--quiet", "--no-eval"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("error: ") and err.count("\n") == 1, err
    assert str(snapshot) in err
