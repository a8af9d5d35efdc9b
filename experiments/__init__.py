"""The learning experiments of the project: one grid registry, one runner, one results store, one report.

A *grid* is a named list of learning runs (task, algorithm per team, seed, budget, overrides); every run trains in
its own subprocess (``python -m cmcl train --runner inline``: the service's roles in one process, or ``--runner
service``: on the embedded Ray), is
summarised once finished (measures, held-out evaluation, 100-episode window curves) and its summary is stored as
``<results>/summaries/<run id>.json``. The report turns the summaries into the tables of docs/RESULTS.md (between
its ``<!-- name:begin -->`` / ``<!-- name:end -->`` markers) and the figures.

    python -m experiments run GRID [GRID ...] [--seeds 0 1 2] [--jobs N] [--out DIR]
    python -m experiments report [--update docs/RESULTS.md]
    python -m experiments figures

Modules: grids (the registry: which runs, which results folder), run_spec (what a run is: `Run`, and ROOT),
screen_arms (the screen's arms, seeds and the permuted control's key), runner (subprocesses that die with the runner;
the resume rule), measures (one run's summary), store (summaries on disk, and the older time-to-solve log),
stats (intervals and tests), tables / curriculum_tables / screen_table / confirm_tables (markdown), figures
(PNGs), report (the blocks of docs/RESULTS.md).
"""
