"""Rollout worker: steps B batched worlds with the current policy and returns transition chunks.

Where it sits: first in the flow (rollout -> replay -> learner). The supervisor calls `rollout(weights,
version)`; the chunk goes, as an object ref owned by the supervisor, straight to the replay server. One call
steps the B worlds until B episodes have finished (each world ends and restarts its episodes on its own) and
sends B complete episodes (`cmcl.rollout.episodes.EpisodeChunker`), so the replay server can give each a global episode
id (and hence a fold). For the built-in twins that is one lock-step episode of every world, as before.

With [task_curriculum] (cmcl.rollout.task_curriculum) the worker owns the curriculum of its worlds: it sets each world's
stage at its episode boundaries, reports the stage of every finished episode (`task_stage`) and saves the
curriculum's state with its checkpoint (`save`, read back when the worker is built: a resumed or restarted worker
goes on at its stage).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from cmcl.io.atomic import atomic_write_bytes
from cmcl.progress.rows import REPORTED_STATS, finished_episodes
from cmcl.replay.messages import Chunk
from cmcl.rollout.episodes import EpisodeChunker
from cmcl.rollout.policy import NumpyPolicy, numpy_policy
from cmcl.rollout.task_curriculum import TaskCurriculum
from cmcl.system import agent_layout, build_maddpg, make_batched_env, to_env_actions
from services.observability.report_schema import FinishedEpisodes, Report, RolloutReport
from services.runtime.common import actor_setup, new_incarnation, restarted_actor


class RolloutWorker:
    """One worker: B worlds of the configured task and a copy of the online actors."""

    def __init__(self, config: Any, worker_id: int, seed: int, resumed_at: int = 0, state_path: str | None = None):
        """resumed_at: the episodes the run had stored when this segment began (0: a new run); a resumed run's worlds
        are then not its first segment's again. state_path: the worker's checkpoint (its task curriculum's state,
        JSON), loaded when it exists."""
        parsed = actor_setup(config, uses_torch=False)
        self.worker_id, self.incarnation = int(worker_id), new_incarnation()
        # a restarted worker must not replay its predecessor's worlds: its incarnation is mixed into the seed (a
        # first incarnation's worlds are the seed's own, so that one process's runs repeat exactly)
        entropy = [int(seed), int(worker_id), *([int(resumed_at)] if resumed_at else []),
                   *([int(self.incarnation, 16)] if restarted_actor() else [])]
        sequence = np.random.SeedSequence(entropy)
        env_seed, noise_seed, net_seed = sequence.spawn(3)
        self.env = make_batched_env(parsed, seed=np.random.default_rng(env_seed), auto_reset=True)
        self.state_path = Path(state_path) if state_path else None
        self.curriculum: TaskCurriculum | None = None
        if parsed.task_curriculum.enabled:
            self.curriculum = TaskCurriculum(parsed.task_curriculum, self.env.num_envs,
                                             np.random.default_rng(sequence.spawn(1)[0]))
            if self.state_path is not None and self.state_path.exists():
                self.curriculum.load_state(json.loads(self.state_path.read_text())["task_curriculum"])
            self.curriculum.start(self.env)
        self.layout = agent_layout(parsed, self.env)
        # continuous actors run in numpy (no torch in this process); the discrete variant (maddpg.discrete, or a
        # factory env with Discrete actions: known once the env is built) keeps torch's MADDPG
        self.config = actor_setup(parsed, uses_torch=self.layout.discrete)
        self.net_seed = int(net_seed.generate_state(1)[0])
        self.policy: Any = build_maddpg(self.config, self.layout, self.net_seed) if self.layout.discrete else None
        self.rng = np.random.default_rng(noise_seed)
        self.version, self.seq = -1, 0
        self.env_steps, self.episodes = 0, 0
        self.obs = self.env.reset()
        self.chunker = EpisodeChunker(self.env.num_envs)

    def rollout(self, published: dict | None) -> tuple[Chunk, Report]:
        """Step the B worlds with the published policy {"version", "weights"} (+ exploration noise) until B
        episodes have finished since the last chunk.

        Returns (chunk, report): a Chunk of B whole episodes (env_index: episode 0..B-1 of the chunk) and a report
        (cumulative env steps and episodes, finished-episode statistics).
        """
        if published is not None and published["version"] != self.version:
            if self.layout.discrete:
                from cmcl.learners.weights import load_published

                load_published(self.policy, published["weights"], parts=("actor",))
            else:
                self.policy = self._numpy_policy(published["weights"]["actor"])
            self.version = int(published["version"])
        if self.policy is None:  # no weights published yet: a fresh actor, initialised like the learner's
            self.policy = self._numpy_policy(_initial_actor(self.config, self.layout, self.net_seed))
        cfg, b = self.config, self.env.num_envs
        finished: list[dict[str, np.ndarray]] = []  # info["episode"] of the steps in which episodes ended
        while self.chunker.ready < b:
            a = self.policy.act(self.obs, cfg.maddpg.exploration_std, rng=self.rng)
            next_obs, r, ended, info = self.env.step(to_env_actions(a, cfg.maddpg.discrete))
            self.chunker.add(self.obs, a, r, info["final_obs"], info["terminated"], ended)
            self.env_steps += b
            if ended.any():
                episode = info["episode"]
                if self.curriculum is not None:
                    stages = self.curriculum.episodes_ended(self.env, ended, episode)
                    episode = {**episode, "task_stage": stages.astype(np.float64)}
                finished.append(episode)
            self.obs = next_obs
        self.episodes += sum(len(e["return"]) for e in finished)
        chunk = self.chunker.pop(b, self.worker_id, self.incarnation, self.seq, max(self.version, 0))
        self.seq += 1
        episode = {k: np.concatenate([e[k] for e in finished]) for k in finished[0]} if finished \
            else {"return": np.zeros((0, self.env.num_agents))}
        return chunk, self._report(episode)

    def save(self) -> None:
        """Write the worker's checkpoint (its task curriculum's state) atomically to state_path; nothing without a
        task curriculum or a path."""
        if self.curriculum is not None and self.state_path is not None:
            atomic_write_bytes(self.state_path, json.dumps({"task_curriculum": self.curriculum.state()}).encode())

    def _numpy_policy(self, actor: dict[str, np.ndarray]) -> NumpyPolicy:
        """The numpy twin of the actor weights `actor`, reading the entities the learner's actor reads (its nearest
        k and its holder margin)."""
        m = self.config.maddpg
        return numpy_policy(actor, self.layout.act_mask, self.layout.entities, m.entity_nearest, m.entity_holder,
                            m.holder_rule)

    def _report(self, episode: dict[str, np.ndarray]) -> Report:
        """Metrics report of this call: cumulative env steps and episodes, the episodes that just finished."""
        finished = FinishedEpisodes(**finished_episodes(episode, self.env.teams, REPORTED_STATS))
        return Report(source=f"rollout-{self.worker_id}", role="rollout", incarnation=self.incarnation,
                      weight_version=max(self.version, 0),
                      rollout=RolloutReport(env_steps=self.env_steps, episodes=self.episodes, finished=finished))


def _initial_actor(config: Any, layout: Any, seed: int) -> dict[str, np.ndarray]:
    """Actor weights of a freshly initialised learner (only used before any weights were published)."""
    from cmcl.learners.weights import published_weights

    return published_weights(build_maddpg(config, layout, seed))["actor"]
