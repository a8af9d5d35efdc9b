"""The online critic is a scorer the learner hosts (ACL td_self, docs/DESIGN.md "Scorers"): every row the buffer
holds gets its |δ| from the learner's online critics, on the inline runner and on the service alike (both schedule
the same roles: services.calls). Before, the service's td_self rows kept their provisional priority for good."""

import numpy as np

from cmcl.config import config_from_dict
from cmcl.io.rundir import RunDirectory
from services.launch import train_in_process


def td_self_config(tiny_config, tmp_path):
    """The tiny ACL config with the td_self variant (its difficulty: the online critics' |δ|), 24 episodes."""
    data = tiny_config("acl", service=True, dir=str(tmp_path / "run"), episodes=24).to_dict()
    data["teams"]["agent"]["acl_variant"] = "td_self"
    return config_from_dict(data)


def test_every_stored_row_is_scored_by_the_online_critics(tiny_config, tmp_path):
    config = td_self_config(tiny_config, tmp_path)
    summary, roles = train_in_process(config, RunDirectory.create(config.run.dir, config))
    replay, scoring = roles.replay.replay, roles.replay.scoring
    assert summary["updates"] > 0 and scoring.online_td
    valid, stamp = scoring.score_stamps(replay, online_td=True)
    assert valid.size == replay.size
    assert (stamp >= 0).all(), f"{int((stamp < 0).sum())} of {valid.size} rows never scored by the online critics"
    td = replay.storage.scores["td_abs"][valid]
    assert replay.storage.scored["td_abs"][valid].all() and np.isfinite(td).all() and (td > 0).any()
