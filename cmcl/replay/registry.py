"""The registry of sampling rules: one line per rule, each rule's file under cmcl/replay/rules/ exporting `RULE`
(cmcl.replay.rules.contract.Rule: its options, sampler, hooks and capabilities). The config, the system builder,
the learner, both runners and the experiments read a rule's capabilities here; no rule's name is compared anywhere
else (tests/test_rules.py checks cmcl/ and services/).

An algorithm here is MADDPG with one sampling rule for its replay:

  maddpg  uniform replay                                  (the paper's baseline)
  per     PER-MADDPG, p = |δ|                             (the paper's baseline)
  acl     KP(ĉ, λ) of the teachers' difficulty            (the paper's ablation)
  cmcl    KP(ĉ, λ) + η·CP(ρ̂)                              (the paper's method, ALGORITHM.md)
  relo    max(0, δ² − δ_target²)                           (ReLo; learner only)
  rho     rank(δ² − ē): the learner's loss minus the teachers' held-out error (RHO-LOSS; teachers)
  lp      rank |Δē| of the held-out error, mixed with staleness (learning progress, PLR; teachers)
  laber   ∝ |δ| computed fresh on m·B uniform candidates (LaBER; learner only)

Adding a rule is its file under cmcl/replay/rules/ and one line in `RULE_MODULES`. A rule kept outside the package
(a file of its own anywhere) is registered with `register_file(path)`, which `replay.rule_files` does at config load
in every process of a run.
"""

from __future__ import annotations

import importlib
import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

from cmcl.replay.rules.acl import COVERAGE_WAITS
from cmcl.replay.rules.contract import Rule
from cmcl.replay.sampling import SamplerArgs

RULE_MODULES = (
    "cmcl.replay.rules.maddpg",
    "cmcl.replay.rules.per",
    "cmcl.replay.rules.acl",
    "cmcl.replay.rules.cmcl",
    "cmcl.replay.rules.relo",
    "cmcl.replay.rules.reducible",
    "cmcl.replay.rules.progress",
    "cmcl.replay.rules.laber",
)
REGISTRY: dict[str, Rule] = {}
__all__ = ["COVERAGE_WAITS", "REGISTRY", "Rule", "build_sampler", "register", "register_file", "spec_of"]


def register(rule: Rule) -> Rule:
    """Add `rule` under its name (again: replaced, so a reloaded file registers anew) -> the rule."""
    REGISTRY[rule.name] = rule
    return rule


def register_file(path: str | Path) -> Rule:
    """Import the rule file at `path` (a module defining RULE) once per process and register its RULE."""
    path = Path(path).resolve()
    name = f"cmcl_rule_file_{path.stem}"
    module = sys.modules.get(name)
    if module is None or getattr(module, "__file__", None) != str(path):
        spec = importlib.util.spec_from_file_location(name, path)
        if spec is None or spec.loader is None:
            raise ValueError(f"replay.rule_files: {str(path)!r} is not a Python file")
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    if module.RULE.name in ALGORITHMS:
        raise ValueError(f"replay.rule_files: {str(path)!r} names its rule {module.RULE.name!r}, a rule of "
                         f"cmcl/replay/rules/ ({list(ALGORITHMS)}); give it a name of its own")
    return register(module.RULE)


for _module in RULE_MODULES:
    register(importlib.import_module(_module).RULE)
ALGORITHMS: tuple[str, ...] = tuple(REGISTRY)  # the package's own rules (a rule file registered later is not here)
PAPER_ALGORITHMS: tuple[str, ...] = tuple(name for name, rule in REGISTRY.items() if rule.paper)


def spec_of(algorithm: str) -> Rule:
    """The rule registered as `algorithm`; ValueError naming the known ones otherwise."""
    try:
        return REGISTRY[algorithm]
    except KeyError:
        raise ValueError(f"algorithm must be one of {list(REGISTRY)}, got {algorithm!r}") from None


def build_sampler(algorithm: str, args: SamplerArgs, options=None):
    """The sampler of one agent learning with `algorithm` under `options` (None: the rule's defaults); η is 0 for
    a rule without one, whatever `args` says."""
    rule = spec_of(algorithm)
    args = replace(args, algorithm=algorithm, eta=args.eta if rule.uses_eta else 0.0)
    return rule.sampler(args, rule.options() if options is None else options)


def sampling_name(algorithm: str) -> str:
    """The metrics' name of `algorithm`'s sampling distribution ("uniform", "per", "acl", ...), without building it."""
    return spec_of(algorithm).sampling


def uses_lambda(names) -> bool:
    """Whether any of the given rules' priorities reads the curriculum factor λ (acl, cmcl)."""
    return any(spec_of(a).uses_lambda for a in names)


def early_notes(names) -> list[str]:
    """The distinct `early_note`s of the given rules, for the progress line while λ < 0.5."""
    return list(dict.fromkeys(spec_of(a).early_note for a in names if spec_of(a).early_note))
