"""Replay stage (numpy only, never torch): storage, samplers, priorities, curriculum, rate limits, difficulty."""
