"""Observation normalisation by running statistics: TorchRL's ``VecNormV2`` with a fix."""
from __future__ import annotations

import warnings

import torch
from torchrl.envs import VecNormV2


class RunningObsNorm(VecNormV2):
    """TorchRL's ``VecNormV2`` with two fixes for this use.

    * The variance ``E[x^2] - E[x]^2`` is clamped at 0 before its square root: float cancellation
      made it slightly negative for (near-)constant channels, and ``VecNormV2`` then returned NaN
      observations (seen on the first step of an airborne start; TorchRL 0.14.1).
    * No "experimental on batched envs" warning, which TorchRL re-emits at every internal rebuild
      of the transform chain; the batched use here (``reduce_batch_dims=True``: one statistics set
      for all sub-envs) is covered by ``tests/test_transforms.py``.
    """

    def _norm(self, data, loc, var, count):
        var = var.apply(lambda v, m: torch.maximum(v, m.pow(2)), loc)
        return super()._norm(data, loc, var, count)

    def set_container(self, container) -> None:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Support of .* is experimental")
            super().set_container(container)
