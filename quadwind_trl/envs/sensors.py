"""The onboard sensor suite: per-instrument rate, white noise and a Gauss-Markov bias.

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

An instrument slower than the 100 Hz control rate samples at the control steps ``k`` with
``k % (100 / f) == 0`` and its value is held in between (zero-order hold). The IMU (gyro and
accelerometer) may run faster, ``m = f / 100`` samples per control step: the simulator hands
:meth:`SensorSuite.measure` the body rate and specific force at the physics substeps nearest
before each intermediate sample instant (at 200 Hz and 500 Hz physics: the 5 ms sample sees the
4 ms state, 1 ms stale, as an IMU read on the last completed integration step would). Every
sample gets its own noise and bias step; the held measurement is the latest sample, and the
navigation filter integrates the mean of the interval's samples (``imu_mean``).

Each bias is a first-order Gauss-Markov process, discretised exactly over its sample interval
``h``: ``b <- exp(-h / tau) b + sigma sqrt(1 - exp(-2 h / tau)) w``, started from its
stationary distribution ``N(0, sigma^2)`` (``tau = inf``: a random walk started at zero, the
``legacy_walk`` preset). Noise, bias steps and the initial biases come from the counter-based hash
of ``(sensor_seed, step, channel)``, so an episode's sensor stream is a function of its seed only.
"""
from __future__ import annotations

import math

import torch
from tensordict import TensorDict
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
_IMU = slice(10, 16)
_NUM_IMU = 6
_STREAM_SENSORS = 201
_STREAM_IMU_SUBSAMPLES = 202
_STREAM_INITIAL_BIAS = 203


