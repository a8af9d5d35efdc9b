"""The entity networks (maddpg.networks = "entity"): attention over landmark and agent slots, their views, ops and
holder rules."""
