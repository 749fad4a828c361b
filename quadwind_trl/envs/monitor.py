"""The runtime monitor (:class:`~quadwind_trl.config.MonitorConfig`): the PD cascade alone while
the vehicle is near its limits, as a pure, branch-free tensor function of one control step.

Each control step, from what the autopilot knows at step ``k`` (the attitude and position the PD
flies on) and the command the residual would give::

    near = tilt > max_tilt + margin  |  T_pd + T_ff >= fraction * T_max  |  z_ref - z > drop
    left = hold + 1  if near  else  max(left - 1, 0)
    ff   = 0         if left > 0  else  ff

so the residual is zero from the first step near a limit (not through the smoothing and slew
limit: handing back must be immediate) until ``hold`` steps after the last one; the zero is the
smoother's previous value, so the residual then comes back from zero at the slew limit. ``left``
(int64 ``[N, 1]``, the state's ``("control", "monitor_left")``) is positive exactly on the steps
the monitor held the residual at zero.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..config import ControllerConfig, MonitorConfig
from .vehicle import VehicleParams


@dataclass(frozen=True)
class MonitorParams:
    """The monitor's thresholds in the units the step works in."""

    cos_tilt_min: float  # cosine of the largest tilt from vertical allowed
    thrust_max: float  # N, total commanded thrust at or above which the rotors are at their limit
    height_drop: float | None  # m below the reference; None: not checked
    hold_steps: int  # control steps of PD alone after the last one near a limit

    @classmethod
    def from_config(cls, cfg: MonitorConfig, controller: ControllerConfig, vehicle: VehicleParams,
                    control_dt_s: float) -> "MonitorParams":
        cfg.validate()
        return cls(
            cos_tilt_min=math.cos(math.radians(controller.max_tilt_deg + cfg.tilt_margin_deg)),
            thrust_max=cfg.thrust_fraction * vehicle.collective_limit,
            height_drop=cfg.height_below_ref_m,
            hold_steps=round(cfg.hold_s / control_dt_s),
        )


def monitor_gate(ff: Tensor, thrust_cmd: Tensor, cos_tilt: Tensor, height_error: Tensor, left: Tensor,
                 p: MonitorParams) -> tuple[Tensor, Tensor]:
    """``(ff applied, steps left)`` for one control step: ``ff`` ``[N, 4]`` the smoothed, slew-limited
    residual; ``thrust_cmd`` ``[N, 1]`` the PD thrust plus ``ff``'s (N); ``cos_tilt`` ``[N, 1]`` the
    cosine of the tilt from vertical; ``height_error`` ``[N, 1]`` altitude minus the reference's (m);
    ``left`` ``[N, 1]`` int64 the steps left from the previous step."""
    near = (cos_tilt < p.cos_tilt_min) | (thrust_cmd >= p.thrust_max)
    if p.height_drop is not None:  # a config constant: no branch on a tensor
        near = near | (height_error < -p.height_drop)
    left = torch.where(near, p.hold_steps + 1, (left - 1).clamp_min(0))
    return torch.where(left > 0, 0.0, ff), left
