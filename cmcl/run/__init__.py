"""A training run from the command line: its flags, the checks before it, its run folder, evaluation, reports, status,
stops and stage sequences. Nothing in the core (the rest of cmcl/) imports it."""
