"""Builds the learning system of one run from its Config: worlds, agent layout, MADDPG, replay, teachers, ICM, λ.

Where it sits: the single place that maps typed config sections onto the constructors of the pure classes.
The roles of both schedulers (services/) call it, so that the two modes run identical components with identical
settings. Each agent's sampler is built by its team's rule (`build_samplers`); the buffer receives them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from cmcl.config import Config, ConfigError, PriorityConfig
from cmcl.envs.entities import EntityLayout, entity_layout
from cmcl.replay.buffer import ReplayBuffer
from cmcl.replay.curriculum import CurriculumSchedule, default_growth
from cmcl.replay.rules.contract import LearnerScore
from cmcl.replay.sampling import SamplerArgs
from cmcl.replay.storage import TransitionStorage

if TYPE_CHECKING:  # torch-backed classes load lazily: the replay server and rollout workers never need torch
    from cmcl.learners.maddpg import MADDPG
    from cmcl.scorers.icm import ICM
    from cmcl.scorers.teachers import TeacherEnsemble

CONTROL_STREAM = 21  # entropy word of the permuted control's seed stream, see `control_seed`
DISCRETE_ACT_DIM = 5  # MPE's discrete action: no-op, +x, -x, +y, -y


@dataclass(frozen=True)
class AgentLayout:
    """Who is who: agent indices per team and what each agent's algorithm needs.

    algorithms: each agent's algorithm (a name of cmcl.replay.registry.REGISTRY, its team's), length N.
    alpha: sampling exponent α_s of eq. 20 per agent, length N (its team's `effective_alpha`, A8).
    priority: each agent's team's sampling settings ([teams.<team>.priority], cmcl.config.PriorityConfig), length N:
    what its sampler and the teachers' errors on its rows use.
    teacher_agents / icm_agents: int64[A_t] / int64[A_c] indices of agents that need teacher / curiosity scores.
    """

    num_agents: int
    obs_dim: int
    env_act_dim: int
    act_dim: int
    teams: dict[str, list[int]]
    algorithms: tuple[str, ...]
    eta: tuple[float, ...]
    alpha: tuple[float, ...]
    importance_weights: tuple[bool, ...]
    difficulty_source: tuple[str, ...]
    teacher_agents: np.ndarray
    icm_agents: np.ndarray
    # u, the uniform floor of each agent's prioritised rule (its team's `priority.uniform_floor`), length N
    floor: tuple[float, ...] = ()
    priority: tuple[PriorityConfig, ...] = ()
    # the learner's per-row scores some agent's rule asks back ("td_abs" and the rules' own; their Needs)
    learner_scores: tuple[str, ...] = ()
    # the scores the learner computes for the rules after each update, beyond |δ| (each rule's `learner_scores`)
    rule_scores: tuple[LearnerScore, ...] = ()
    # a learner-side pick (LaBER): each learner minibatch is drawn as `candidates` × batch rows, and the agents
    # marked in `select` pick theirs among them with their rule's `pick` by fresh |δ|; the others take their first
    # batch-size draws
    candidates: int = 1
    select: tuple[bool, ...] = ()
    pick: Callable[..., tuple[np.ndarray, np.ndarray]] | None = None
    # the agents whose actor trains on a uniform minibatch of its own, drawn apart from the critic's (their team's
    # actor_batch = "uniform" under a prioritised rule, TeamConfig.uniform_actor), length N
    uniform_actor: tuple[bool, ...] = ()
    # float32[N, act_dim]: 1 where the agent has that action entry, 0 on padding (agents whose action sizes differ,
    # env.factory); None when every agent uses every entry (the built-in tasks)
    act_mask: np.ndarray | None = None
    # Gumbel-softmax actors (A17): maddpg.discrete for the built-in tasks (MPE's 5-way action), or an env.factory
    # environment whose agents' action spaces are Discrete
    discrete: bool = False
    # how each flat observation splits into entities (cmcl.envs.entities), for maddpg.networks = "entity";
    # None for an env.factory environment (no known layout)
    entities: EntityLayout | None = None

    @property
    def teacher_error_squared(self) -> list[bool]:
        """Per teacher agent (`teacher_agents`): whether its teachers' error is squared (its team's
        `priority.difficulty_error`), as both runners score rows (cmcl.learners.network_steps.teacher_errors)."""
        priority = self.priority or (PriorityConfig(),) * self.num_agents
        return [priority[a].difficulty_error == "squared" for a in self.teacher_agents]

    @property
    def permuted_select(self) -> tuple[bool, ...]:
        """Per agent, length N: whether it picks among candidates (`select`, LaBER) under its team's permuted control
        (`priority.difficulty_transform`); the buffer then draws the order its candidates' |δ| are read in
        (cmcl.replay.rules.laber.candidate_orders), as both runners sample."""
        priority = self.priority or (PriorityConfig(),) * self.num_agents
        return tuple(bool(pick) and p.difficulty_transform == "permuted"
                     for pick, p in zip(self.select or (False,) * self.num_agents, priority, strict=True))

    @property
    def team_of(self) -> list[str]:
        """Team name of every agent, length N."""
        names = [""] * self.num_agents
        for team, members in self.teams.items():
            for agent in members:
                names[agent] = team
        return names


def make_batched_env(config: Config, num_envs: int | None = None, seed: Any = None, auto_reset: bool = True,
                     render_mode: str | None = None):
    """The batched numpy twin of config.env.task stepping `num_envs` (default config.env.num_envs) worlds, or for
    `env.factory` that many copies of the user's environment behind the same interface (render_mode: theirs only),
    or with env.twin the factory's own batched twin (cmcl.envs.twins)."""
    env = config.env
    b = env.num_envs if num_envs is None else num_envs
    if env.twin and render_mode is None:  # the factory's vectorised twin (cmcl.envs.twins); drawing needs its env
        from cmcl.envs.twins import twin_for

        return twin_for(env.factory)(env.factory_kwargs, b, env.episode_length, seed, auto_reset)
    if env.factory:
        from cmcl.envs.factory import load_factory
        from cmcl.envs.parallel_vector import VectorParallelEnv

        kwargs = env.factory_kwargs if render_mode is None else {**env.factory_kwargs, "render_mode": render_mode}
        return VectorParallelEnv(load_factory(env.factory, kwargs), b, env.episode_length, seed=seed,
                                 auto_reset=auto_reset, team_of=env.team_of, success_key=env.success_key,
                                 coverage_key=env.coverage_key, factory=f"env.factory {env.factory!r}")
    from cmcl.envs.batched import BatchedSparseSpread, BatchedSparseTag

    twin = BatchedSparseSpread if env.task == "spread" else BatchedSparseTag
    return twin(b, env.world, episode_length=env.episode_length, seed=seed, auto_reset=auto_reset)


