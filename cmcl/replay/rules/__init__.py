"""Sampling rules beyond the paper's four, one file each (issue 36); `cmcl.replay.registry` registers them.

  relo.py ........ ReLo: p = max(0, δ_online² − δ_target²), the learner's own reducible loss
  reducible.py ... rho: rank(δ² − ē), the learner's loss against the K-fold teachers' held-out error (RHO-LOSS)
  laber.py ....... laber: each minibatch picked ∝ |δ| computed fresh on m·B uniform candidates (LaBER)
  progress.py .... lp: rank of |ē(t) − ē(t−1)|, the change of a row's held-out error, mixed with staleness (PLR)
"""
