"""The grid registry: every learning grid of the project, the runs it is made of, and where its results live.

Grids (the shared defaults of cmcl/config/ for every algorithm unless a run names overrides):

* ``spread``: sparse cooperative navigation N=4 with maddpg, per, acl and cmcl, 20,000 episodes, no early stop
  (the paper's Figs. 8-9);
* ``tag``: predator-prey, predators learning with each algorithm against MADDPG prey (Fig. 12);
* ``winrate``: CMCL predators against ACL prey and against PER-MADDPG prey (Fig. 13);
* ``ablations``: CMCL on navigation with one setting changed at a time (ABLATIONS; the unchanged CMCL runs of
  ``spread`` are their reference);
* ``curriculum`` (the pre-registered protocol of lab/RESULTS.md): navigation N=4 with the arms of
  CURRICULUM_ARMS -- maddpg, per, acl, cmcl, and CMCL's two controls, ``cmcl_permuted`` (its priorities shuffled
  across rows: same ESS, no information) and ``cmcl_anti`` (difficulty reversed) -- progress rows every 200
  episodes so that the summary holds the sampling distribution's ESS and reward-row shares over training;
* ``curriculum_hard``: the same arms on the calibrated harder navigation of configs/spread_hard.toml;
* ``curriculum_tag``: the same arms as the predators of sparse predator-prey (configs/tag_<algorithm>.toml), the
  prey MADDPG (the paper's Fig. 12 at the rank-difficulty defaults);
* ``screen``: candidate sampling rules of the registry (cmcl.replay.registry) on the harder task, MADDPG and
  PER-MADDPG beside them for reference, in two rounds: every arm at seed 100, then MADDPG and round one's three best
  candidates at seeds 101-102 (experiments.screen_arms);
* ``confirm``: the rules the screen's committed summaries select (experiments.screen_selection.selection),
  MADDPG and each selected rule's permuted control, on the harder task, seeds 0-19 with an interim look after seeds
  0-9; its arms (experiments.confirm_arms) refuse to exist (ConfirmNotReady) while the screen has no selection;
* ``make_run``: the exact `make run` (MAKE_RUN), one run per seed; run it with --jobs 1 on an idle
  machine;
* ``schedule``: time to solve navigation with MADDPG inline, maddpg.update_every x maddpg.batch_size, each run
  stopped once its 100-episode moving-average coverage reaches 0.95 or after 900 s of training;
* ``algorithms``: time to solve with each algorithm, inline and on the embedded service, same stops;
* ``scale``: navigation with more agents, each cell of SCALE_CELLS (agent count x networks) with
  MADDPG, the full budget, progress rows every 200 episodes; the per-agent cells are the baseline;
* ``own_envs``: environments no one here wrote (experiments.own_envs.OWN_ENVS) through
  ``env.factory``, inline and on the embedded service, each with its own budget and settings;
* ``sparse_calibration`` (docs/SPARSE_TASKS.md): uniform MADDPG and PER-MADDPG on each sparse task of
  SPARSE_TASKS (its preset configs/<task>_maddpg.toml, through ``env.factory``), inline, the preset's budget.
* ``sparse_recalibration``: uniform MADDPG again on the tasks of SPARSE_RECALIBRATED, whose presets' learner
  settings changed after their calibration, the same way;
* ``sparse_screen`` (docs/SPARSE_TASKS.md, its screen protocol): the task-curriculum and intrinsic-reward candidates
  of each round of SCREEN_ROUNDS on vacl_n4 and push_box (presets configs/<task>_curriculum.toml, _radius.toml,
  _intrinsic.toml), uniform MADDPG sampling, inline, the preset's budget, at the round's seeds (first rounds 0-2, second
  rounds 200-202);
* ``sparse_scale``: on each task whose screen chose curiosity as a reward, that candidate with a frozen ICM at coef 1
  for 300 s at the screen's seeds (the scale of the confirmation's control);
* ``sparse_confirm`` (its confirmation protocol): per task the screen chose a candidate for, the candidate, uniform
  MADDPG and the control (experiments.sparse_arms), seeds 100-109.

Runs are ordered seed outermost (seed k of every cell before any seed k+1), so a grid stopped part-way has
balanced arms. A run's id names its summary file, so ids never change once results exist.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from cmcl.config import load_data
from cmcl.replay.registry import PAPER_ALGORITHMS
from experiments.confirm_arms import arms_at_seed, screen_choice
from experiments.own_envs import OWN_ENVS
from experiments.run_spec import ROOT, Run
from experiments.screen_arms import PERMUTED_CONTROL, ROUND_ONE_SEEDS, ROUND_TWO_SEEDS, SCREEN_ARMS, rule_algorithm
from experiments.screen_selection import round_two_arms
from experiments.sparse_arms import (
    FROZEN_AT_COEF_1,
    SCALE_SECONDS,
    SCREEN_ROUNDS,
    SPARSE_SCREEN,
    SPARSE_SCREEN_TASKS,
    config_of,
    confirm_arms,
    current_round,
    is_curriculum,
    sparse_choice,
)
from experiments.store import ResultsStore

RESULTS = ROOT / "lab" / "results"
EPISODES = 20_000  # the paper's budget per run

# arm -> (config file, --set overrides) of the curriculum grids; every other setting is the shared default. An
# override of "teams.<team>." is the learning team's: the agents of navigation, the predators of predator-prey
# (`team_sets`). PERMUTED_CONTROL, the permuted control's key: experiments.screen_arms.
CURRICULUM_ARMS = {
    "maddpg": ("spread_maddpg.toml", []),
    "per": ("spread_per.toml", []),
    "acl": ("spread_acl.toml", []),
    "cmcl": ("spread_cmcl.toml", []),
    "cmcl_permuted": ("spread_cmcl.toml", [PERMUTED_CONTROL]),
    "cmcl_anti": ("spread_cmcl.toml", ["teams.<team>.priority.difficulty_transform=reversed"]),
}
HARD_CONFIG = "spread_hard.toml"  # the calibrated harder task (lab/RESULTS.md, "A harder task: calibration")
# grid -> {arm: --set overrides}: CMCL on the harder task with one setting changed, every other setting the
# curriculum_hard grid's, whose MADDPG and default CMCL runs stand beside them in the report.
# curriculum_stride, the λ schedule: other strides than the default 3e-6 per env step (λ from 0.1 to 1 at half of the
# 20,000 episodes); with rank difficulty KP can exclude rows only while λ < 0.5: the first ~2,350 (×2), ~4,570
# (default) or ~9,020 (×½) episodes. curriculum_eta: the curiosity weight η = 1 (default 0.5) in CI = KP + η·CP.
HARD_SETTING_GRIDS: dict[str, dict[str, list[str]]] = {
    "curriculum_stride": {
        "cmcl_stride_x2": ["curriculum.stride=6e-6"],  # λ_max at a quarter of training
        "cmcl_stride_half": ["curriculum.stride=1.5e-6"],  # λ_max at the end
    },
    "curriculum_eta": {"cmcl_eta1": ["teams.agent.eta=1.0"]},
}
# The rule screen: its arms (arm -> --set overrides), references, rounds and seeds are experiments.screen_arms's.
# The rule confirmation (protocol in lab/RESULTS.md, "the confirmation's protocol"): its arms come from the
# screen's selection, its seeds (CONFIRM_SEEDS) and interim look from experiments.confirm_arms.

ABLATIONS = {  # name -> (config file, --set overrides, episode budget or None for the grid's) of CMCL variants
    "eta0": ("spread_cmcl.toml", ["teams.agent.eta=0.0"], None),
    "eta1": ("spread_cmcl.toml", ["teams.agent.eta=1.0"], None),
    "k2": ("spread_cmcl.toml", ["teachers.num_folds=2"], None),
    # the default since 2026-12 (A1); kept so its committed 5-seed results (run at the old "max" default) stay named
    "rank": ("spread_cmcl.toml", ["teams.agent.priority.difficulty_norm=rank"], None),
    "max": ("spread_cmcl.toml", ["teams.agent.priority.difficulty_norm=max"], None),  # the pre-2026-12 normalisation
    "stride_x2": ("spread_cmcl.toml", ["curriculum.stride=6e-6"], None),  # λ_max at a quarter of training
    "stride_half": ("spread_cmcl.toml", ["curriculum.stride=1.5e-6"], None),  # λ_max at the end
    "is_on": ("spread_cmcl.toml", ["teams.agent.is_correction=true"], None),
    # One update per world step: 16 times the updates, about 35 min a run here, so it runs the first 4,000
    # episodes only and is compared with the reference runs' first 4,000 episodes (prefix_reference_runs).
    "paper_schedule": ("paper/spread_cmcl.toml", [], 4_000),
}

@dataclass(frozen=True)
class ScaleCell:
    """One cell of the scale grid: N agents and N landmarks, MADDPG. config: a file under configs/; sets:
    its --set overrides; stages: the agent counts of an agent-count curriculum (python -m cmcl stages: each stage
    starts from the networks of the one before), () for one run; stage_episodes: episodes per stage; budget: episodes
    of the run (of its last stage's run, for stages), None for the grid's --episodes."""

    config: str
    sets: tuple[str, ...]
    stages: tuple[int, ...] = ()
    stage_episodes: tuple[int, ...] = ()
    budget: int | None = None


NO_CAP = "run.max_seconds=0"  # the presets' wall-clock caps off: every seed gets the same episodes, whatever the load
NO_HOLDER = "maddpg.entity_holder=false"  # the presets' holder margin (on in the presets): off, as these cells ran
# The first four cells ran first (one seed): entity networks cost 6x more per update at N = 8 (lab/RESULTS.md), so
# they trained for a wall-clock budget, 45 min or 15 min per stage (2 -> 4 -> 8), the "progress" cell also ended once
# the critics' TD-error learning progress stayed below 5% for three 500-episode windows (the old default,
# run.progress_signal = critic_loss; it never fired: lab/RESULTS.md). The later cells fill the
# agent-count curriculum's table at equal episodes: N = 4 and N = 16 with the presets' entity networks
# (configs/spread_n8.toml, configs/spread_n16.toml), N = 16 with the paper's per-agent networks, and N = 16 trained
# from scratch for the 3,040 episodes the preset trains after its N = 8 stage.
SCALE_CELLS: dict[str, ScaleCell] = {
    "n8_per_agent": ScaleCell("spread_maddpg.toml", ("env.num_agents=8",)),  # the paper's networks: the baseline
    "n8_entity": ScaleCell("spread_maddpg.toml", ("env.num_agents=8", "maddpg.networks=entity",
                                                  "run.max_seconds=2700")),
    "n8_entity_stages": ScaleCell("spread_maddpg.toml", ("maddpg.networks=entity", "run.max_seconds=900"), (2, 4, 8),
                                  (3_000, 5_000, 20_000)),
    "n8_entity_stages_progress": ScaleCell("spread_maddpg.toml", ("maddpg.networks=entity", "run.max_seconds=900",
                                                                  "run.stop_progress=0.05", "run.progress_window=500",
                                                                  "run.progress_patience=3",
                                                                  "run.progress_signal=critic_loss"), (2, 4, 8),
                                           (3_000, 5_000, 20_000)),
    "n4_entity": ScaleCell("spread_n8.toml", ("env.num_agents=4", NO_CAP, NO_HOLDER), budget=6_000),
    "n4_entity_stages": ScaleCell("spread_n8.toml", (NO_CAP, NO_HOLDER), (2, 4), (3_008, 3_000),
                                  budget=3_000),
    "n16_per_agent": ScaleCell("spread_maddpg.toml", ("env.num_agents=16", NO_CAP), budget=3_040),
    "n16_entity": ScaleCell("spread_n16.toml", ("run.init_from=", NO_CAP, NO_HOLDER), budget=3_040),
    # from scratch for as many episodes as the staged run trains in all (3,008 + 2,624 + 1,136 at N = 2, 4, 8, then
    # 3,040 at N = 16), all at N = 16: does the curriculum's gain survive equal episodes?
    "n16_entity_long": ScaleCell("spread_n16.toml", ("run.init_from=", NO_CAP, NO_HOLDER), budget=9_808),
}

# `make run` measured, not remembered: the Makefile's run target, one run per seed, one at a time, on an
# otherwise idle machine: the service, configs/spread_maddpg.toml (uniform replay; configs/spread_cmcl.toml until
# 2026-12-05), stop at a 100-episode moving-average coverage of 0.9 or after 300 s of training, or at the Makefile's
# RUN_EPISODES (MAKE_RUN_EPISODES; the config's 20,000 until 2026-12-06, which a fast machine used up in ~150 s) (the
# grid's runner adds --quiet and --metrics-port 0, and its own seed and run folder).
MAKE_RUN = {"config": "spread_maddpg.toml", "stop_coverage": 0.9, "max_seconds": 300.0}
MAKE_RUN_EPISODES = 60_000
UPDATE_EVERY, BATCHES = (1, 4, 16, 64), (128, 512)  # the schedule grid's maddpg.update_every x maddpg.batch_size
SOLVE_STOP_COVERAGE, SOLVE_MAX_SECONDS = 0.95, 900.0  # the time-to-solve grids' stops (moving average; seconds)


def curriculum_runs(name: str, seed: int, budget: int) -> list[Run]:
    """The arms of CURRICULUM_ARMS on the grid's task: navigation N=4 (``curriculum``), the harder navigation
    (``curriculum_hard``) or predator-prey, each arm's algorithm for the predators against MADDPG prey
    (``curriculum_tag``)."""
    runs = []
    for arm, (config, sets) in CURRICULUM_ARMS.items():
        algorithm, task, prey, team = arm.split("_")[0], "spread", None, "agent"
        if name == "curriculum_hard":  # the same arms on the harder task: its config, each algorithm
            config, sets = HARD_CONFIG, [f"teams.agent.algorithm={algorithm}", *sets]
        elif name == "curriculum_tag":  # the predators' config of each algorithm; its prey learn with MADDPG
            config, task, prey, team = f"tag_{algorithm}.toml", "tag", "maddpg", "predator"
        runs.append(Run(f"{name}_{arm}_s{seed}", name, task, algorithm, prey, seed, budget, arm=arm,
                        config=config, sets=tuple(team_sets(sets, team))))
    return runs


def team_sets(sets: list[str], team: str) -> list[str]:
    """`sets` with every "teams.<team>." override made `team`'s."""
    return [s.replace("teams.<team>.", f"teams.{team}.", 1) if s.startswith("teams.<team>.") else s for s in sets]


def setting_runs(name: str, seed: int, budget: int) -> list[Run]:
    """A grid of HARD_SETTING_GRIDS: its arms, CMCL on the harder task."""
    return [Run(f"{name}_{arm}_s{seed}", name, "spread", "cmcl", None, seed, budget, arm=arm, config=HARD_CONFIG,
                sets=tuple(sets))
            for arm, sets in HARD_SETTING_GRIDS[name].items()]


def rule_runs(name: str, arms: dict[str, list[str]], seed: int, budget: int) -> list[Run]:
    """The screen's or the confirmation's arms (arm -> overrides) on the harder task."""
    return [Run(f"{name}_{arm}_s{seed}", name, "spread", rule_algorithm(sets), None, seed, budget, arm=arm,
                config=HARD_CONFIG, sets=tuple(team_sets(sets, "agent")))
            for arm, sets in arms.items()]


def ablation_runs(seed: int, budget: int) -> list[Run]:
    return [Run(f"ablation_{name}_s{seed}", "ablations", "spread", "cmcl", None, seed,
                min(budget, own_budget or budget), ablation=name, config=config, sets=tuple(sets))
            for name, (config, sets, own_budget) in ABLATIONS.items()]


def paper_runs(name: str, seed: int, budget: int, algorithms: list[str]) -> list[Run]:
    """The spread, tag and winrate grids: one run per (task, predators' or agents' algorithm, prey)."""
    if name == "spread":
        cells = [("spread", a, None) for a in reversed(algorithms)]  # the longest (cmcl) first
    elif name == "tag":
        cells = [("tag", a, "maddpg") for a in reversed(algorithms)]
    else:
        cells = [("tag", "cmcl", prey) for prey in ("acl", "per")]
    return [Run(f"{task}_{a}_s{seed}" if prey in (None, "maddpg") else f"{task}_{a}_vs_{prey}_s{seed}",
                name, task, a, prey, seed, budget) for task, a, prey in cells]


def solve_runs(name: str, seed: int, budget: int, algorithms: list[str]) -> list[Run]:
    """The time-to-solve grids (schedule: MADDPG over update_every x batch; algorithms: inline and service)."""
    stops = {"stop_coverage": SOLVE_STOP_COVERAGE, "max_seconds": SOLVE_MAX_SECONDS}
    if name == "schedule":
        return [Run(f"schedule_inline_maddpg_u{every}_b{batch}_s{seed}", name, "spread", "maddpg", None, seed,
                    budget, sets=(f"maddpg.update_every={every}", f"maddpg.batch_size={batch}"), **stops)
                for every in UPDATE_EVERY for batch in BATCHES]
    return [Run(f"algorithms_{mode}_{a}_s{seed}", name, "spread", a, None, seed, budget, mode=mode, **stops)
            for mode in ("inline", "service") for a in reversed(algorithms)]


def make_run_runs(seed: int) -> list[Run]:
    """The make_run grid: `make run`'s command (MAKE_RUN, MAKE_RUN_EPISODES episodes) at `seed`, id
    "make_run_<algorithm>_s<seed>" (the ids "make_run_s<seed>" are the CMCL `make run` measured until 2026-12-05;
    their summaries stay). The algorithm is the one MAKE_RUN's config file trains."""
    algorithm = load_data(ROOT / "configs" / MAKE_RUN["config"])["teams"]["agent"]["algorithm"]
    return [Run(f"make_run_{algorithm}_s{seed}", "make_run", "spread", algorithm, None, seed, MAKE_RUN_EPISODES,
                mode="service", **MAKE_RUN)]


def scale_runs(seed: int, budget: int) -> list[Run]:
    """The scale grid: every cell of SCALE_CELLS with MADDPG at its budget (else the grid's), id
    "scale_<cell>_s<seed>"."""
    return [Run(f"scale_{name}_s{seed}", "scale", "spread", "maddpg", None, seed, cell.budget or budget, arm=name,
                config=cell.config, sets=tuple(cell.sets), stages=cell.stages,
                stage_episodes=cell.stage_episodes)
            for name, cell in SCALE_CELLS.items()]


def own_env_runs(seed: int) -> list[Run]:
    """The own_envs grid: every environment of OWN_ENVS on each runner, at its own budget and settings (both runners log
    a progress row every 2 s)."""
    return [Run(f"own_{name}_{mode}_s{seed}", "own_envs", "own_env", "maddpg", None, seed, env.budget, mode=mode,
                env=name, sets=(f"env.factory={env.factory}", *env.sets))
            for name, env in OWN_ENVS.items() for mode in ("inline", "service")]


# the sparse tasks (docs/SPARSE_TASKS.md), shortest budget first: task -> its preset under configs/
SPARSE_TASKS = {t: f"{t}_maddpg.toml" for t in ("push_box", "pass", "vacl_n4", "vacl_n8", "spmarl_n8")}
SPARSE_ALGORITHMS = ("maddpg", "per")  # uniform MADDPG and PER-MADDPG (arms; --arms maddpg runs the first alone)


# the tasks whose presets' learner settings changed after their calibration (docs/SPARSE_TASKS.md, "The learner's
# settings on vacl_n4" and "... on push_box"): uniform MADDPG is calibrated again there at the new settings
SPARSE_RECALIBRATED = ("vacl_n4", "push_box")


def sparse_run(grid_name: str, task: str, arm: str, seed: int, config: str, sets: tuple[str, ...],
               max_seconds: float | None = None, algorithm: str = "maddpg") -> Run:
    """One run of a sparse grid, id "<grid_name>_<task>_<arm>_s<seed>", through env.factory, at the budget of its
    preset configs/`config` (its run.episodes, and its run.max_seconds unless `max_seconds` is given); `algorithm`:
    its team's (the summary's label; `sets` sets it where it is not the preset's)."""
    preset = load_data(ROOT / "configs" / config)["run"]
    return Run(f"{grid_name}_{task}_{arm}_s{seed}", grid_name, "own_env", algorithm, None, seed,
               int(preset["episodes"]), arm=arm, config=config, env=task, sets=sets,
               max_seconds=float(preset["max_seconds"] if max_seconds is None else max_seconds))


def sparse_calibration_runs(seed: int, name: str = "sparse_calibration", tasks: tuple[str, ...] = tuple(SPARSE_TASKS),
                            algorithms: tuple[str, ...] = SPARSE_ALGORITHMS) -> list[Run]:
    """The sparse_calibration grid (`name`): every task of `tasks` with each of `algorithms` at its preset's
    budget, id "<name>_<task>_<algorithm>_s<seed>". The sparse_recalibration grid is uniform MADDPG on
    SPARSE_RECALIBRATED."""
    return [sparse_run(name, task, algorithm, seed, SPARSE_TASKS[task], (f"teams.agent.algorithm={algorithm}",),
                       algorithm=algorithm) for task in tasks for algorithm in algorithms]


def sparse_screen_runs(seed: int) -> list[Run]:
    """The sparse_screen grid: on each task, every candidate of each round of its screen (SCREEN_ROUNDS) that runs at
    `seed` and did not stop, at its preset's budget, id "sparse_screen_<task>_<candidate>_s<seed>"."""
    return [sparse_run("sparse_screen", task, c, seed, config_of(task, c), SPARSE_SCREEN[c][1])
            for task, rounds in SCREEN_ROUNDS.items() for r in rounds if seed in r.seeds and not r.stopped
            for c in r.candidates]


def sparse_scale_runs(seed: int, screen: list[dict]) -> list[Run]:
    """The sparse_scale grid: on each task whose screen chose curiosity as a reward, that candidate with a frozen
    ICM at coef 1 (FROZEN_AT_COEF_1) for SCALE_SECONDS at a screen seed, id "sparse_scale_<task>_<candidate>_s<seed>"
    (the confirmation's control scale, experiments.sparse_arms.frozen_coef) at a seed of the task's current round.
    SparseNotReady while the screen misses a run."""
    runs = []
    for task in SPARSE_SCREEN_TASKS:
        chosen = sparse_choice(screen, task).candidate
        if chosen is None or is_curriculum(chosen) or seed not in current_round(task).seeds:
            continue
        runs.append(sparse_run("sparse_scale", task, chosen, seed, config_of(task, chosen),
                               (*SPARSE_SCREEN[chosen][1], *FROZEN_AT_COEF_1), max_seconds=SCALE_SECONDS))
    return runs


def sparse_confirm_runs(seed: int, screen: list[dict], scale: list[dict]) -> list[Run]:
    """The sparse_confirm grid: on each task the screen chose a candidate for, its three arms (experiments.sparse_arms
    .confirm_arms) at the preset's budget, id "sparse_confirm_<task>_<arm>_s<seed>"; SparseNotReady while the screen
    or a control's reference runs miss a run."""
    return [sparse_run("sparse_confirm", task, arm, seed, config, sets) for task in SPARSE_SCREEN_TASKS
            for arm, (config, sets) in confirm_arms(screen, scale, task).items()]


GRIDS = {  # name -> results folder (its summaries/ and runs/)
    "spread": RESULTS / "reproduce", "tag": RESULTS / "reproduce", "winrate": RESULTS / "reproduce",
    "ablations": RESULTS / "reproduce", "curriculum": RESULTS / "curriculum",
    "curriculum_hard": RESULTS / "curriculum_hard", "curriculum_tag": RESULTS / "curriculum_tag",
    "curriculum_stride": RESULTS / "curriculum_stride", "curriculum_eta": RESULTS / "curriculum_eta",
    "screen": RESULTS / "screen", "confirm": RESULTS / "confirm", "make_run": RESULTS / "make_run",
    "schedule": RESULTS / "time_to_solve",
    "algorithms": RESULTS / "time_to_solve", "own_envs": RESULTS / "own_envs", "scale": RESULTS / "scale",
    "sparse_calibration": RESULTS / "sparse_calibration", "sparse_screen": RESULTS / "sparse_screen",
    "sparse_recalibration": RESULTS / "sparse_recalibration",
    "sparse_scale": RESULTS / "sparse_scale", "sparse_confirm": RESULTS / "sparse_confirm",
}


def screen_arms_at(seed: int, second: tuple[str, ...] | None) -> dict[str, list[str]]:
    """The screen's arms at `seed` (experiments.screen_arms): every arm in round one; in round two the arms `second`
    (`round_two_arms` of the screen's summaries; None, no arms, while round one misses a run). ValueError for a seed
    of neither round."""
    if seed in ROUND_ONE_SEEDS:
        return SCREEN_ARMS
    if seed not in ROUND_TWO_SEEDS:
        raise ValueError(f"--seeds: {seed} is not a seed of the screen (round one {list(ROUND_ONE_SEEDS)}, round two "
                         f"{list(ROUND_TWO_SEEDS)})")
    return {arm: SCREEN_ARMS[arm] for arm in second or ()}


def grid(names: list[str], seeds: list[int], algorithms: list[str] = PAPER_ALGORITHMS,
         budget: int = EPISODES, screen: Path | None = None, confirm: Path | None = None) -> list[Run]:
    """The runs of the named grids, seed outermost (every cell has seed k before any has seed k+1), duplicates
    (same id) once. screen: the results folder whose screen summaries decide the screen's round two and select the
    confirm grid's arms (default the registry's); ConfirmNotReady while they select none. confirm: the folder of the
    confirmation's summaries, whose interim look decides its later seeds (default the registry's). A round or half
    that waits for earlier runs has no runs yet: run the command again once they are in."""
    unknown = sorted(set(names) - set(GRIDS))
    if unknown:
        raise ValueError(f"grid: unknown {unknown}; known {sorted(GRIDS)}")
    screen = screen or GRIDS["screen"]
    chosen = screen_choice(screen) if "confirm" in names else ()
    confirmed = ResultsStore(confirm or GRIDS["confirm"]).load() if "confirm" in names else []
    second = round_two_arms(ResultsStore(screen).load()) if "screen" in names else None
    sparse = {"sparse_scale", "sparse_confirm"} & set(names)
    sparse_screen = ResultsStore(GRIDS["sparse_screen"]).load() if sparse else []
    sparse_scale = ResultsStore(GRIDS["sparse_scale"]).load() if "sparse_confirm" in names else []
    runs = []
    for seed in seeds:
        for name in names:
            if name in HARD_SETTING_GRIDS:
                runs += setting_runs(name, seed, budget)
            elif name == "screen":
                runs += rule_runs(name, screen_arms_at(seed, second), seed, budget)
            elif name == "confirm":
                runs += rule_runs(name, arms_at_seed(seed, chosen, confirmed), seed, budget)
            elif name == "make_run":
                runs += make_run_runs(seed)
            elif name.startswith("curriculum"):
                runs += curriculum_runs(name, seed, budget)
            elif name == "ablations":
                runs += ablation_runs(seed, budget)
            elif name == "own_envs":
                runs += own_env_runs(seed)
            elif name == "sparse_calibration":
                runs += sparse_calibration_runs(seed)
            elif name == "sparse_recalibration":
                runs += sparse_calibration_runs(seed, name, SPARSE_RECALIBRATED, ("maddpg",))
            elif name == "sparse_screen":
                runs += sparse_screen_runs(seed)
            elif name == "sparse_scale":
                runs += sparse_scale_runs(seed, sparse_screen)
            elif name == "sparse_confirm":
                runs += sparse_confirm_runs(seed, sparse_screen, sparse_scale)
            elif name == "scale":
                runs += scale_runs(seed, budget)
            elif name in ("schedule", "algorithms"):
                runs += solve_runs(name, seed, budget, list(algorithms))
            else:
                runs += paper_runs(name, seed, budget, list(algorithms))
    return list({r.id: r for r in runs}.values())


def prefix_reference_runs(runs: list[Run], full_budget: int) -> list[Run]:
    """For every ablation run with a smaller budget than the grid's, the unchanged CMCL run of its seed read up to
    that budget (same measures, held-out from its checkpoint at that episode): id "reference_e<B>_s<seed>", grid
    "ablation_reference", source the spread run's id, budget B."""
    refs = [Run(f"reference_e{r.budget}_s{r.seed}", "ablation_reference", "spread", "cmcl", None, r.seed, r.budget,
                source=f"spread_cmcl_s{r.seed}") for r in runs if r.grid == "ablations" and r.budget < full_budget]
    return list({r.id: r for r in refs}.values())
