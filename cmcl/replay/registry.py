"""The registry of algorithms: one spec per algorithm, read by the config, the system builder, the buffer, both
runners, the metrics and the experiments (issue 36). No algorithm name is compared as a string anywhere else.

An algorithm here is MADDPG with one sampling rule for its replay: the rule's sampler class (the closed protocol of
`cmcl.replay.sampling`), the scores it needs (the K-fold teachers' difficulty, the ICM's curiosity, the learner's
per-row losses), its default sampling exponent α_s (eq. 20) and whether importance-sampling weights correct the
critic. Adding a rule is its sampler's file under cmcl/replay/rules/, its test, and one line in `REGISTRY`. Every
prioritised rule (`AlgorithmSpec.prioritised`: all but maddpg) also takes a team's uniform floor and its actor_batch
("uniform": the actor trains on a uniform minibatch of its own, cmcl.replay.buffer_steps.sample_owner_batches).

  maddpg  uniform replay                                  (the paper's baseline)
  per     PER-MADDPG, p = |δ|                             (the paper's baseline)
  acl     KP(ĉ, λ) of the teachers' difficulty            (the paper's ablation)
  cmcl    KP(ĉ, λ) + η·CP(ρ̂)                              (the paper's method, ALGORITHM.md)
  relo    max(0, δ² − δ_target²)                           (ReLo; learner only)
  rho     rank(δ² − ē): the learner's loss minus the teachers' held-out error (RHO-LOSS; teachers)
  lp      rank |Δē| of the held-out error, mixed with staleness (learning progress, PLR; teachers)
  laber   ∝ |δ| computed fresh on m·B uniform candidates (LaBER; learner only)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from cmcl.replay.rules.laber import CANDIDATES, LargeBatchSampling
from cmcl.replay.rules.progress import HeldOutProgressSampling
from cmcl.replay.rules.reducible import HeldOutReducibleSampling
from cmcl.replay.rules.relo import ReducibleLossSampling
from cmcl.replay.sampling import CurriculumSampling, PrioritizedSampling, SamplerArgs, UniformSampling


@dataclass(frozen=True)
class Needs:
    """What one team's agents need from the other roles: teachers (the K-fold difficulty column), icm (the
    curiosity column), learner_scores (the learner's per-row losses fed back: "td_abs", "target_td_abs"),
    difficulty_source ("difficulty" from the teachers, or "td_abs": ACL td_self's own |δ|)."""

    teachers: bool = False
    icm: bool = False
    learner_scores: tuple[str, ...] = ()
    difficulty_source: str = "difficulty"


@dataclass(frozen=True)
class AlgorithmSpec:
    """One registered algorithm.

    name: the config's `teams.<team>.algorithm`. summary: one line for --help, docs and reports. sampler: the
    sampler class (built with a SamplerArgs). sampling: its name in the metrics ("sampling.modes"). default_alpha:
    α_s when no config sets one (A8). importance_weights: IS weights on the critic when `is_correction` is unset
    (A9). needs: the scores it needs, given the team's config (`team` has eta and acl_variant). uses_eta: η
    enters its priority. paper: one of the paper's four compared algorithms (ALGORITHM.md §5). early_note: what is
    normal while λ < 0.5, for the progress line ("" = nothing to say). candidates: m of LaBER (1 for the others).
    uses_lambda: the curriculum factor λ enters its priority (the progress line shows λ only then)."""

    name: str
    summary: str
    sampler: type
    sampling: str
    default_alpha: float = 1.0
    importance_weights: bool = False
    needs: Callable[[Any], Needs] = lambda team: Needs()
    uses_eta: bool = False
    paper: bool = False
    early_note: str = ""
    candidates: int = 1  # m: the learner picks each minibatch among m·B candidate rows (LaBER); 1 = it takes them
    uses_lambda: bool = False

    @property
    def prioritised(self) -> bool:
        """Whether the rows the critic trains on are drawn other than uniformly (every rule but maddpg): LaBER's
        candidates are uniform, its pick is not. A team's `actor_batch` = "uniform" acts on these rules only."""
        return not (self.sampler is UniformSampling and self.candidates == 1)


COVERAGE_WAITS = ", cov may wait"  # the part of KP_EXCLUDES a run without a coverage metric is not shown
KP_EXCLUDES = "normal while λ < 0.5: KP excludes the hardest rows" + COVERAGE_WAITS


def _acl_needs(team: Any) -> Needs:
    if team.acl_variant == "td_self":
        return Needs(learner_scores=("td_abs",), difficulty_source="td_abs")
    return Needs(teachers=True)


REGISTRY: dict[str, AlgorithmSpec] = {s.name: s for s in (
    AlgorithmSpec("maddpg", "uniform replay", UniformSampling, "uniform", paper=True),
    AlgorithmSpec("per", "PER-MADDPG: p = |δ| + ε (Schaul et al.)", PrioritizedSampling, "per", 0.6, True,
                  lambda team: Needs(learner_scores=("td_abs",)), paper=True),
    AlgorithmSpec("acl", "the K-fold priority KP(ĉ, λ) alone", CurriculumSampling, "acl", needs=_acl_needs,
                  paper=True, early_note=KP_EXCLUDES, uses_lambda=True),
    AlgorithmSpec("cmcl", "CI = KP(ĉ, λ) + η·CP(ρ̂): the paper's method", CurriculumSampling, "cmcl",
                  needs=lambda team: Needs(teachers=True, icm=team.eta > 0), uses_eta=True, paper=True,
                  early_note=KP_EXCLUDES, uses_lambda=True),
    AlgorithmSpec("relo", "ReLo: p = max(0, δ² − δ_target²) + ε (Sujit et al.)", ReducibleLossSampling, "relo", 0.6,
                  True, lambda team: Needs(learner_scores=("td_abs", "target_td_abs"))),
    AlgorithmSpec("rho", "reducible held-out loss: rank(δ² − ē), ē the teachers' held-out error (RHO-LOSS)",
                  HeldOutReducibleSampling, "rho", needs=lambda team: Needs(teachers=True, learner_scores=("td_abs",))),
    AlgorithmSpec("lp", "held-out learning progress: rank |Δē| mixed with staleness (PLR)", HeldOutProgressSampling,
                  "lp", needs=lambda team: Needs(teachers=True)),
    AlgorithmSpec("laber", "LaBER: each minibatch picked ∝ fresh |δ| among 4·B uniform candidates (Lahire et al.)",
                  LargeBatchSampling, "laber", 1.0, True, candidates=CANDIDATES),
)}
ALGORITHMS: tuple[str, ...] = tuple(REGISTRY)
PAPER_ALGORITHMS: tuple[str, ...] = tuple(name for name, spec in REGISTRY.items() if spec.paper)
AlgorithmName = Literal[ALGORITHMS]  # the config's type for `teams.<team>.algorithm`


def spec_of(algorithm: str) -> AlgorithmSpec:
    """The spec of a registered algorithm; ValueError naming the known ones otherwise."""
    try:
        return REGISTRY[algorithm]
    except KeyError:
        raise ValueError(f"algorithm must be one of {list(ALGORITHMS)}, got {algorithm!r}") from None


def build_sampler(algorithm: str, args: SamplerArgs):
    """The sampler of one agent learning with `algorithm` (its spec's class built from `args`; η is 0 for a rule
    without one, whatever `args` says)."""
    spec = spec_of(algorithm)
    return spec.sampler(SamplerArgs(**{**args.__dict__, "algorithm": algorithm,
                                       "eta": args.eta if spec.uses_eta else 0.0}))


def sampling_name(algorithm: str) -> str:
    """The metrics' name of `algorithm`'s sampling distribution ("uniform", "per", "acl", ...), without building it."""
    return spec_of(algorithm).sampling


def uses_lambda(algorithms) -> bool:
    """Whether any of the given algorithms' priorities reads the curriculum factor λ (acl, cmcl)."""
    return any(spec_of(a).uses_lambda for a in algorithms)


def early_notes(algorithms) -> list[str]:
    """The distinct `early_note`s of the given algorithms, for the progress line while λ < 0.5."""
    return list(dict.fromkeys(spec_of(a).early_note for a in algorithms if spec_of(a).early_note))