def make_parallel_env(config: Config, render_mode: str | None = None):
    """The PettingZoo ParallelEnv of config.env.task (reference dynamics, rendering)."""
    env = config.env
    if env.factory:
        from cmcl.envs.factory import load_factory

        return load_factory(env.factory, {**env.factory_kwargs, "render_mode": render_mode})()
    if env.task == "spread":
        from cmcl.envs.sparse_spread_v0 import SparseSpreadEnv as task_env
    else:
        from cmcl.envs.sparse_tag_v0 import SparseTagEnv as task_env
    return task_env(env.world, max_cycles=env.episode_length, render_mode=render_mode)


def agent_layout(config: Config, env) -> AgentLayout:
    """Per-agent algorithms and score needs from the team configs and the env's team membership.

    Raises ConfigError when the config's teams are not exactly the env's (a factory env's teams are known here
    first), naming the teams and their agents."""
    n = env.num_agents
    if set(env.teams) != set(config.teams):
        ids = getattr(env, "agent_ids", [str(i) for i in range(n)])
        members = {team: [ids[i] for i in idx] for team, idx in env.teams.items()}
        raise ConfigError(f"teams: the config names {sorted(config.teams)}, the environment's agents form the teams "
                          f"{members} (by agent-id prefix or env.team_of); give every one a [teams.<name>] table")
    algorithms, eta, isw, source, alpha = [""] * n, [0.0] * n, [False] * n, ["difficulty"] * n, [1.0] * n
    priority = [PriorityConfig()] * n
    teacher, icm, learner_scores, select, uniform_actor = [], [], set(), [False] * n, [False] * n
    for team, members in env.teams.items():
        spec = config.teams[team]
        needs = spec.needs
        for agent in members:
            algorithms[agent] = spec.algorithm
            eta[agent] = spec.effective_eta
            alpha[agent] = spec.effective_alpha()
            isw[agent] = spec.importance_weights
            priority[agent] = spec.priority
            source[agent] = needs.difficulty_source
            if needs.teachers:
                teacher.append(agent)
            if needs.icm or config.icm.intrinsic_reward_coef > 0:  # ρ as a reward: every agent's ICM trains
                icm.append(agent)
            learner_scores.update(needs.learner_scores)
            select[agent] = spec.rule.pick is not None
            uniform_actor[agent] = spec.uniform_actor
    teams = [config.teams[t] for t in env.teams]
    act_dim = DISCRETE_ACT_DIM if config.maddpg.discrete else env.act_dim
    discrete = acts_discretely(config, env)
    mask = getattr(env, "act_mask", None)
    return AgentLayout(num_agents=n, obs_dim=env.obs_dim, env_act_dim=env.act_dim, act_dim=act_dim,
                       teams={k: list(v) for k, v in env.teams.items()}, algorithms=tuple(algorithms),
                       eta=tuple(eta),
                       alpha=tuple(alpha),
                       importance_weights=tuple(isw), difficulty_source=tuple(source),
                       floor=tuple(p.uniform_floor for p in priority), priority=tuple(priority),
                       learner_scores=tuple(sorted(learner_scores)), select=tuple(select),
                       uniform_actor=tuple(uniform_actor),
                       candidates=max((t.rule.candidates(t.options) for t in teams), default=1),
                       pick=next((t.rule.pick for t in teams if t.rule.pick is not None), None),
                       rule_scores=tuple({s.name: s for t in teams for s in t.rule.learner_scores}.values()),
                       teacher_agents=np.asarray(sorted(teacher), dtype=np.int64),
                       icm_agents=np.asarray(sorted(icm), dtype=np.int64),
                       act_mask=None if mask is None or mask.all() else mask.copy(), discrete=discrete,
                       entities=entity_layout(getattr(env, "params", None)))


