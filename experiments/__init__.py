"""The grid runner: one grid registry, one runner, one results store.

A *grid* is a named list of learning runs (task, algorithm per team, seed, budget, overrides); every run trains in
its own subprocess (``python -m cmcl train --runner inline``: the service's roles in one process, or ``--runner
service``: on the embedded Ray), is summarised once finished (measures, held-out evaluation, 100-episode window
curves) and its summary is stored as ``<results>/summaries/<run id>.json``. The tables and figures drawn from the
summaries belong to the research record beside the package (``python -m lab report``, lab/report/).

    python -m experiments run GRID [GRID ...] [--seeds 0 1 2] [--jobs N] [--out DIR]

Modules: grids (the registry: which runs, which results folder), run_spec (what a run is: `Run`, and ROOT),
screen_arms (the screen's arms, seeds and the permuted control's key), screen_selection (the screen's selection
rule), confirm_arms (the confirmation's arms, from the screen's selection), labels (the arms' names), own_envs (the
own-environment grid's settings and measures), runner (subprocesses that die with the runner; the resume rule),
measures (one run's summary), provenance (which code a summary ran), store (summaries on disk, and the older
time-to-solve log).
"""
