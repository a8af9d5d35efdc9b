"""How well each critic explains its TD targets on its minibatch: the normalised TD error (run.progress_signal =
"normalised_td", cmcl.progress.learning), returned by :meth:`cmcl.learners.maddpg.MADDPG.update` as
``critic_loss_normalised``.

Reads tensors only, without grad: the MADDPG step does not depend on it.
"""

from __future__ import annotations

import torch

from cmcl.learners.agent_presence import AgentPresence, row_mean

__all__ = ["normalised_td_error"]


@torch.no_grad()
def normalised_td_error(y: torch.Tensor, delta: torch.Tensor, presence: AgentPresence | None) -> torch.Tensor:
    """Each owner's normalised TD error on its minibatch: mean (y − Q)² over the variance of y, over the rows where it
    is present, unweighted (the share of its targets' variance the critic does not explain, 1 − R²; free of the value
    scale, which the critic loss of eq. 5 is not).

    y: TD targets float32[N, S]; delta: y − Q_v(s, a) float32[N, S] (0 where the owner is absent); presence: None for
    every row -> float32[N], nan where y has no variance.
    """
    mse = row_mean(delta.pow(2), None, presence)
    centred = y - row_mean(y, None, presence).unsqueeze(1)
    var = row_mean(centred.pow(2), None, presence)
    return torch.where(var > 0, mse / var.clamp(min=torch.finfo(var.dtype).tiny), torch.nan)