def acts_discretely(config: Config, env: Any) -> bool:
    """Whether `config`'s agents act through Gumbel-softmax actors in `env` (its batched world): maddpg.discrete for
    the built-in tasks' 5-way action, or an env.factory world with Discrete action spaces (`env.discrete`)."""
    return config.maddpg.discrete or bool(getattr(env, "discrete", False))


def layout_of(config: Config) -> AgentLayout:
    """The agent layout of `config`, read from one world of its batched twin (what every role that does not step the
    worlds itself builds its networks from)."""
    return agent_layout(config, make_batched_env(config, num_envs=1))


def _require_entity_layout(layout: AgentLayout, key: str, kind: str) -> None:
    """ConfigError when `key` asks for entity networks in a world without an entity layout (an env.factory one)."""
    if kind == "entity" and layout.entities is None:
        raise ConfigError(f"{key} = 'entity' needs a built-in task (env.task spread or tag): this environment's "
                          "observations have no known entity layout")


def build_maddpg(config: Config, layout: AgentLayout, seed: int) -> MADDPG:
    """The stacked MADDPG learner of every agent."""
    from cmcl.learners.maddpg import MADDPG

    m = config.maddpg
    _require_entity_layout(layout, "maddpg.networks", m.networks)
    return MADDPG(layout.num_agents, layout.obs_dim, layout.act_dim, hidden=m.hidden, actor_lr=m.actor_lr,
                  critic_lr=m.critic_lr, gamma=m.gamma, tau=m.tau, grad_clip=m.grad_clip, discrete=layout.discrete,
                  seed=seed, act_mask=layout.act_mask, networks=m.networks, entity_layout=layout.entities,
                  entity_pool=m.entity_pool, target_scores=any(s.target_critic for s in layout.rule_scores),
                  entity_nearest=m.entity_nearest, assignment_loss=m.assignment_loss, entity_holder=m.entity_holder,
                  holder_rule=m.holder_rule)


def build_samplers(config: Config, layout: AgentLayout) -> list:
    """One sampler per agent, built by its team's rule (`Rule.sampler`) from the agent's settings (its team's
    priority table, α_s, η, difficulty source) and the team's rule options; validated at config load, not here."""
    r, samplers = config.replay, []
    for a, team in enumerate(layout.team_of):
        spec, p = config.teams[team], layout.priority[a]
        args = SamplerArgs(capacity=r.capacity, alpha=layout.alpha[a], backend=r.backend, eps=r.priority_eps, agent=a,
                           algorithm=layout.algorithms[a], eta=layout.eta[a],
                           difficulty_source=layout.difficulty_source[a], difficulty_norm=p.difficulty_norm,
                           difficulty_squared=p.difficulty_error == "squared", cp_input=p.cp_input,
                           lam_max=config.curriculum.lam_max, reversed_difficulty=p.difficulty_transform == "reversed",
                           permuted=p.difficulty_transform == "permuted", floor=layout.floor[a])
        samplers.append(spec.rule.sampler(args, spec.options))
    return samplers


