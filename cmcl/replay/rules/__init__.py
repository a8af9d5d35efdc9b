"""Sampling rules, one file each; every file exports RULE (cmcl.replay.rules.contract.Rule: its options, sampler,
learner scores, learner-side pick and capabilities) and `cmcl.replay.registry` registers it with one line.

  contract.py .... what a rule declares: Rule, Needs, LearnerScore, Range (its options' ranges), NoOptions
  maddpg.py ...... maddpg: uniform replay (the paper's baseline)
  per.py ......... per: PER-MADDPG, p = |δ| + ε_p, new rows at the running maximum (the paper's baseline)
  acl.py ......... acl: KP(ĉ, λ) of the teachers' (or td_self's) difficulty; the curriculum sampler acl and cmcl share
  cmcl.py ........ cmcl: CI = KP(ĉ, λ) + η·CP(ρ̂), the paper's method
  relo.py ........ relo: p = max(0, δ_online² − δ_target²), with its own learner score |y − Q_target|
  reducible.py ... rho: rank(δ² − ē), the learner's loss against the K-fold teachers' held-out error (RHO-LOSS)
  progress.py .... lp: rank of |ē(t) − ē(t−1)| mixed with staleness (PLR); option teams.<team>.staleness
  laber.py ....... laber: each minibatch picked ∝ |δ| computed fresh on m·B uniform candidates (LaBER), a
                   learner-side pick; option teams.<team>.candidates (m)
"""
