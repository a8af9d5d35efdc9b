"""The report: the markdown blocks of lab/RESULTS.md, README.md and docs/LEARNING.md and the figures, drawn from
the grid runner's summaries (report: the blocks and the page update; stats: intervals and tests; tables /
curriculum_tables / screen_table / confirm_tables / own_env_table / make_run_table: markdown; quoted*: the numbers
the pages quote; figures / curriculum_figure: PNGs; stalls: the stall records of finished runs)."""