def _gauss_markov_step(ch: SensorChannelConfig, h_s: float) -> tuple[float, float]:
    """``(decay, step_std)`` of the exact discretisation over an interval ``h_s``."""
    if math.isinf(ch.bias_corr_time_s):  # the walk: (1, q sqrt(h))
        return 1.0, ch.bias_drive_std_per_sqrt_s * math.sqrt(h_s)
    return math.exp(-h_s / ch.bias_corr_time_s), ch.bias_std * math.sqrt(-math.expm1(-2.0 * h_s / ch.bias_corr_time_s))


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
            if ratio < 1 and not name.startswith(("gyro", "accel")):
                raise ValueError(f"SensorConfig: {name} at {ch.rate_hz} Hz is faster than the {control_hz:.0f} Hz control "
                                 "rate; only the IMU (gyro, accel) may be")
            periods.append(max(1, round(ratio)))
        imu_ratio = cfg.gyro.rate_hz / control_hz
        if imu_ratio > 1 and abs(imu_ratio - round(imu_ratio)) > 1e-6:
            raise ValueError(f"SensorConfig: gyro/accel at {cfg.gyro.rate_hz} Hz must be a whole multiple of the "
                             f"{control_hz:.0f} Hz control rate")
        self.imu_samples_per_step = max(1, round(imu_ratio))
        self.period = torch.tensor(periods, dtype=torch.int64, device=device)
        self.noise_std = torch.tensor([ch.noise_std for ch in per_channel], dtype=torch.float32, device=device)
        steps = [_gauss_markov_step(ch, p * control_dt_s / (self.imu_samples_per_step if 10 <= i < 16 else 1))
                 for i, (ch, p) in enumerate(zip(per_channel, periods))]
        self.bias_decay = torch.tensor([a for a, _ in steps], dtype=torch.float32, device=device)
        self.bias_step_std = torch.tensor([c for _, c in steps], dtype=torch.float32, device=device)
        self.bias_std = torch.tensor([ch.bias_std for ch in per_channel], dtype=torch.float32, device=device)

    def imu_substeps(self, physics_substeps: int) -> tuple[int, ...]:
        """After which physics substeps of a control step (1-based counts) the simulator must
        capture the IMU's truth for the intermediate samples: the last completed one before each
        sample instant ``j / m`` of the step, ``j = 1 .. m - 1``."""
        m = self.imu_samples_per_step
        return tuple(j * physics_substeps // m for j in range(1, m))

    def ticks(self, step: Tensor, channel: int) -> Tensor:
        """bool ``[N, 1]``: whether ``channel``'s instrument delivers a new sample at ``step``."""
        return (step % self.period[channel] == 0).unsqueeze(-1)

    def init(self, sensor_seed: Tensor) -> tuple[TensorDict, TensorDict]:
        """``(params, state)`` of a batch of episodes: the noise seed ``[N]``, and the instruments'
        state (biases from their stationary distribution, nothing held yet)."""
        n = sensor_seed.shape[0]
        zeros = torch.zeros(n, NUM_SENSOR_CHANNELS, device=sensor_seed.device)
        bias = self.bias_std * hash_normal(sensor_seed, 0, _STREAM_INITIAL_BIAS, NUM_SENSOR_CHANNELS)
        params = TensorDict(seed=sensor_seed, batch_size=[n])
        return params, TensorDict(bias=bias, held=zeros, imu_mean=zeros[..., _IMU].clone(), batch_size=[n])

    def measure(
        self,
        params: TensorDict,
        state: TensorDict,
        truth: Tensor,
        step: Tensor,
        force: Tensor | None = None,
        imu_truth_sub: Tensor | None = None,
    ) -> tuple[Tensor, TensorDict]:
        """Measurements ``[N, 16]`` at control step ``step`` ``[N]`` from the true values ``truth``
        ``[N, 16]`` (same channel order). ``force`` (bool ``[N, 1]``) samples every channel, for
        the first measurement of an episode. ``imu_truth_sub`` ``[N, m - 1, 6]``: the true body
        rate and specific force at the IMU's intermediate samples since the last control step
        (only with ``m > 1``; none at an episode's first measurement)."""
        if not self.cfg.enabled:
            return truth, TensorDict(bias=state["bias"], held=state["held"], imu_mean=truth[..., _IMU],
                                     batch_size=state.batch_size)
        tick = (step.unsqueeze(-1) % self.period) == 0
        if force is not None:
            tick = tick | force
        bias = state["bias"]
        imu_sum = None
        if imu_truth_sub is not None:
            # the IMU's intermediate samples, in time order, each with its own noise and bias step
            sub = imu_truth_sub.shape[-2]
            draws = hash_normal(params["seed"], step, _STREAM_IMU_SUBSAMPLES, 2 * _NUM_IMU * sub).unflatten(-1, (sub, 2 * _NUM_IMU))
            imu_bias, imu_sum = bias[..., _IMU], 0.0
            for j in range(sub):
                imu_bias = self.bias_decay[_IMU] * imu_bias + self.bias_step_std[_IMU] * draws[..., j, _NUM_IMU:]
                imu_sum = imu_sum + imu_truth_sub[..., j, :] + imu_bias + self.noise_std[_IMU] * draws[..., j, :_NUM_IMU]
            bias = torch.cat((bias[..., :10], imu_bias), -1)
        draws = hash_normal(params["seed"], step, _STREAM_SENSORS, 2 * NUM_SENSOR_CHANNELS)
        stepped = self.bias_decay * bias + self.bias_step_std * draws[..., NUM_SENSOR_CHANNELS:]
        bias = torch.where(tick, stepped, bias)
        sample = truth + bias + self.noise_std * draws[..., :NUM_SENSOR_CHANNELS]
        # wrap yaw to [-pi, pi) with a remainder, not atan2(sin, cos): torch's CPU atan2 rounds
        # differently in a kernel's vectorised body and its scalar tail, which made a row's
        # measurement depend on the batch size (tests/test_sensors.py)
        yaw = torch.remainder(sample[..., _YAW : _YAW + 1] + math.pi, 2.0 * math.pi) - math.pi
        sample = torch.cat((sample[..., :_YAW], yaw, sample[..., _YAW + 1 :]), -1)
        held = torch.where(tick, sample, state["held"])
        imu_mean = held[..., _IMU] if imu_sum is None else (imu_sum + held[..., _IMU]) / self.imu_samples_per_step
        return held, TensorDict(bias=bias, held=held, imu_mean=imu_mean, batch_size=state.batch_size)
