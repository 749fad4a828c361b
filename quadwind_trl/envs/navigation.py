"""A simple navigation filter: what a small autopilot feeds its position controller.

Position and velocity are predicted at the control rate from the accelerometer (the mean of its
samples over the step, rotated to the world with the measured attitude, gravity removed) and pulled towards GPS position and velocity
(10 Hz) and barometric altitude (25 Hz) whenever those sensors deliver a new sample
(complementary filter with fixed gains). The white GPS noise is filtered; its random-walk bias is
not observable without another absolute reference and passes through, as on a real vehicle.
The gains (``NavigationConfig``) are constant: a steady-state filter, tuned for the paper's noise.
Attitude and body rates are taken from the attitude sensor and the gyro as they are.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from ..config import GRAVITY_M_S2, NavigationConfig
from .rotations import rotate, rotmat_from_euler


@dataclass
class NavigationParams:
    pos_gain: float  # fraction of the GPS position innovation applied per GPS sample
    vel_gain: float
    alt_gain: float  # fraction of the barometric innovation applied per baro sample

    @classmethod
    def from_config(cls, cfg: NavigationConfig) -> "NavigationParams":
        return cls(cfg.gps_position_gain, cfg.gps_velocity_gain, cfg.baro_gain)


def init_navigation(meas: Tensor) -> dict[str, Tensor]:
    """Start from the first measurements: GPS horizontal position, baro altitude, GPS velocity."""
    return {"pos": torch.cat((meas[..., 0:2], meas[..., 6:7]), -1), "vel": meas[..., 3:6].clone()}


def update_navigation(
    nav: dict[str, Tensor],
    meas: Tensor,
    accel_mean: Tensor,
    gps_tick: Tensor,
    baro_tick: Tensor,
    p: NavigationParams,
    dt: float,
) -> dict[str, Tensor]:
    """One control step: predict over ``dt`` with ``accel_mean`` ``[N, 3]`` (the body-frame
    accelerometer samples of the step, averaged), then correct with the sensors that ticked
    (bool ``[N, 1]`` masks)."""
    rot = rotmat_from_euler(meas[..., 7:10])
    acc = rotate(rot, accel_mean) - meas.new_tensor([0.0, 0.0, GRAVITY_M_S2])
    vel = nav["vel"] + dt * acc
    pos = nav["pos"] + dt * vel
    pos_xy = torch.where(gps_tick, pos[..., :2] + p.pos_gain * (meas[..., 0:2] - pos[..., :2]), pos[..., :2])
    pos_z = torch.where(baro_tick, pos[..., 2:] + p.alt_gain * (meas[..., 6:7] - pos[..., 2:]), pos[..., 2:])
    vel = torch.where(gps_tick, vel + p.vel_gain * (meas[..., 3:6] - vel), vel)
    return {"pos": torch.cat((pos_xy, pos_z), -1), "vel": vel}
