"""The research record beside the product: the report and doc-generation code (lab/report/), the one-off studies
(lab/studies/), the grids' results (lab/results/), the full record of every comparison (lab/RESULTS.md) and their
tests (lab/tests/, `make test-lab`). Nothing of the installed packages imports it; it is run from the repository's
root (`python -m lab report`).
"""
