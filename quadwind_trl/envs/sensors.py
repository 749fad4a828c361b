"""The onboard sensor suite: per-instrument rate, white noise and random-walk bias.

Sixteen measured channels, packed in this order (``SENSOR_CHANNELS``):

=========  ====  ====================================  =========
channels   rate  quantity                              frame
=========  ====  ====================================  =========
0-2        10    GPS position (m)                      world ENU
3-5        10    GPS velocity (m/s)                    world ENU
6          25    barometric altitude (m)               -
7-9        50    attitude: roll, pitch, yaw (rad)      Z-Y-X Euler
10-12      200   gyro: body rates (rad/s)              body FLU
13-15      200   accelerometer: specific force (m/s2)  body FLU
=========  ====  ====================================  =========

Everything is evaluated at control instants (100 Hz). A sensor of rate ``f <= 100 Hz`` samples
at the control steps ``k`` with ``k % (100 / f) == 0`` and its value is held in between (zero-order
hold); the 200 Hz instruments sample at every control step (the samples in between would be
overwritten before anything reads them, so only their bias walk matters and it is accumulated
over the whole interval). Noise and bias increments come from the counter-based hash of
``(sensor_seed, step, channel)``, so an episode's sensor stream is a function of its seed only.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

from ..config import SensorConfig, SensorChannelConfig
from .counter_rng import hash_normal

SENSOR_CHANNELS = (
    "gps_x", "gps_y", "gps_z",
    "gps_vx", "gps_vy", "gps_vz",
    "baro_alt",
    "roll", "pitch", "yaw",
    "gyro_x", "gyro_y", "gyro_z",
    "accel_x", "accel_y", "accel_z",
)  # fmt: skip
NUM_SENSOR_CHANNELS = len(SENSOR_CHANNELS)
_YAW = 9
_STREAM_SENSORS = 201


class SensorSuite:
    def __init__(self, cfg: SensorConfig, control_dt_s: float, device: torch.device | str | None = None):
        self.cfg = cfg
        per_channel: list[SensorChannelConfig] = (
            [cfg.gps_pos] * 3 + [cfg.gps_vel] * 3 + [cfg.baro_alt]
            + [cfg.attitude_rp] * 2 + [cfg.attitude_yaw] + [cfg.gyro] * 3 + [cfg.accel] * 3
        )  # fmt: skip
        control_hz = 1.0 / control_dt_s
        periods = []
        for name, ch in zip(SENSOR_CHANNELS, per_channel):
            ratio = control_hz / ch.rate_hz
            if ratio >= 1 and abs(ratio - round(ratio)) > 1e-6:
                raise ValueError(f"SensorConfig: {name} at {ch.rate_hz} Hz does not divide the {control_hz:.0f} Hz control rate")
            periods.append(max(1, round(ratio)))
        self.period = torch.tensor(periods, dtype=torch.int64, device=device)
        self.noise_std = torch.tensor([ch.noise_std for ch in per_channel], dtype=torch.float32, device=device)
        self.bias_step_std = torch.tensor(
            [ch.bias_walk_std_per_sqrt_s * math.sqrt(p * control_dt_s) for ch, p in zip(per_channel, periods)],
            dtype=torch.float32,
            device=device,
        )

    def ticks(self, step: Tensor, channel: int) -> Tensor:
        """bool ``[N, 1]``: whether ``channel``'s instrument delivers a new sample at ``step``."""
        return (step % self.period[channel] == 0).unsqueeze(-1)

    def init_state(self, sensor_seed: Tensor) -> dict[str, Tensor]:
        n = sensor_seed.shape[0]
        zeros = torch.zeros(n, NUM_SENSOR_CHANNELS, device=sensor_seed.device)
        return {"seed": sensor_seed, "bias": zeros, "held": zeros.clone()}

    def measure(
        self, state: dict[str, Tensor], truth: Tensor, step: Tensor, force: Tensor | None = None
    ) -> tuple[Tensor, dict[str, Tensor]]:
        """Measurements ``[N, 16]`` at control step ``step`` ``[N]`` from the true values ``truth``
        ``[N, 16]`` (same channel order). ``force`` (bool ``[N, 1]``) samples every channel, for
        the first measurement of an episode."""
        if not self.cfg.enabled:
            return truth, state
        tick = (step.unsqueeze(-1) % self.period) == 0
        if force is not None:
            tick = tick | force
        draws = hash_normal(state["seed"], step, _STREAM_SENSORS, 2 * NUM_SENSOR_CHANNELS)
        bias = torch.where(tick, state["bias"] + self.bias_step_std * draws[..., NUM_SENSOR_CHANNELS:], state["bias"])
        sample = truth + bias + self.noise_std * draws[..., :NUM_SENSOR_CHANNELS]
        # wrap yaw to [-pi, pi) with a remainder, not atan2(sin, cos): torch's CPU atan2 rounds
        # differently in a kernel's vectorised body and its scalar tail, which made a row's
        # measurement depend on the batch size (tests/test_sensors.py)
        yaw = torch.remainder(sample[..., _YAW : _YAW + 1] + math.pi, 2.0 * math.pi) - math.pi
        sample = torch.cat((sample[..., :_YAW], yaw, sample[..., _YAW + 1 :]), -1)
        held = torch.where(tick, sample, state["held"])
        return held, dict(state, bias=bias, held=held)
