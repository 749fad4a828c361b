"""Observation normalisation by running statistics: TorchRL's ``VecNormV2`` with fixes."""
from __future__ import annotations

import warnings

import torch
from tensordict import TensorDictBase
from torchrl.envs import VecNormV2


class RunningObsNorm(VecNormV2):
    """TorchRL's ``VecNormV2`` with three fixes for this use.

    * The variance ``E[x^2] - E[x]^2`` is clamped at 0 before its square root: float cancellation
      made it slightly negative for (near-)constant channels, and ``VecNormV2`` then returned NaN
      observations (seen on the first step of an airborne start; TorchRL 0.14.1).
    * No "experimental on batched envs" warning, which TorchRL re-emits at every internal rebuild
      of the transform chain; the batched use here (``reduce_batch_dims=True``: one statistics set
      for all sub-envs) is covered by ``tests/test_transforms.py``.
    * A partial reset adds to the statistics the first observations of the rows that restart, and
      only those. ``VecNormV2`` added every row of the reset's output: the rows that go on were
      counted a second time in one process, and as zeros behind a ``ParallelEnv`` (whose partial
      reset pads the rows it keeps with 0), so the statistics depended on the process layout.
    """

    def _reset(self, tensordict: TensorDictBase | None, tensordict_reset: TensorDictBase) -> TensorDictBase:
        restart = None if tensordict is None else tensordict.get("_reset", None)
        if restart is None or self.frozen:
            return super()._reset(tensordict, tensordict_reset)
        observed = tensordict_reset.select(*self.in_keys, strict=False)
        if observed.is_empty():
            return tensordict_reset
        self._maybe_stateful_init(tensordict_reset)
        rows = restart.reshape(tensordict_reset.batch_size)
        if bool(rows.any()):  # a reset of no row adds nothing (TorchRL's partial reset syncs on this too)
            self._stateful_update(observed[rows])
        return tensordict_reset.update(self._stateful_norm(observed))

    def _norm(self, data, loc, var, count):
        var = var.apply(lambda v, m: torch.maximum(v, m.pow(2)), loc)
        return super()._norm(data, loc, var, count)

    def set_container(self, container) -> None:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Support of .* is experimental")
            super().set_container(container)
