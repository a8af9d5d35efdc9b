"""Episode ids of B worlds that end their episodes each on its own, and rollout chunks of whole episodes.

Where it sits: the replay gives every transition an episode id and assigns the K teacher folds by episode id
(ALGORITHM.md §3.2), so the rows of one episode must share one id and no two episodes may share one. The inline
loop tags every stored row with `WorldEpisodes.ids`; the rollout worker (services/roles/rollout.py) gathers steps in an
`EpisodeChunker` and sends only whole episodes, numbered 0..E-1 within the chunk (`Chunk.env_index`), which the
replay server turns into global ids. For the built-in twins (all worlds end together after T steps) both give
exactly the ids and chunks of the lock-step worlds: world i of round r is episode r·B + i.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cmcl.replay.messages import Chunk


class WorldEpisodes:
    """The episode id each of B worlds is playing now: int64[B], new ids in world order as episodes end."""

    def __init__(self, num_envs: int, ids: np.ndarray | None = None):
        self.ids = np.arange(num_envs, dtype=np.int64) if ids is None else np.asarray(ids, np.int64).copy()

    def advance(self, ended: np.ndarray) -> None:
        """The worlds with ended[b] (bool[B]) start the next unused ids, in world order."""
        idx = np.flatnonzero(ended)
        if idx.size:
            self.ids[idx] = self.ids.max() + 1 + np.arange(idx.size)


@dataclass
class EpisodeChunker:
    """Steps of B worlds in, chunks of whole episodes out (rows in step order, as they were played).

    `add` takes one step: obs / next_obs float32[B, N, od], act float32[B, N, ad], rew float32[B, N], done
    float32[B, N] (1 where the agent terminated, per agent; or [B], per world) and ended bool[B]. `pop` returns the
    rows of at most `max_episodes` finished episodes (oldest ids first) and keeps every other row for a later chunk.
    """

    num_envs: int
    steps: list[dict[str, np.ndarray]] = field(default_factory=list)
    finished: list[int] = field(default_factory=list)  # ids of finished episodes not yet sent, oldest first

    def __post_init__(self) -> None:
        self.episodes = WorldEpisodes(self.num_envs)

    def add(self, obs: np.ndarray, act: np.ndarray, rew: np.ndarray, next_obs: np.ndarray, done: np.ndarray,
            ended: np.ndarray) -> None:
        self.steps.append({"obs": obs, "act": act, "rew": rew, "next_obs": next_obs,
                           "done": np.asarray(done, np.float32), "episode": self.episodes.ids.copy()})
        self.finished.extend(int(e) for e in self.episodes.ids[np.flatnonzero(ended)])
        self.episodes.advance(ended)

    @property
    def ready(self) -> int:
        """Finished episodes waiting to be sent."""
        return len(self.finished)

    def pop(self, max_episodes: int, writer: int, incarnation: str, seq: int, policy_version: int) -> Chunk:
        """A Chunk of the oldest min(ready, max_episodes) finished episodes; env_index = their rank 0..E-1."""
        send = np.asarray(sorted(self.finished)[:max_episodes], np.int64)
        joined = {k: np.concatenate([s[k] for s in self.steps]) for k in self.steps[0]} if self.steps else {}
        keep = ~np.isin(joined["episode"], send) if joined else np.zeros(0, bool)
        rows = {k: v[~keep] for k, v in joined.items()}
        self.steps = [{k: v[keep] for k, v in joined.items()}] if keep.any() else []
        sent = set(send.tolist())
        self.finished = [e for e in self.finished if e not in sent]
        return Chunk(obs=rows["obs"], act=rows["act"], rew=rows["rew"], next_obs=rows["next_obs"],
                     done=rows["done"], env_index=np.searchsorted(send, rows["episode"]).astype(np.int64),
                     writer=writer, incarnation=incarnation, seq=seq, policy_version=policy_version)
