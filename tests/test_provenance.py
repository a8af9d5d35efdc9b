"""Every result records the code it ran, and the report never tests runs of mixed code."""

import json
import subprocess
from pathlib import Path

import pytest

import experiments.__main__ as experiments_cli
from cmcl.config import load_config
from cmcl.run.provenance import SIMD, LoadSampler, code_at_start, code_state, cpu, provenance
from cmcl.run.rundir import RunDirectory
from experiments.provenance import cell_versions, code_version


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-c", "user.email=t@t", "-c", "user.name=t", *args], cwd=repo, check=True,
                          capture_output=True, text=True).stdout.strip()


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    git(tmp_path, "init", "-q")
    (tmp_path / "tracked.txt").write_text("one\n")
    git(tmp_path, "add", "tracked.txt")
    git(tmp_path, "commit", "-qm", "first")
    return tmp_path


def test_code_state_names_the_commit_and_sees_a_dirty_tracked_file(repo):
    head = git(repo, "rev-parse", "HEAD")
    assert code_state(repo) == (head, False)
    (repo / "untracked.txt").write_text("not tracked: not dirty\n")
    assert code_state(repo) == (head, False)
    (repo / "tracked.txt").write_text("changed\n")
    assert code_state(repo) == (head, True)


def test_a_grids_own_results_do_not_make_the_code_dirty(repo):
    """A grid's tracked results.csv changes after its first run: the runs after it ran the same code."""
    results = repo / "lab" / "results" / "grid"
    results.mkdir(parents=True)
    (results / "results.csv").write_text("id\n")
    git(repo, "add", "lab")
    git(repo, "commit", "-qm", "results")
    head = git(repo, "rev-parse", "HEAD")
    (results / "results.csv").write_text("id\nrun_s0\n")
    assert code_state(repo) == (head, False)
    (repo / "tracked.txt").write_text("changed\n")
    assert code_state(repo) == (head, True)


def test_outside_a_checkout_the_commit_comes_from_the_environment_or_is_none(tmp_path, monkeypatch):
    monkeypatch.delenv("CMCL_COMMIT", raising=False)
    assert code_state(tmp_path) == (None, None)
    monkeypatch.setenv("CMCL_COMMIT", "abc1234")
    assert code_state(tmp_path) == ("abc1234", None)


def test_the_record_holds_config_hash_versions_cores_and_load(repo):
    record = provenance("[run]\nseed = 1\n", repo)
    other = provenance("[run]\nseed = 2\n", repo)
    assert record["config_sha256"] != other["config_sha256"] and len(record["config_sha256"]) == 64
    assert set(record["versions"]) == {"python", "torch", "numpy", "ray"}
    assert record["cores"] >= 1 and len(record["load_avg"]) == 3
    assert record["cpu"] == cpu() and record["cpu"]["model"] and record["cpu"]["simd"] in {*dict(SIMD), "unknown"}


def test_the_cpu_is_named_with_its_widest_vector_extension(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: Some Xeon\nflags\t\t: fpu sse2 avx avx2 avx512f\n\n"
                    "processor\t: 1\nmodel name\t: Some Xeon\nflags\t\t: fpu sse2 avx avx2 avx512f\n")
    assert cpu(info) == {"model": "Some Xeon", "simd": "avx512"}
    info.write_text("model name\t: Older\nflags\t\t: fpu sse2 avx avx2\n")
    assert cpu(info) == {"model": "Older", "simd": "avx2"}
    assert cpu(tmp_path / "absent")["simd"] == "unknown"


def test_a_commit_made_while_a_run_trains_does_not_rename_the_code_it_ran(repo):
    # the N = 8 runs of 2026-12-05: main was merged while they trained, and their summaries named the merge
    started = git(repo, "rev-parse", "HEAD")
    assert code_at_start(repo) == (started, False)  # the run opens
    (repo / "tracked.txt").write_text("two\n")
    git(repo, "commit", "-qam", "second")  # made while it trains
    record = provenance(None, repo)  # its summary, written at the end
    assert (record["commit"], record["dirty"]) == (started, False)
    assert record["changed_during_run"] == {"commit": git(repo, "rev-parse", "HEAD"), "dirty": False}
    assert code_version({"provenance": record}) == started[:7] + "+changed"


def test_an_unchanged_checkout_records_no_change(repo):
    code_at_start(repo)
    assert "changed_during_run" not in provenance(None, repo)


