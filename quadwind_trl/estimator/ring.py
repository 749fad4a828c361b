"""The online estimator input: per-sub-env causal 10 Hz features and a ring of the last ``window``.

:class:`FeatureRing` (plain Python, no TorchRL) feeds one 10 Hz sample of the raw record into
:class:`~quadwind_trl.estimator.features.FeatureExtractor` (the very same ``step`` that builds the
offline datasets) for the rows that tick, and keeps a ring of the last
``window`` feature vectors per row; :class:`~quadwind_trl.transforms.wind.WindEstimate` owns one.

Timing. The env's ``step`` observation entry is the control-step index; a row *ticks* when
``step % log_every == 0`` (every 10th control step: the samples the dataset record holds, the
episode's first observation included). Every row keeps its own phase, so rows that restarted after
a crash tick at other control steps than the rest of the batch.

Padding. Until a row has ``window`` samples in its current episode, its window is left-padded by
repeating the episode's first feature vector: the first tick fills every slot with it, and each
later tick overwrites the oldest slot. After 60 ticks (6 s) the window is exactly the last 60
samples, as in the offline windows.

State (extractor state, ring, write pointer, sample count) lives in the ring, per row; a reset
restarts only the rows of its mask.
"""
from __future__ import annotations

from typing import Mapping

import torch
from tensordict import TensorDictBase
from torch import Tensor

from .features import FeatureExtractor


def _clone(state):
    """Deep copy of a nested dict/tuple of tensors (no two leaves share storage afterwards)."""
    if isinstance(state, dict):
        return {k: _clone(v) for k, v in state.items()}
    if isinstance(state, tuple):
        return tuple(_clone(v) for v in state)
    return state.clone()


def _gather(state, idx: Tensor):
    """Rows ``idx`` of every leaf (copies)."""
    if isinstance(state, dict):
        return {k: _gather(v, idx) for k, v in state.items()}
    if isinstance(state, tuple):
        return tuple(_gather(v, idx) for v in state)
    return state[idx]


def _scatter(state, idx: Tensor, sub):
    """``state`` with rows ``idx`` replaced by ``sub``. Dict leaves are replaced out of place (they
    may alias tensors the env returned); the elements of tuples (the extractor's long sample
    history, hundreds of tensors) are written in place, which is safe because the ring owns them:
    they are de-aliased at init and the extractor only ever creates fresh ones."""
    if isinstance(state, dict):
        return {k: _scatter(v, idx, sub[k]) for k, v in state.items()}
    if isinstance(state, tuple):
        for t, s in zip(state, sub):
            t[idx] = s
        return state
    return state.index_put((idx,), sub)


class FeatureRing:
    """Batched feature-extractor state plus a ring of the last ``window`` features per row."""

    def __init__(self, extractor: FeatureExtractor, window: int, log_every: int):
        if window < 1:
            raise ValueError(f"FeatureRing.window={window} must be >= 1")
        self.extractor = extractor
        self.window = window
        self.log_every = log_every
        self.n = 0
        self.fx_state: dict | None = None
        self.buf: Tensor | None = None  # [N, W, C] ring
        self.ptr: Tensor | None = None  # [N] slot of the oldest sample (= next write)
        self.count: Tensor | None = None  # [N] samples in the current episode

    @property
    def initialized(self) -> bool:
        return self.buf is not None

    def init(self, n: int, device) -> None:
        c = self.extractor.num_channels
        self.n = n
        self.fx_state = _clone(self.extractor.init_state(n, device))  # de-aliased: see _scatter
        self.buf = torch.zeros(n, self.window, c, device=device)
        self.ptr = torch.zeros(n, dtype=torch.int64, device=device)
        self.count = torch.zeros(n, dtype=torch.int64, device=device)

    def reset_rows(self, mask: Tensor) -> None:
        """Restart rows ``mask`` (bool ``[N]``): their next sample is an episode's first."""
        self.fx_state = self.extractor.reset_rows(self.fx_state, mask)
        self.count = torch.where(mask, 0, self.count)
        self.ptr = torch.where(mask, 0, self.ptr)

    def ticks(self, step: Tensor) -> Tensor:
        """bool ``[N]``: rows whose control step ``step`` (``[N, 1]`` or ``[N]``) is a log tick."""
        return (step.reshape(-1) % self.log_every) == 0

    def ingest(self, record: Mapping[str, Tensor | TensorDictBase], mask: Tensor) -> Tensor:
        """Feed one 10 Hz sample to the rows of ``mask``; returns their indices (``[B]`` int64).

        Rows outside ``mask`` are left exactly as they were (extractor state, ring, count)."""
        idx = mask.nonzero().squeeze(-1)
        if idx.numel() == 0:
            return idx
        if idx.numel() == self.n:
            raw = {k: record[k] for k in self.extractor.raw_keys}
            self.fx_state, f = self.extractor.step(self.fx_state, raw)
        else:  # only the ticking rows: the extractor is row-wise, so a subset gives the same numbers
            raw = {k: record[k][idx] for k in self.extractor.raw_keys}
            sub, f = self.extractor.step(_gather(self.fx_state, idx), raw)
            self.fx_state = _scatter(self.fx_state, idx, sub)
        first = self.count[idx] == 0
        if bool(first.any()):
            # a row's first sample fills its whole window (left padding by repetition)
            self.buf[idx[first]] = f[first].unsqueeze(1).expand(-1, self.window, -1)
            self.ptr[idx[first]] = 0
        slot = self.ptr[idx]
        self.buf[idx, slot] = f
        self.ptr[idx] = (slot + 1) % self.window
        self.count[idx] = self.count[idx] + 1
        return idx

    def windows(self, idx: Tensor) -> Tensor:
        """Ordered windows ``[B, W, C]`` (oldest first; ``[:, -1]`` is the latest sample) of rows
        ``idx``."""
        order = (self.ptr[idx, None] + torch.arange(self.window, device=idx.device)) % self.window
        return self.buf[idx[:, None], order]
