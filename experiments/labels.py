"""Names and colours of the algorithms and of the curriculum grid's arms, shared by the tables and the figures."""

ORDER = ("maddpg", "per", "acl", "cmcl")  # the algorithms, in the order of every table and legend
LABEL = {"maddpg": "MADDPG", "per": "PER-MADDPG", "acl": "ACL", "cmcl": "CMCL"}
COLOUR = {"maddpg": "tab:blue", "per": "tab:orange", "acl": "tab:green", "cmcl": "tab:red"}
ARM_LABEL = {**LABEL, "cmcl_permuted": "CMCL, permuted control", "cmcl_anti": "CMCL, anti-curriculum",
             "cmcl_stride_x2": "CMCL, λ stride ×2", "cmcl_stride_half": "CMCL, λ stride ×½",
             "cmcl_eta1": "CMCL, η = 1", "relo": "ReLo", "rho": "reducible held-out loss",
             "lp": "held-out learning progress", "per_floor": "PER-MADDPG, floor 0.2",
             "cmcl_lam05": "CMCL, λ₀ = 0.5", "cmcl_floor": "CMCL, floor 0.2", "laber": "LaBER",
             "per_actor_uniform": "PER-MADDPG, actor on uniform rows"}
PERMUTED = "_permuted"  # an arm's permuted control is the arm named "<arm>_permuted" (experiments.grids)
ARM_LABEL.update({f"{arm}{PERMUTED}": f"{label}, permuted control" for arm, label in list(ARM_LABEL.items())
                  if not arm.endswith(PERMUTED)})
ARM_COLOUR = {**COLOUR, "cmcl_permuted": "tab:purple", "cmcl_anti": "tab:brown",
              "cmcl_stride_x2": "tab:pink", "cmcl_stride_half": "tab:olive",
              "cmcl_eta1": "tab:cyan"}
ARM_ORDER = (*ORDER, "cmcl_permuted", "cmcl_anti")  # the curriculum grids' arms, in table and legend order
