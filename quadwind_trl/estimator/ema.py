"""The deployment post-filter: a causal exponential moving average with spike gating.

One incremental, batched code path, used offline (tau sweeps over test flights, by scanning)
and online (the ``WindEstimate`` transform, one 10 Hz sample at a time)::

    innovation e = x - y_prev
    gain       g = (1 - exp(-dt / tau)) * min(1, k * s / |e|)      (k = 3)
    y          = y_prev + g e
    scale      s = s + (1 - exp(-dt / tau_s)) (min(|e|, k s) - s)

``s`` is the running scale of the innovation magnitude (clipped innovations feed it, so one spike
cannot inflate it); when an innovation exceeds ``k`` times that scale the step is attenuated to
the size of a ``k s`` innovation. The first sample initialises the output, and the scale starts
from ``initial_scale`` (in the signal's units). ``tau = 0`` passes the input through (raw).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


#: the paper's deployed time constant: the env's ``ema_tau_s`` unless one is chosen (the PPO recipes
#: train with the tau chosen on the estimator's validation flights, ``rl.envs.validated_tau_s``)
DEFAULT_TAU_S = 3.0


@dataclass(frozen=True)
class EMAConfig:
    tau_s: float = DEFAULT_TAU_S  # 0 passes the raw estimate through
    dt_s: float = 0.1  # the 10 Hz flight record
    spike_factor: float = 3.0  # paper: gate innovations beyond 3x the running scale
    scale_tau_s: float = 10.0  # ours: how fast the innovation scale adapts
    initial_scale: float = 1.0  # m/s

    def __post_init__(self):
        for name in ("tau_s", "dt_s", "spike_factor", "scale_tau_s", "initial_scale"):
            value = getattr(self, name)
            if not (value >= 0 if name == "tau_s" else value > 0):
                raise ValueError(f"EMAConfig.{name}={value!r}; allowed: {'>= 0' if name == 'tau_s' else '> 0'}")


def ema_init(batch: int, channels: int, device: torch.device | str | None = None) -> dict[str, Tensor]:
    return {
        "value": torch.zeros(batch, channels, device=device),
        "scale": torch.zeros(batch, 1, device=device),
        "started": torch.zeros(batch, 1, dtype=torch.bool, device=device),
    }


def ema_reset_rows(state: dict[str, Tensor], mask: Tensor) -> dict[str, Tensor]:
    """Forget rows ``mask`` (bool ``[N]``): their next sample starts them afresh."""
    return {**state, "started": state["started"] & ~mask.reshape(-1, 1)}


def ema_step(state: dict[str, Tensor], x: Tensor, cfg: EMAConfig) -> tuple[dict[str, Tensor], Tensor]:
    """Filter one sample ``x`` ``[N, C]``; returns the new state and the filtered value."""
    if cfg.tau_s <= 0:
        return {**state, "value": x, "started": torch.ones_like(state["started"])}, x
    alpha = 1.0 - math.exp(-cfg.dt_s / cfg.tau_s)
    beta = 1.0 - math.exp(-cfg.dt_s / cfg.scale_tau_s)
    started = state["started"]
    prev = torch.where(started, state["value"], x)
    scale = torch.where(started, state["scale"], torch.full_like(state["scale"], cfg.initial_scale))
    innovation = x - prev
    size = innovation.norm(dim=-1, keepdim=True)
    limit = cfg.spike_factor * scale
    gate = torch.where(size > limit, limit / size.clamp_min(1e-12), 1.0)
    value = prev + alpha * gate * innovation
    scale = scale + beta * (torch.minimum(size, limit) - scale)
    return {"value": value, "scale": scale, "started": torch.ones_like(started)}, value


def ema_scan(x: Tensor, cfg: EMAConfig) -> Tensor:
    """Filter whole sequences ``[N, T, C]`` with the same step the online transform uses."""
    state = ema_init(x.shape[0], x.shape[-1], x.device)
    out = []
    for t in range(x.shape[1]):
        state, y = ema_step(state, x[:, t], cfg)
        out.append(y)
    return torch.stack(out, 1)