def test_run_summary_records_provenance_and_the_commits_of_every_segment(tmp_path):
    config = load_config(None, [f"run.dir={tmp_path / 'run'}"])
    run_dir = RunDirectory.create(config.run.dir, config)
    run_dir.write_summary({"ended": "stopped"})
    first = run_dir.summary()["provenance"]
    assert first["config_sha256"] and first["segment_commits"] == ([first["commit"]] if first["commit"] else [])
    # an earlier segment made at another commit stays named after the next segment's summary
    earlier = {**run_dir.summary(), "provenance": {**first, "commit": "0" * 40, "segment_commits": ["0" * 40]}}
    run_dir.summary_path.write_text(json.dumps(earlier))
    run_dir.write_summary({"ended": "budget"})
    assert run_dir.summary()["provenance"]["segment_commits"][0] == "0" * 40
    assert len(run_dir.summary()["provenance"]["segment_commits"]) == (2 if first["commit"] else 1)



def test_a_run_started_over_does_not_inherit_the_old_runs_commits_or_its_ending(tmp_path):
    """Before (found 2026-12-06): --overwrite deleted the old run's checkpoints and metrics but kept its summary.json,
    so the new run's summary listed the old run's commit among its segments (a grid read it as resumed across
    commits: "mixed"), and a new run cut off before its first summary still read as the old one's ending."""
    config = load_config(None, [f"run.dir={tmp_path / 'run'}"])
    old = RunDirectory.create(config.run.dir, config)
    old.summary_path.write_text(json.dumps({"ended": "solved", "provenance": {"commit": "0" * 40,
                                                                              "segment_commits": ["0" * 40]}}))
    new = RunDirectory.create(config.run.dir, config, overwrite=True)
    assert new.summary() == {}  # nothing of the old run's ending is left to read
    new.write_summary({"ended": "budget"})
    assert "0" * 40 not in new.summary()["provenance"]["segment_commits"]

def test_load_sampler_takes_a_sample_at_entry_and_exit():
    with LoadSampler(every_s=60) as load:
        pass
    assert load.summary()["load_samples"] == 2 and load.summary()["load_mean"] >= 0
    with pytest.raises(ValueError, match="every_s"):
        LoadSampler(every_s=0)


def summary(arm: str, seed: int, value: float, commit: str | None, fp: str | None = None, **extra) -> dict:
    prov = None if commit is None else {"commit": commit, "dirty": False, "segment_commits": [commit],
                                        "fingerprint": None if fp is None else {"curve": fp, "weights": fp}}
    return {"id": f"{arm}_{seed}", "arm": arm, "seed": seed, "budget": 100, "auc_coverage": value,
            "provenance": prov, **extra}


def test_cell_versions_one_code_mixed_code_and_fingerprints_that_vouch():
    one = [summary("maddpg", s, 0.5, "a" * 40) for s in range(3)] + [summary("cmcl", s, 0.4, "a" * 40)
                                                                    for s in range(3)]
    assert cell_versions(one) == ("aaaaaaa", True)
    mixed = one[:2] + [summary("maddpg", 2, 0.5, "b" * 40)] + one[3:]
    label, testable = cell_versions(mixed)
    assert not testable and label.startswith("mixed: ") and "bbbbbbb (1 runs)" in label
    vouched = [summary(r["arm"], r["seed"], 0.5, r["provenance"]["commit"], fp=r["arm"]) for r in mixed]
    assert cell_versions(vouched)[1] and "fingerprints agree" in cell_versions(vouched)[0]
    # fingerprints that differ within an arm: the commits train it differently
    vouched[2]["provenance"]["fingerprint"]["curve"] = "other"
    assert not cell_versions(vouched)[1]


def test_summaries_without_provenance_are_told_apart_by_the_later_measures_keys():
    assert code_version(summary("cmcl", 0, 0.4, None)) == "unrecorded"
    assert code_version(summary("cmcl", 0, 0.4, None, update_every=16, batch_size=128)) == \
        "unrecorded, later measures"
    dirty = summary("cmcl", 0, 0.4, "c" * 40)
    dirty["provenance"]["dirty"] = True
    assert code_version(dirty) == "ccccccc+dirty"


def test_a_grid_refuses_a_dirty_tree_unless_told(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(experiments_cli, "code_state", lambda: ("d" * 40, True))
    trained = []
    monkeypatch.setattr(experiments_cli, "run_grid", lambda runs, *a, **k: trained.append(runs) or 0)
    argv = ["run", "curriculum_hard", "--seeds", "0", "--arms", "maddpg", "--out", str(tmp_path)]
    assert experiments_cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--allow-dirty" in err and "ddddddd" in err and not trained
    assert experiments_cli.main([*argv, "--allow-dirty"]) == 0 and trained
    assert "with uncommitted changes" in capsys.readouterr().out
