"""Training-time episode control: de-synchronised first episodes and truncation on request.

All sub-envs of a training run start on the ground at the same instant; left alone, every row
would then climb, cruise and land in lock step and each batch would hold a single phase of flight.
:class:`EpisodeControl` truncates each row's *first* episode after a random number of env steps
(uniform over the multiples of ``align`` in ``[align, desync_steps]``, drawn once from a seeded
generator), which spreads the rows over the flight phases from the second episode on. Later
episodes run to their natural end. Limits are multiples of ``align`` (the env steps in one log
interval: 10 for 10 ms env steps, 1 when an env step holds 10 control steps) so that
restarted rows stay in phase with the 10 Hz ticks of the others (episodes start and end on ticks),
which keeps the estimator transform on its one-batch-per-tick fast path.

:meth:`EpisodeControl.request_truncation` truncates every running episode at the next step (the
vertical curriculum uses it when a stage starts, so the new trajectory set takes effect at once).

Truncation is time-limit truncation: ``truncated`` and ``done`` are set, ``terminated`` is not, so
GAE bootstraps from the value of the last observation. Place this transform before ``RewardSum``
and ``StepCounter`` so they see the updated ``done``.
"""
from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.envs import Transform

from .reset import reset_mask


class EpisodeControl(Transform):
    def __init__(self, desync_steps: int = 0, seed: int = 0, align: int = 10, rows: slice | None = None):
        if desync_steps < 0:
            raise ValueError(f"EpisodeControl.desync_steps={desync_steps} must be >= 0")
        if align < 1:
            raise ValueError(f"EpisodeControl.align={align} must be >= 1")
        super().__init__(in_keys=[], out_keys=[])
        self.desync_steps = int(desync_steps)
        self.align = int(align)
        self.seed = int(seed)
        # this env's rows of a larger batch (a collection worker's share; None: the whole batch):
        # its first-episode lengths are those rows of the whole batch's draw
        self.rows = rows
        self.limit: torch.Tensor | None = None  # [N] first-episode length, 0 = none
        self.count: torch.Tensor | None = None  # [N] env steps into the current episode
        self.first: torch.Tensor | None = None  # [N] bool: still in the first episode
        self._force = False

    def request_truncation(self) -> None:
        """Truncate every running episode at the next step."""
        self._force = True

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        done = tensordict_reset.get("done")
        n, dev = done.shape[0], done.device
        mask = reset_mask(tensordict, n, dev)
        full = tensordict is None or tensordict.get("_reset", None) is None
        if full or self.count is None or self.count.shape[0] != n:
            gen = torch.Generator().manual_seed(self.seed)
            if self.desync_steps > 0:
                top = max(1, self.desync_steps // self.align)
                first = 0 if self.rows is None else self.rows.start
                if self.rows is not None and self.rows.stop - first != n:
                    raise ValueError(f"EpisodeControl.rows={self.rows} holds {self.rows.stop - first} rows but the env has {n}")
                draw = torch.randint(1, top + 1, (first + n,), generator=gen)[first:]  # the CPU draw is serial: a prefix is a shorter draw
                self.limit = (self.align * draw).to(dev)
            else:
                self.limit = torch.zeros(n, dtype=torch.int64, device=dev)
            self.count = torch.zeros(n, dtype=torch.int64, device=dev)
            self.first = torch.ones(n, dtype=torch.bool, device=dev)
        else:
            self.first = self.first & ~mask
        self.count = torch.where(mask, 0, self.count)
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self.count is None:
            return next_tensordict
        self.count = self.count + 1
        cut = self.first & (self.limit > 0) & (self.count >= self.limit)
        if self._force:
            cut = torch.ones_like(cut)
            self._force = False
        cut = cut.unsqueeze(-1)  # applied unconditionally: no host sync on the step
        next_tensordict.set("truncated", next_tensordict.get("truncated") | cut)
        next_tensordict.set("done", next_tensordict.get("done") | cut)
        return next_tensordict
