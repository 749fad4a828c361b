"""The estimator's training loss (paper, Section "Architecture").

    L = Huber(z_hat, z)                                  standardised (north, east), mean over both
      + 0.03 * sum_i w_i Huber_1(|v_hat_i| - |v_i|) / sum_i w_i        speed, m/s
      + 0.05 * sum_i w_i angle(v_hat_i, v_i)       / sum_i w_i        direction, rad

``z`` are the standardised labels the network regresses, ``v = z * std + mean`` the same winds in
physical units (m/s). The two auxiliary terms are in those units.

**Weighting toward higher wind speeds** (the paper gives no formula; ours): each window's
auxiliary terms are weighted by its *true* wind speed, ``w_i = |v_i|`` (m/s), and normalised by
the batch's total weight, so the terms stay a weighted *mean* whatever the batch's speeds are
(a batch whose windows all have the same speed gets the plain mean). Why linear in speed:

* the wind direction is undefined at zero wind and the angle error of a weak wind is dominated by
  turbulence (a 1 m/s gust turns a 2 m/s wind by 30 degrees): ``w -> 0`` there removes an
  ill-posed, noisy target without a threshold;
* the drag cue grows with the square of the relative wind, so strong winds are where the
  estimate can be sharp, and where the controller needs it;
* the component Huber term already covers every window equally, weak winds included.

The direction term is the unsigned angle between the estimate and the label,
``atan2(|v_hat x v|, v_hat . v)`` in radians (in [0, pi]), with ``|cross|`` smoothed as
``sqrt(c^2 + eps^2) - eps`` so the gradient is finite at a perfect estimate. Windows whose true
speed is below ``min_direction_speed`` (0.1 m/s) are left out of it (their weight is ~0 anyway).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor
from torch.nn import functional as F


@dataclass(frozen=True)
class EstimatorLossConfig:
    huber_beta: float = 1.0  # standardised units
    speed_weight: float = 0.03  # paper
    direction_weight: float = 0.05  # paper
    speed_huber_beta_m_s: float = 1.0  # ours
    speed_weighting: str = "linear"  # "linear": w = |v| (ours); "none": w = 1
    min_direction_speed_m_s: float = 0.1
    angle_eps: float = 1e-3  # m^2/s^2, smoothing of |cross|

    def __post_init__(self):
        if self.speed_weighting not in ("linear", "none"):
            raise ValueError(f"EstimatorLossConfig.speed_weighting={self.speed_weighting!r}; allowed: 'linear', 'none'")
        if self.speed_weight < 0 or self.direction_weight < 0:
            raise ValueError("EstimatorLossConfig.speed_weight and direction_weight must be >= 0")


def wind_angle(pred: Tensor, true: Tensor, eps: float = 0.0) -> Tensor:
    """Unsigned angle (rad, [0, pi]) between 2-vectors ``[..., 2]``; ``eps`` smooths ``|cross|``."""
    cross = pred[..., 0] * true[..., 1] - pred[..., 1] * true[..., 0]
    dot = (pred * true).sum(-1)
    abs_cross = (cross * cross + eps * eps).sqrt() - eps if eps > 0 else cross.abs()
    return torch.atan2(abs_cross, dot)


def speed_weights(true: Tensor, mode: str = "linear") -> Tensor:
    """Per-window weight of the auxiliary terms: the true wind speed (``"linear"``) or 1."""
    speed = true.norm(dim=-1)
    return speed if mode == "linear" else torch.ones_like(speed)


class EstimatorLoss(torch.nn.Module):
    """``forward(pred_std, label_std) -> (loss, terms)``; ``terms`` holds the detached parts
    (``huber``, ``speed``, ``direction``: the unweighted-by-coefficient term values)."""

    def __init__(self, label_mean: Tensor, label_std: Tensor, cfg: EstimatorLossConfig = EstimatorLossConfig()):
        super().__init__()
        self.cfg = cfg
        self.register_buffer("label_mean", torch.as_tensor(label_mean, dtype=torch.float32).reshape(2))
        self.register_buffer("label_std", torch.as_tensor(label_std, dtype=torch.float32).reshape(2))

    def forward(self, pred_std: Tensor, label_std: Tensor) -> tuple[Tensor, dict[str, Tensor]]:
        cfg = self.cfg
        huber = F.smooth_l1_loss(pred_std, label_std, beta=cfg.huber_beta)
        pred = pred_std * self.label_std + self.label_mean
        true = label_std * self.label_std + self.label_mean
        w = speed_weights(true, cfg.speed_weighting)
        total_w = w.sum().clamp_min(1e-6)
        speed_err = pred.norm(dim=-1) - true.norm(dim=-1)
        speed = (w * F.smooth_l1_loss(speed_err, torch.zeros_like(speed_err), beta=cfg.speed_huber_beta_m_s, reduction="none")).sum() / total_w
        keep = true.norm(dim=-1) >= cfg.min_direction_speed_m_s
        wd = torch.where(keep, w, torch.zeros_like(w))
        angle = wind_angle(pred, true, cfg.angle_eps)
        direction = (wd * torch.where(keep, angle, torch.zeros_like(angle))).sum() / wd.sum().clamp_min(1e-6)
        loss = huber + cfg.speed_weight * speed + cfg.direction_weight * direction
        return loss, {"huber": huber.detach(), "speed": speed.detach(), "direction": direction.detach()}