def build_replay(config: Config, layout: AgentLayout) -> ReplayBuffer:
    """Replay storage with one sampling distribution per agent, its team's rule's (`build_samplers`; IS β is passed
    at sample time)."""
    storage = TransitionStorage(capacity=config.replay.capacity, n_agents=layout.num_agents, obs_dim=layout.obs_dim,
                                act_dim=layout.act_dim, n_folds=config.teachers.num_folds)
    return ReplayBuffer(storage, build_samplers(config, layout), min_size=max(1, config.maddpg.warmup),
                        lam_max=config.curriculum.lam_max, control_seed=control_seed(config.run.seed))


def control_seed(seed: int) -> np.random.SeedSequence:
    """Seed of the permuted control's permutations: a stream of its own for run seed `seed` (independent of the
    loop's env / noise / sampler streams, and the same in the inline loop and the replay server)."""
    return np.random.SeedSequence([int(seed), CONTROL_STREAM])


def build_teachers(config: Config, layout: AgentLayout, seed: int, num_folds: int | None = None
                   ) -> TeacherEnsemble | None:
    """All K teachers of every teacher-using agent as one ensemble (or `num_folds` of them: a service teacher actor
    hosting some folds), or None when no team uses teachers."""
    if layout.teacher_agents.size == 0:
        return None
    from cmcl.scorers.teachers import TeacherEnsemble

    t = config.teachers
    _require_entity_layout(layout, "teachers.networks", t.networks)
    in_dim = layout.num_agents * (layout.obs_dim + layout.act_dim)
    return TeacherEnsemble(int(layout.teacher_agents.size), in_dim=in_dim,
                           num_folds=t.num_folds if num_folds is None else num_folds, hidden=t.hidden, lr=t.lr,
                           seed=seed, networks=t.networks, agents=layout.teacher_agents,
                           entity_layout=layout.entities, act_dim=layout.act_dim,
                           entity_pool=config.maddpg.entity_pool, entity_nearest=config.maddpg.entity_nearest,
                           entity_holder=config.maddpg.entity_holder,
                           entity_holder_rule=config.maddpg.holder_rule)


def build_icm(config: Config, layout: AgentLayout, seed: int) -> ICM | None:
    """Per-agent ICMs of every curiosity-using agent, or None when no team uses curiosity."""
    if layout.icm_agents.size == 0:
        return None
    from cmcl.scorers.icm import ICM

    c = config.icm
    _require_entity_layout(layout, "icm.networks", c.networks)
    return ICM(int(layout.icm_agents.size), layout.obs_dim, layout.act_dim, feature_dim=c.feature_dim,
               hidden=c.hidden, beta_forward=c.beta_forward, lr=c.lr, discrete=layout.discrete, seed=seed,
               networks=c.networks, agents=layout.icm_agents, entity_layout=layout.entities,
               entity_pool=config.maddpg.entity_pool, entity_nearest=config.maddpg.entity_nearest,
               entity_holder=config.maddpg.entity_holder, entity_holder_rule=config.maddpg.holder_rule)


def build_schedule(config: Config) -> CurriculumSchedule:
    """λ schedule; the default stride reaches λ_max at half of run.episodes × episode_length env steps."""
    c = config.curriculum
    stride = config.curriculum_stride()
    growth = default_growth(config.total_env_steps, c.lam0, c.lam_max)
    return CurriculumSchedule(lam0=c.lam0, lam_max=c.lam_max, stride=stride, warmup_steps=config.maddpg.warmup,
                              kind=c.kind, growth=growth)


def to_env_actions(actions: np.ndarray, discrete: bool) -> np.ndarray:
    """Policy output float32[B, N, act_dim] -> env force float32[B, N, 2] in [-1, 1].

    `discrete`: config.maddpg.discrete (the built-in tasks' variant). Continuous actions, and the Gumbel-softmax
    samples of an env.factory environment with Discrete actions (its adapter takes their argmax), pass through;
    the discrete MPE action (no-op, +x, -x, +y, -y) maps to (p[+x] - p[-x], p[+y] - p[-y]) as mpe2 does for its
    continuous action vector.
    """
    if not discrete:
        return actions
    return np.stack([actions[..., 1] - actions[..., 2], actions[..., 3] - actions[..., 4]], axis=-1)


def beta_is(config: Config, env_steps: int) -> float:
    """PER importance-sampling exponent, annealed linearly from beta_is_start to beta_is_end over the run."""
    r = config.replay
    frac = min(1.0, env_steps / max(1, config.total_env_steps))
    return r.beta_is_start + (r.beta_is_end - r.beta_is_start) * frac
