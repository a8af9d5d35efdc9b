"""maddpg: MADDPG's uniform replay (the paper's baseline, ALGORITHM.md §5): P(j) = 1/|D|, IS weights of 1.

The sampler is cmcl.replay.sampling.UniformSampling (the actors' own uniform minibatches draw from it too). It reads
no score, so rows carried from fewer agents (run.carry_replay) may be drawn.
"""

from __future__ import annotations

from cmcl.replay.rules.contract import Rule
from cmcl.replay.sampling import UniformSampling

RULE = Rule("maddpg", "uniform replay", lambda args, options: UniformSampling(args), "uniform", paper=True,
            masks_absent_agents=True, draws_uniformly=True)
