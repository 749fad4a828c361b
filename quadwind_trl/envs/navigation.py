"""A simple navigation filter: what a small autopilot feeds its position controller.

Position and velocity are predicted at the control rate from the accelerometer (the mean of its
samples over the step, rotated to the world with the measured attitude, gravity removed) and pulled towards GPS position and velocity
(10 Hz) and barometric altitude (25 Hz) whenever those sensors deliver a new sample
(complementary filter with fixed gains). The white noise is filtered; the GNSS biases are not
observable without another absolute reference and pass through, as on a real vehicle. The
altitude's anchor is ``NavigationConfig.height_reference``: the barometer (its bias passes
through) or the GNSS height (the barometer's offset is then estimated against it and removed).
The gains (``NavigationConfig``) are constant: a steady-state filter, tuned for the paper's noise.
Attitude and body rates are taken from the attitude sensor and the gyro as they are.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict
from torch import Tensor

from ..config import GRAVITY_M_S2, NavigationConfig
from .rotations import euler_to_rotmat, rotate
from .tensordicts import entry, unchecked


@dataclass
class NavigationParams:
    pos_gain: float  # fraction of the GPS position innovation applied per GPS sample
    vel_gain: float
    alt_gain: float  # fraction of the barometric innovation applied per baro sample
    gnss_height: bool  # the GNSS height anchors the altitude (else the barometer does)
    gnss_height_gain: float  # per GPS sample
    baro_offset_gain: float  # per baro sample

    @classmethod
    def from_config(cls, cfg: NavigationConfig) -> "NavigationParams":
        return cls(cfg.gps_position_gain, cfg.gps_velocity_gain, cfg.baro_gain, cfg.height_reference == "gnss",
                   cfg.gnss_height_gain, cfg.baro_offset_gain)


def init_navigation(meas: TensorDict) -> TensorDict:
    """The solution read straight off the measurements (``meas``: the sensors' named entries; the
    filter's start, and the ``feedback="sensors"`` autopilot): GPS horizontal position, baro
    altitude, GPS velocity, and a zero barometer offset (its expected value)."""
    baro = meas["baro_alt"]
    return unchecked(meas.batch_size, dict(pos=torch.cat((meas["gps_pos"][..., :2], baro), -1), vel=meas["gps_vel"].clone(),
                                           baro_offset=torch.zeros_like(baro)))


def update_navigation(
    nav: TensorDict,
    meas: TensorDict,
    accel_mean: Tensor,
    gps_tick: Tensor,
    baro_tick: Tensor,
    p: NavigationParams,
    dt: float,
    rot: Tensor | None = None,
) -> TensorDict:
    """One control step: predict over ``dt`` with ``accel_mean`` ``[N, 3]`` (the body-frame
    accelerometer samples of the step, averaged), then correct with the sensors (``meas``: their
    named entries) that ticked (bool ``[N, 1]`` masks). ``rot``: the measured attitude's rotation
    matrix, if the caller has it already (it is computed from ``meas`` otherwise)."""
    gps_pos, gps_vel, baro = entry(meas, "gps_pos"), entry(meas, "gps_vel"), entry(meas, "baro_alt")
    if rot is None:
        rot = euler_to_rotmat(entry(meas, "attitude"))
    acc = rotate(rot, accel_mean) - accel_mean.new_tensor([0.0, 0.0, GRAVITY_M_S2])
    vel = entry(nav, "vel") + dt * acc
    pos = entry(nav, "pos") + dt * vel
    pos_xy = torch.where(gps_tick, pos[..., :2] + p.pos_gain * (gps_pos[..., :2] - pos[..., :2]), pos[..., :2])
    pos_z, offset = pos[..., 2:], entry(nav, "baro_offset")
    if p.gnss_height:
        offset = torch.where(baro_tick, offset + p.baro_offset_gain * (baro - pos_z - offset), offset)
        pos_z = torch.where(baro_tick, pos_z + p.alt_gain * (baro - offset - pos_z), pos_z)
        pos_z = torch.where(gps_tick, pos_z + p.gnss_height_gain * (gps_pos[..., 2:] - pos_z), pos_z)
    else:
        pos_z = torch.where(baro_tick, pos_z + p.alt_gain * (baro - pos_z), pos_z)
    vel = torch.where(gps_tick, vel + p.vel_gain * (gps_vel - vel), vel)
    return unchecked(nav.batch_size, dict(pos=torch.cat((pos_xy, pos_z), -1), vel=vel, baro_offset=offset))
