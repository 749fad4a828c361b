"""The wind channels of the policy: the frozen estimator + EMA (``WindEstimate``) and the ablation
(``WindZero``).

``WindEstimate(bundle)`` keeps a :class:`~quadwind_trl.transforms.history.FeatureRing` per sub-env;
at every 10 Hz log tick of a row it queries the frozen estimator on that row's 60-sample feature
window (left-padded by repeating the episode's first sample until 60 samples exist), de-standardises
the output (``EstimatorBundle.predict``), filters it with the spike-gated EMA
(:mod:`quadwind_trl.modules.ema`, ``tau = bundle.ema_tau_s``, ``dt`` = the log interval) and holds
the filtered value until the row's next tick. It writes ``wind_hat`` ``[2]`` = (north, east) m/s.

Only rows that tick are evaluated (gathered, then scattered back), so the estimator's cost is one
window per row per 10 control steps whatever the rows' phases.

The estimator is frozen (``eval()``, ``requires_grad_(False)``) and held as a plain attribute of
the transform, not a registered sub-module: ``transform.parameters()`` and ``state_dict()`` do not
contain it, so no optimiser built from the env, the loss or the policy can ever see it, and policy
checkpoints do not duplicate it (they record the estimator's path and manifest instead).

``source="truth"`` is the oracle: ``wind_hat`` is the true turbulence-free mean wind at the
vehicle, ``truth.mean_wind`` (ENU) reordered to (north, east), written at every control step,
unfiltered.
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Literal, Sequence

import torch
from tensordict import TensorDictBase
from torch import Tensor
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from ..config import EnvConfig
from ..data.features import make_extractor
from ..modules.ema import EMAConfig, ema_init, ema_reset_rows, ema_step
from ..modules.wind_estimator import EstimatorBundle
from .history import WINDOW, FeatureRing, reset_mask

WIND_KEY = "wind_hat"


class WindEstimate(Transform):
    """Writes ``wind_hat`` ``[2]`` (north, east, m/s): the frozen estimator's EMA-filtered output
    (``source="estimate"``) or the true mean wind (``source="truth"``).

    Args:
        bundle: the trained estimator (ignored, may be None, for ``source="truth"``).
        ema: the post-filter; default ``EMAConfig(tau_s=bundle.ema_tau_s)`` with ``dt_s`` the
            config's log interval. ``EMAConfig(tau_s=0)`` passes the raw output through.
        source: ``"estimate"`` or ``"truth"``.
        config: the env config (vehicle mass for the features, log rate).
        out_key: the entry written (default ``"wind_hat"``).
    """

    def __init__(
        self,
        bundle: EstimatorBundle | None = None,
        ema: EMAConfig | None = None,
        *,
        source: Literal["estimate", "truth"] = "estimate",
        config: EnvConfig | None = None,
        out_key: str = WIND_KEY,
    ):
        if source not in ("estimate", "truth"):
            raise ValueError(f"WindEstimate.source={source!r}; allowed: 'estimate', 'truth'")
        cfg = config or EnvConfig()
        log_dt = cfg.timing.log_dt_s
        self.source = source
        if source == "estimate":
            if bundle is None:
                raise ValueError("WindEstimate(source='estimate') needs an EstimatorBundle")
            extractor = make_extractor(bundle.schema, cfg)
            if tuple(bundle.channels) != tuple(extractor.channels):
                raise ValueError(
                    f"estimator channels ({len(bundle.channels)}) differ from the {bundle.schema!r} feature "
                    f"extractor's ({extractor.num_channels}): retrain or pick the matching schema"
                )
            in_keys = list(extractor.raw_keys) + ["step"]
        else:
            extractor = None
            in_keys = [("truth", "mean_wind")]
        super().__init__(in_keys=in_keys, out_keys=[out_key])
        self.out_key = out_key
        # plain attributes (not sub-modules): no parameters, no state_dict entries
        self.bundle = bundle
        if bundle is not None:
            bundle.model.eval().requires_grad_(False)
        self.ema_config = ema if ema is not None else EMAConfig(tau_s=bundle.ema_tau_s if bundle else 3.0, dt_s=log_dt)
        if abs(self.ema_config.dt_s - log_dt) > 1e-9:
            self.ema_config = replace(self.ema_config, dt_s=log_dt)
        window = getattr(getattr(bundle, "model", None), "cfg", None)
        window = getattr(window, "window", WINDOW)
        self.ring = FeatureRing(extractor, window, cfg.timing.log_every_control_steps) if extractor else None
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
            if self.bundle.feature_mean.device != torch.device(device):
                self.bundle.to(device)

    @torch.no_grad()
    def _tick(self, record: TensorDictBase, mask: Tensor) -> None:
        idx = self.ring.ingest(record, mask)
        if idx.numel() == 0:
            return
        t0 = time.perf_counter()
        pred = self.bundle.predict(self.ring.windows(idx))  # [B, 2] (north, east), m/s
        self.estimator_seconds += time.perf_counter() - t0
        self.estimator_calls += idx.numel()
        sub = {k: v[idx] for k, v in self.ema_state.items()}
        sub, filtered = ema_step(sub, pred, self.ema_config)
        for k, v in sub.items():
            self.ema_state[k][idx] = v
        self.value[idx] = filtered

    @staticmethod
    def _truth(td: TensorDictBase) -> Tensor:
        mean = td.get(("truth", "mean_wind"))
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
        # come from ``evaluation.estimation.predict_flights`` and ``modules.ema.ema_scan``.
        raise NotImplementedError("WindEstimate is stateful: use it inside a TransformedEnv")


class WindZero(Transform):
    """Forces the wind channels to exactly zero (the perception ablation); specs unchanged.

    ``WindZero()`` zeroes channels :data:`~quadwind_trl.transforms.observation.WIND_INDICES`
    (13, 14) of ``"observation"``: placed last in the stack (after normalisation) it makes the
    policy's two wind inputs exactly 0 and leaves every other input bit-identical.
    ``WindZero(in_key="wind_hat", indices=None)`` zeroes the whole raw ``wind_hat`` entry instead.
    """

    def __init__(self, in_key: str = "observation", indices: Sequence[int] | None = None):
        super().__init__(in_keys=[in_key], out_keys=[in_key])
        if indices is None and in_key == "observation":
            from .observation import WIND_INDICES

            indices = WIND_INDICES
        self.indices = None if indices is None else tuple(int(i) for i in indices)
        if self.indices is not None:  # a buffer: moves with the transform, no copy per step
            self.register_buffer("_index", torch.tensor(self.indices), persistent=False)

    def _apply_transform(self, x: Tensor) -> Tensor:
        if self.indices is None:
            return torch.zeros_like(x)
        return x.index_fill(-1, self._index.to(x.device), 0.0)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)
