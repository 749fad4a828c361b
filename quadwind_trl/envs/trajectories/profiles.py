"""Smooth time profiles shared by every pattern: the speed ramp from hover and the climb."""
from __future__ import annotations

import torch
from torch import Tensor


def smoothstep(x: Tensor) -> Tensor:
    x = x.clamp(0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def ramp_integral(t: Tensor, tau: float) -> Tensor:
    """Integral of ``smoothstep(t / tau)``: 0 before 0, ``t - tau / 2`` after ``tau``."""
    x = (t / tau).clamp(0.0, 1.0)
    inside = tau * x**3 * (1.0 - 0.5 * x)
    return torch.where(t > tau, t - 0.5 * tau, inside)


def _ramp_derivatives(t: Tensor, tau: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """``ramp_integral`` and its first three time derivatives (the last is zero outside)."""
    x = t / tau
    inside = (x > 0) & (x < 1)
    xc = x.clamp(0.0, 1.0)
    d1 = xc * xc * (3.0 - 2.0 * xc)
    d2 = torch.where(inside, 6.0 * xc * (1.0 - xc) / tau, 0.0)
    d3 = torch.where(inside, (6.0 - 12.0 * xc) / tau**2, 0.0)
    return ramp_integral(t, tau), d1, d2, d3


def climb_profile(t: Tensor, height: Tensor, rate: float, blend: float) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Altitude, climb rate, acceleration and jerk of a smooth climb from 0 to ``height``.

    Constant rate ``rate`` with smoothstep blends of ``blend`` seconds at both ends; reaches
    ``height`` at ``height / rate + blend``. Works on ``[N]`` tensors (batched altitudes).
    """
    duration = height / rate
    # the blends into and out of the climb side by side, the four quantities stacked: one
    # evaluation of the (elementwise) ramp for both, not one per blend and per quantity
    up, down = torch.stack(_ramp_derivatives(torch.stack((t, t - duration), -1), blend), -1).unbind(-2)
    return (rate * (up - down)).unbind(-1)  # type: ignore[return-value]
