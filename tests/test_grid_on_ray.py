"""A grid's runs as Ray Tune trials (experiments.on_ray, `python -m experiments run GRID --ray`), on the tests' real
embedded Ray: a run without a summary trains as a trial into the store, one with a summary is not submitted, and a
service run is refused before anything trains."""

import pytest

from experiments.on_ray import GridOnRayError, run_grid_on_ray
from experiments.run_spec import Run
from experiments.store import ResultsStore
from tests.test_experiments_runner import TINY


def test_a_grid_trains_its_unfinished_runs_as_tune_trials_and_skips_finished_ones(ray_cluster, tmp_path):
    store = ResultsStore(tmp_path)
    fresh = Run("spread_maddpg_s5", "spread", "spread", "maddpg", None, 5, 160, sets=TINY)
    finished = Run("spread_maddpg_s6", "spread", "spread", "maddpg", None, 6, 160, sets=TINY)
    store.write({**finished.record(), "held_out_coverage": 0.25})
    lines: list[str] = []
    assert run_grid_on_ray([finished, fresh], store, jobs=1, address=None, report=lines.append) == 0, lines
    assert lines[0] == f"1 runs to do, as Ray Tune trials: {fresh.id}"
    assert lines[1].startswith(f"{fresh.id} done in ")
    summaries = {r["id"]: r for r in store.load()}
    assert summaries[fresh.id]["episodes"] == 160 and summaries[fresh.id]["seed"] == 5
    assert summaries[finished.id]["held_out_coverage"] == 0.25 and not store.runs_dir(finished.id).exists()
    assert (tmp_path / "results.csv").read_text().count("\n") == 3
    assert ray_cluster.is_initialized(), "the tests' Ray was used, not stopped"


def test_a_service_run_is_refused_in_one_line_before_anything_trains(tmp_path):
    service = Run("make_run_maddpg_s0", "make_run", "spread", "maddpg", None, 0, 160, mode="service")
    with pytest.raises(GridOnRayError, match="make_run_maddpg_s0 has mode service"):
        run_grid_on_ray([service], ResultsStore(tmp_path), jobs=1, address=None, report=lambda line: None)
    assert not any(tmp_path.iterdir())
