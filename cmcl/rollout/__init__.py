"""Rollout: what a rollout worker runs besides the worlds (cmcl/envs/): the numpy actor, episode bookkeeping, the task
curriculum."""
