"""One-off studies: each answered one question once (a calibration, a diagnosis, a signal's shape) and is kept so
that its numbers in lab/RESULTS.md can be reproduced. Run as scripts from the repository's root
(`python lab/studies/NAME.py`, or `python -m lab.studies.calibrate`)."""
