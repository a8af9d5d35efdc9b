"""Rollout worker: steps B batched worlds with the current policy and returns transition chunks.

Where it sits: first in the flow (rollout -> replay -> learner). The supervisor calls `rollout(weights,
version)`; the chunk goes, as an object ref owned by the supervisor, straight to the replay server. One call
is one whole episode in each of the B lock-stepped worlds (episode_length steps), so a chunk holds
B complete episodes and the replay server can give each a global episode id (and hence a fold).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from cmcl.learners.policy import NumpyPolicy
from cmcl.messages import Chunk
from cmcl.progress import REPORTED_STATS, finished_episodes
from cmcl.system import agent_layout, build_maddpg, make_batched_env, to_env_actions
from services.common import actor_setup, new_incarnation
from services.report_schema import FinishedEpisodes, Report, RolloutReport


class RolloutWorker:
    """One worker: B worlds of the configured task and a copy of the online actors."""

    def __init__(self, config: Any, worker_id: int, seed: int):
        parsed = actor_setup(config, uses_torch=False)
        self.config = actor_setup(parsed, uses_torch=parsed.maddpg.discrete)
        self.worker_id, self.incarnation = int(worker_id), new_incarnation()
        # a restarted worker must not replay its predecessor's worlds: mix the incarnation into the seed
        entropy = [int(seed), int(worker_id), int(self.incarnation, 16)]
        env_seed, noise_seed, net_seed = np.random.SeedSequence(entropy).spawn(3)
        self.env = make_batched_env(self.config, seed=np.random.default_rng(env_seed), auto_reset=True)
        self.layout = agent_layout(self.config, self.env)
        # continuous actors run in numpy (no torch in this process); the discrete variant keeps torch's MADDPG
        self.net_seed = int(net_seed.generate_state(1)[0])
        self.policy: Any = build_maddpg(self.config, self.layout, self.net_seed) if self.config.maddpg.discrete \
            else None
        self.rng = np.random.default_rng(noise_seed)
        self.version, self.seq = -1, 0
        self.env_steps, self.episodes = 0, 0
        self.obs = self.env.reset()

    def rollout(self, published: dict | None) -> tuple[Chunk, Report]:
        """Run one episode in every world with the published policy {"version", "weights"} (+ exploration noise).

        Returns (chunk, report): a Chunk of T*B rows (env_index: world 0..B-1 of this worker) and a metrics report
        (cumulative env steps and episodes, finished-episode statistics).
        """
        if published is not None and published["version"] != self.version:
            if self.config.maddpg.discrete:
                from cmcl.learners.weights import load_published

                load_published(self.policy, published["weights"], parts=("actor",))
            else:
                self.policy = NumpyPolicy(published["weights"]["actor"])
            self.version = int(published["version"])
        if self.policy is None:  # no weights published yet: a fresh actor, initialised like the learner's
            self.policy = NumpyPolicy(_initial_actor(self.config, self.layout, self.net_seed))
        cfg, b, t_len = self.config, self.env.num_envs, self.env.episode_length
        obs, act, rew, nxt = [], [], [], []
        info: dict[str, Any] = {}
        for _ in range(t_len):
            a = self.policy.act(self.obs, cfg.maddpg.exploration_std, rng=self.rng)
            next_obs, r, _, info = self.env.step(to_env_actions(a, cfg.maddpg.discrete))
            obs.append(self.obs)
            act.append(a)
            rew.append(r)
            nxt.append(info["final_obs"])
            self.obs = next_obs
        if not info["episode_mask"].all():
            raise RuntimeError("worlds are expected to end their episodes together (lock-step reset)")
        self.env_steps += t_len * b
        self.episodes += b
        chunk = Chunk(obs=np.concatenate(obs), act=np.concatenate(act), rew=np.concatenate(rew),
                      next_obs=np.concatenate(nxt), done=np.zeros(t_len * b, np.float32),
                      env_index=np.tile(np.arange(b, dtype=np.int64), t_len), writer=self.worker_id,
                      incarnation=self.incarnation, seq=self.seq, policy_version=max(self.version, 0))
        self.seq += 1
        return chunk, self._report(info["episode"])

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
