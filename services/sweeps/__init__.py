"""Sweeps on Ray Tune (`python -m cmcl tune`): the search space, one trial, the sweep."""
