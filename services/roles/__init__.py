"""The Ray roles of the service: rollout workers, the replay server, the learner, the scorers' actors (teachers,
ICM)."""
