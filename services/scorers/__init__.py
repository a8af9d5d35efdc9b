"""The scorer roles: a teacher group (`teachers.py`) and the ICM (`icm.py`), each turning a `ScoreWork` into
`Scores`; the online critic is the learner's (`services.learner.Learner.update`)."""
