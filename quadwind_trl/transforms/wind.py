"""The wind channels of the policy: the frozen estimator + EMA (``WindEstimate``); the ablation
zeroes them with :class:`~quadwind_trl.transforms.observation.ZeroInputs`.

``WindEstimate(estimator)`` takes any :class:`~quadwind_trl.estimator.base.WindEstimator` (the
trained ``EstimatorBundle``, or a user's own class) and keeps a
:class:`~quadwind_trl.estimator.ring.FeatureRing` of its feature schema per sub-env, fed at every
10 Hz log tick of a row. Every ``every_s`` seconds of a row's episode (default: every log tick; a
whole number ``stride`` of log intervals, counted from the row's reset, whose tick is always a
query) it queries the estimator on that row's ``estimator.window``-sample feature window
(left-padded by repeating the episode's first sample until it is full), filters the (north, east)
output with the spike-gated EMA (:mod:`quadwind_trl.estimator.ema`; ``tau`` from ``ema``, default
``EMAConfig()``; ``dt`` = ``every_s``, so the filter's time constants stay in seconds) and holds the
filtered value until the row's next query. It writes ``wind_hat`` ``[2]`` = (north, east) m/s.

Only rows whose query is due are evaluated (gathered, then scattered back), so the estimator's cost
is one window per row per ``10 x stride`` control steps whatever the rows' phases.

The estimator is frozen (``eval()``, ``requires_grad_(False)``) and held as a plain attribute of
the transform, not a registered sub-module: ``transform.parameters()`` and ``state_dict()`` do not
contain it, so no optimiser built from the env, the loss or the policy can ever see it, and policy
checkpoints do not duplicate it (they record the estimator's path and manifest instead). The
estimator is expected frozen (``EstimatorBundle`` loads frozen); the transform only calls
``predict`` under ``torch.no_grad()``.

``source="truth"`` is the oracle: ``wind_hat`` is the true turbulence-free mean wind at the
vehicle, ``truth.mean_wind`` (ENU) reordered to (north, east), written at every control step,
unfiltered.
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from numbers import Real
from typing import Literal

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from ..config import EnvConfig
from ..estimator.base import WindEstimator
from ..estimator.ema import EMAConfig, ema_init, ema_reset_rows, ema_step
from ..estimator.features import make_extractor
from ..estimator.ring import FeatureRing
from ..keys import MEAN_WIND_KEY, WIND_KEY
from .reset import reset_mask


def estimate_stride(every_s: float, log_dt_s: float, name: str = "WindEstimate.every_s") -> int:
    """Log ticks per estimator query for a query every ``every_s`` seconds; a ``ValueError``
    naming ``name`` unless ``every_s`` is a positive whole multiple of the log interval ``log_dt_s``
    (the ring is fed at log ticks, so a query can only happen on one)."""
    valid = isinstance(every_s, Real) and not isinstance(every_s, bool) and math.isfinite(every_s) and every_s > 0
    stride = round(every_s / log_dt_s) if valid else 0
    if stride < 1 or not math.isclose(stride * log_dt_s, every_s, rel_tol=1e-9):
        raise ValueError(f"{name}={every_s!r} s; allowed: a positive whole multiple of the log interval "
                         f"{log_dt_s:g} s ({log_dt_s:g}, {2 * log_dt_s:g}, ..., {5 * log_dt_s:g}, {10 * log_dt_s:g}, ...)")
    return stride


class WindEstimate(Transform):
    """Writes ``wind_hat`` ``[2]`` (north, east, m/s): the frozen estimator's EMA-filtered output
    (``source="estimate"``) or the true mean wind (``source="truth"``).

    Args:
        estimator: a :class:`~quadwind_trl.estimator.base.WindEstimator` (ignored, may be None,
            for ``source="truth"``).
        ema: the post-filter; default ``EMAConfig()``; its ``dt_s`` is set to the query interval.
            ``EMAConfig(tau_s=0)`` passes the raw output through.
        source: ``"estimate"`` or ``"truth"``.
        config: the env config (vehicle mass for the features, log rate).
        out_key: the entry written (default ``"wind_hat"``).
        every_s: seconds between a row's estimator queries, a positive whole multiple of the log
            interval (default: the log interval, every tick). Ignored for ``source="truth"``.
    """

    def __init__(
        self,
        estimator: WindEstimator | None = None,
        ema: EMAConfig | None = None,
        *,
        source: Literal["estimate", "truth"] = "estimate",
        config: EnvConfig | None = None,
        out_key: str = WIND_KEY,
        every_s: float | None = None,
    ):
        if source not in ("estimate", "truth"):
            raise ValueError(f"WindEstimate.source={source!r}; allowed: 'estimate', 'truth'")
        cfg = config or EnvConfig()
        log_dt = cfg.timing.log_dt_s
        self.stride = 1 if every_s is None else estimate_stride(every_s, log_dt)
        self.source = source
        if source == "estimate":
            if estimator is None:
                raise ValueError("WindEstimate(source='estimate') needs an estimator")
            if not isinstance(estimator, WindEstimator):
                missing = [m for m in ("schema", "channels", "window", "predict", "to") if not hasattr(estimator, m)]
                raise TypeError(f"WindEstimate: {type(estimator).__name__} is not a WindEstimator (missing {missing})")
            # the extractor that makes the estimator's channels (its trailing means read from their names)
            extractor = make_extractor(estimator.schema, cfg, channels=tuple(estimator.channels))
            in_keys = list(extractor.raw_keys) + ["step"]
        else:
            extractor = None
            in_keys = [MEAN_WIND_KEY]
        super().__init__(in_keys=in_keys, out_keys=[out_key])
        self.out_key = out_key
        # a plain attribute (not a sub-module): no parameters, no state_dict entries
        self.estimator = estimator
        # one filter step per query: dt = the query interval keeps tau (in seconds) the same
        self.ema_config = replace(ema if ema is not None else EMAConfig(), dt_s=log_dt * self.stride)
        self.ring = FeatureRing(extractor, estimator.window, cfg.timing.log_every_control_steps) if extractor else None
        self.ema_state: dict[str, Tensor] | None = None
        self.value: Tensor | None = None  # [N, 2] held output
        self.estimator_calls = 0  # windows evaluated (for benchmarks)
        self.estimator_seconds = 0.0

    # --- the estimator path --------------------------------------------------------------------

    def _ensure(self, n: int, device) -> None:
        if self.ring is not None and (not self.ring.initialized or self.ring.n != n):
            self.ring.init(n, device)
            self.ema_state = ema_init(n, 2, device)
            self.value = torch.zeros(n, 2, device=device)
            self.estimator = self.estimator.to(device)

    def _due(self, idx: Tensor) -> Tensor:
        """The rows of ``idx`` (just fed a sample) whose query is due: every ``stride``-th sample of
        each row's own episode, its first (the reset tick) included."""
        if self.stride == 1:
            return idx
        return idx[(self.ring.count[idx] - 1) % self.stride == 0]

    @torch.no_grad()
    def _tick(self, record: TensorDictBase, mask: Tensor) -> None:
        # every tick feeds the ring (the window is the last 60 samples at 10 Hz); only due rows query
        idx = self._due(self.ring.ingest(record, mask))
        if idx.numel() == 0:
            return
        t0 = time.perf_counter()
        pred = self.estimator.predict(self.ring.windows(idx))  # [B, 2] (north, east), m/s
        self.estimator_seconds += time.perf_counter() - t0
        self.estimator_calls += idx.numel()
        sub = {k: v[idx] for k, v in self.ema_state.items()}
        sub, filtered = ema_step(sub, pred, self.ema_config)
        for k, v in sub.items():
            self.ema_state[k][idx] = v
        self.value[idx] = filtered

    @staticmethod
    def _truth(td: TensorDictBase) -> Tensor:
        mean = td.get(MEAN_WIND_KEY)
        return torch.stack((mean[..., 1], mean[..., 0]), -1)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        if self.source == "truth":
            tensordict_reset.set(self.out_key, self._truth(tensordict_reset))
            return tensordict_reset
        step = tensordict_reset.get("step")
        n = step.shape[0]
        self._ensure(n, step.device)
        mask = reset_mask(tensordict, n, step.device)
        self.ring.reset_rows(mask)
        self.ema_state = ema_reset_rows(self.ema_state, mask)
        self.value = torch.where(mask.unsqueeze(-1), 0.0, self.value)
        self._tick(tensordict_reset, mask & self.ring.ticks(step))
        tensordict_reset.set(self.out_key, self.value.clone())
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        if self.source == "truth":
            next_tensordict.set(self.out_key, self._truth(next_tensordict))
            return next_tensordict
        self._tick(next_tensordict, self.ring.ticks(next_tensordict.get("step")))
        next_tensordict.set(self.out_key, self.value.clone())
        return next_tensordict

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[self.out_key] = Unbounded(shape=(*observation_spec.shape, 2), device=observation_spec.device)
        return observation_spec

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        # Deliberately unsupported: the estimate needs each flight's feature window and EMA state,
        # which stored rows (``forward``'s input) do not carry. Offline estimates of whole flights
        # come from ``evaluation.estimation.predict_flights`` and ``estimator.ema.ema_scan``.
        raise NotImplementedError(  # by design, not a stub: stored rows carry no flight history
            "WindEstimate is stateful: use it inside a TransformedEnv; for recorded flights use "
            "evaluation.estimation.predict_flights and estimator.ema.ema_scan"
        )

