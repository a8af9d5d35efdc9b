"""Scorers: the models that give replay rows a score column keyed by (slot, generation) - the K-fold teachers'
difficulty (`teachers.py` torch, `difficulty.py` eqs. 10-11), the ICM's curiosity ρ (`icm.py` torch, eqs. 13-18)
and the learner's online critics' |δ| (ACL td_self) - and the scoring state that picks the rows each scores next
(`scoring.py`, numpy). Their roles are `services/scorers/`; the messages `cmcl.replay.messages.ScoreWork` / `Scores`."""
