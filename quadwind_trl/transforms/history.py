"""Per-sub-env causal feature history at the 10 Hz log rate.

:class:`FeatureRing` is the engine (plain Python, no TorchRL): it feeds one 10 Hz sample of the raw
record into :class:`~quadwind_trl.data.features.FeatureExtractor` (the very same ``step`` that
builds the offline datasets, DESIGN.md invariant 3) for the rows that tick, and keeps a ring of the
last ``window`` feature vectors per row. :class:`FeatureHistory` wraps it as a TorchRL transform
that writes the latest feature vector (and, optionally, the whole ordered window) into the
tensordict; :class:`~quadwind_trl.transforms.wind.WindEstimate` owns its own ring.

Timing. The env's ``step`` observation entry is the control-step index; a row *ticks* when
``step % log_every == 0`` (every 10th control step: the samples the dataset record holds, the
episode's first observation included). Every row keeps its own phase, so rows that restarted after
a crash tick at other control steps than the rest of the batch.

Padding. Until a row has ``window`` samples in its current episode, its window is left-padded by
repeating the episode's first feature vector: the first tick fills every slot with it, and each
later tick overwrites the oldest slot. After 60 ticks (6 s) the window is exactly the last 60
samples, as in the offline windows.

State (extractor state, ring, write pointer, sample count) lives in the engine, per row; a reset
restarts only the rows of its mask.
"""
from __future__ import annotations

from typing import Mapping

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from ..config import EnvConfig
from ..data.features import FeatureExtractor, make_extractor

WINDOW = 60  # paper: 6 s at 10 Hz


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


def reset_mask(tensordict: TensorDictBase | None, n: int, device) -> Tensor:
    """bool ``[n]``: the rows a reset call restarts (all rows for a full reset)."""
    mask = tensordict.get("_reset", None) if tensordict is not None else None
    if mask is None:
        return torch.ones(n, dtype=torch.bool, device=device)
    return mask.reshape(n).to(device)


class FeatureRing:
    """Batched feature-extractor state plus a ring of the last ``window`` features per row."""

    def __init__(self, extractor: FeatureExtractor, window: int = WINDOW, log_every: int = 10):
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
        self.latest: Tensor | None = None  # [N, C] last feature vector

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
        self.latest = torch.zeros(n, c, device=device)

    def reset_rows(self, mask: Tensor) -> None:
        """Restart rows ``mask`` (bool ``[N]``): their next sample is an episode's first."""
        self.fx_state = self.extractor.reset_rows(self.fx_state, mask)
        self.count = torch.where(mask, 0, self.count)
        self.ptr = torch.where(mask, 0, self.ptr)
        self.latest = torch.where(mask.unsqueeze(-1), 0.0, self.latest)

    def ticks(self, step: Tensor) -> Tensor:
        """bool ``[N]``: rows whose control step ``step`` (``[N, 1]`` or ``[N]``) is a log tick."""
        return (step.reshape(-1) % self.log_every) == 0

    def ingest(self, record: Mapping[str, Tensor], mask: Tensor) -> Tensor:
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
        self.latest[idx] = f
        return idx

    def windows(self, idx: Tensor) -> Tensor:
        """Ordered windows ``[B, W, C]`` (oldest first) of rows ``idx``."""
        order = (self.ptr[idx, None] + torch.arange(self.window, device=idx.device)) % self.window
        return self.buf[idx[:, None], order]


class FeatureHistory(Transform):
    """Keeps, per sub-env, the causal 10 Hz estimator features and their last ``window`` samples.

    Writes ``out_key`` (default ``"features"``, ``[C]``: the latest feature vector, held between
    ticks) and, if ``window_key`` is given, the ordered window ``[window, C]`` (large: only for
    inspection). The record keys it reads (``extractor.raw_keys``) must be env observations.

    Args:
        extractor: a :class:`FeatureExtractor` (or ``"horizontal"``/``"vertical"`` with ``config``).
        window: ring length (60 = 6 s, the estimator's window).
        config: env config (vehicle mass, log rate) when ``extractor`` is a schema name.
    """

    def __init__(
        self,
        extractor: FeatureExtractor | str = "horizontal",
        window: int = WINDOW,
        *,
        config: EnvConfig | None = None,
        out_key: str | None = "features",
        window_key: str | None = None,
    ):
        if isinstance(extractor, str):
            extractor = make_extractor(extractor, config)
        cfg = config or EnvConfig()
        out_keys = [k for k in (out_key, window_key) if k is not None]
        super().__init__(in_keys=list(extractor.raw_keys) + ["step"], out_keys=out_keys)
        self.ring = FeatureRing(extractor, window, cfg.timing.log_every_control_steps)
        self.out_key, self.window_key = out_key, window_key

    @property
    def extractor(self) -> FeatureExtractor:
        return self.ring.extractor

    def _write(self, td: TensorDictBase) -> TensorDictBase:
        if self.out_key is not None:
            td.set(self.out_key, self.ring.latest.clone())
        if self.window_key is not None:
            all_rows = torch.arange(self.ring.n, device=self.ring.buf.device)
            td.set(self.window_key, self.ring.windows(all_rows))
        return td

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        step = tensordict_reset.get("step")
        n = step.shape[0]
        mask = reset_mask(tensordict, n, step.device)
        if not self.ring.initialized or self.ring.n != n:
            self.ring.init(n, step.device)
        self.ring.reset_rows(mask)
        self.ring.ingest(tensordict_reset, mask & self.ring.ticks(step))
        return self._write(tensordict_reset)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        self.ring.ingest(next_tensordict, self.ring.ticks(next_tensordict.get("step")))
        return self._write(next_tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        shape, dev = observation_spec.shape, observation_spec.device
        c = self.extractor.num_channels
        if self.out_key is not None:
            observation_spec[self.out_key] = Unbounded(shape=(*shape, c), device=dev)
        if self.window_key is not None:
            observation_spec[self.window_key] = Unbounded(shape=(*shape, self.ring.window, c), device=dev)
        return observation_spec

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        # Deliberately unsupported, not unfinished: ``forward`` is TorchRL's entry point for
        # transforming stored data (replay buffers, offline batches), where consecutive rows are not
        # one flight's consecutive steps. A per-flight history built from them would be silently
        # wrong; offline features come from ``FeatureExtractor.scan`` instead (the same code).
        raise NotImplementedError("FeatureHistory is stateful: use it inside a TransformedEnv")
