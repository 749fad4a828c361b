"""Value normalisation (PPOConfig.value_norm): the critic learns its targets in running-standardised
units, PopArt-style (van Hasselt et al. 2016, "Learning values across many orders of magnitude").

The critic's network predicts a standardised value; :class:`NormalizedValue` turns it back into
return units with the running mean and standard deviation of every value target seen so far
(TorchRL's ``RunningValueNorm``, Welford, no decay), so GAE bootstraps on the real scale. Its
:meth:`~NormalizedValue.update` folds a batch's targets into the statistics and rescales the
output layer so that every prediction is unchanged by the new statistics (PopArt's "preserve
outputs precisely"): the values GAE computed for this batch stay the critic's. The loss
(:class:`NormalizedCriticLoss`) regresses the standardised prediction on the standardised target,
so the critic's loss, its gradient and its share of the clipped gradient norm keep one scale
whatever the returns are (here about -35 per episode-length horizon, -100 at a crash).
"""
from __future__ import annotations

import torch
from torch import nn
from torchrl.modules import RunningValueNorm
from torchrl.objectives import ClipPPOLoss


class NormalizedValue(nn.Module):
    """``net``'s output, standardised, turned back into return units: ``mean + std * net(*inputs)``.

    ``net``'s last ``nn.Linear`` is its output layer (rescaled by :meth:`update`). The statistics
    are buffers (``norm.mean``, ``norm.m2``, ``norm.count``): they travel with the critic's
    ``state_dict`` into checkpoints, so a resumed run continues them.
    """

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net
        self.norm = RunningValueNorm(shape=1)

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        return self.norm.denormalize(self.net(*inputs))

    @torch.no_grad()
    def update(self, value_target: torch.Tensor) -> None:
        """Fold ``value_target`` (``[..., 1]``, return units) into the statistics; the output layer
        is rescaled so that ``forward`` gives the same values before and after."""
        mean, std = self.norm.mean.clone(), self.norm.scale().clone()
        self.norm.update(value_target.reshape(-1, 1))
        new_mean, new_std = self.norm.mean, self.norm.scale()
        out = [m for m in self.net.modules() if isinstance(m, nn.Linear)][-1]
        out.weight.mul_(std / new_std)
        out.bias.mul_(std).add_(mean - new_mean).div_(new_std)


def normalized_value(value: nn.Module) -> NormalizedValue | None:
    """The critic's :class:`NormalizedValue` (None: a critic on the return scale)."""
    return next((m for m in value.modules() if isinstance(m, NormalizedValue)), None)


class NormalizedCriticLoss(ClipPPOLoss):
    """``ClipPPOLoss`` whose critic loss compares the standardised prediction with the standardised
    target (the statistics of ``value_head``, not updated here: :meth:`NormalizedValue.update`
    runs once per batch). Through TorchRL's hook for this (``_critic_loss_inputs``, as its MAPPO
    loss normalises), so the rest of the critic loss (its type, the explained variance) is the
    parent's."""

    def __init__(self, *args, value_head: NormalizedValue, **kwargs):
        super().__init__(*args, **kwargs)
        # not a sub-module: its buffers are the critic's already (a second registration would list them twice)
        self._norm = [value_head.norm]

    def _critic_loss_inputs(self, target_return, state_value, old_state_value):
        norm = self._norm[0]
        return (norm.normalize(target_return), norm.normalize(state_value),
                None if old_state_value is None else norm.normalize(old_state_value))
