"""Sparse MPE tasks (ALGORITHM.md §6): PettingZoo reference envs and batched numpy twins.

Where it sits: rollout workers step the batched twins (`cmcl.envs.batched`); evaluation, rendering and
the parity tests use the PettingZoo versions (`cmcl.envs.sparse_spread_v0`, `cmcl.envs.sparse_tag_v0`,
built on mpe2's World). `cmcl.envs.state` copies a world state between the two; `cmcl.envs.metrics`
holds coverage / success / predator-win. Your own environment (`env.factory`): `cmcl.envs.factory` loads and
checks it, `cmcl.envs.parallel_vector` steps M copies of it behind the twins' interface, `cmcl.envs.examples` holds
one written from scratch (docs/OWN_ENVIRONMENT.md). The sparse tasks (docs/SPARSE_TASKS.md), trained through
`env.factory`: `cmcl.envs.sparse_nav_v0` (VACL, SPMARL navigation; twin `cmcl.envs.sparse_nav`), `cmcl.envs.cmae_grids`.
Submodules are imported on demand so that a rollout worker does not pay for pettingzoo and mpe2.
"""
