"""The onboard sensor suite: per-instrument rate, white noise and a Gauss-Markov bias.

The instruments are the rows of :data:`INSTRUMENTS`; everything else (the measurement
entries, their widths, rates, noise and biases, the env's observation spec) derives from it.
:meth:`SensorSuite.measure` returns the measurements as a TensorDict of named entries, the env's
``"meas"`` observation (``keys.MEAS_KEY``):

============  =====  ====  ====================================  ===============================
entry         width  rate  quantity (``SensorConfig`` field)     frame, unit
============  =====  ====  ====================================  ===============================
``gps_pos``   3      10    GPS position (``gps_pos``)            world ENU (x, y, z), m
``gps_vel``   3      10    GPS velocity (``gps_vel``)            world ENU, m/s
``baro_alt``  1      25    barometric altitude (``baro_alt``)    height above the ground, m
``attitude``  3      50    roll, pitch (``attitude_rp``), yaw    Z-Y-X Euler, rad; yaw from east,
                           (``attitude_yaw``)                    CCW, wrapped to [-pi, pi)
``gyro``      3      200   body rates (``gyro``)                 body FLU (p, q, r), rad/s
``accel``     3      200   specific force (``accel``)            body FLU, m/s^2
============  =====  ====  ====================================  ===============================

An instrument slower than the 100 Hz control rate samples at the control steps ``k`` with
``k % (100 / f) == 0`` and its value is held in between (zero-order hold). The IMU (the ``imu``
rows: gyro and accelerometer) may run faster, ``m = f / 100`` samples per control step: the
simulator hands :meth:`SensorSuite.measure` the body rate and specific force at the physics
substeps nearest before each intermediate sample instant (at 200 Hz and 500 Hz physics: the 5 ms
sample sees the 4 ms state, 1 ms stale, as an IMU read on the last completed integration step
would). Every sample gets its own noise and bias step; the held measurement is the latest
sample, and the navigation filter integrates the mean of the interval's samples
(:meth:`SensorSuite.imu_mean`).

Each bias is a first-order Gauss-Markov process, discretised exactly over its sample interval
``h``: ``b <- exp(-h / tau) b + sigma sqrt(1 - exp(-2 h / tau)) w``, started from its
stationary distribution ``N(0, sigma^2)`` (``tau = inf``: a random walk started at zero, the
``legacy_walk`` preset). Noise, bias steps and the initial biases come from the counter-based hash
of ``(sensor_seed, step, channel)``, so an episode's sensor stream is a function of its seed only.
Internally the suite keeps the channels packed in table order (one vectorised noise and bias
step); that packing is the channel index of the hash, so the table's row order is part of the
physics (appending a row changes the draw layout of every channel: a new calibration).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDict
from torch import Tensor

from ..config import SensorChannelConfig, SensorConfig
from .counter_rng import hash_normal, keyed_normal, stream_key
from .tensordicts import entry, unchecked


@dataclass(frozen=True)
class Instrument:
    """One row of the sensor table: a named measurement entry of ``len(components)`` channels."""

    name: str  # the entry's key in the measurement TensorDict
    components: tuple[str, ...]  # channel names, in the entry's last dimension
    config: tuple[str, ...]  # the SensorConfig field of each component (rate, noise, bias)
    frame: str  # frame and unit (documentation)
    imu: bool = False  # sampled by the IMU: may run faster than the control rate (sub-samples)
    wrapped: tuple[str, ...] = ()  # angle components wrapped to [-pi, pi)

    @property
    def width(self) -> int:
        return len(self.components)


def _row(name: str, components: tuple[str, ...], field: str, frame: str, **kw) -> Instrument:
    """A row whose components all share one ``SensorConfig`` field."""
    return Instrument(name, components, (field,) * len(components), frame, **kw)


#: the instruments, in packed channel order (the hash's channel index: see the module doc)
INSTRUMENTS: tuple[Instrument, ...] = (
    _row("gps_pos", ("x", "y", "z"), "gps_pos", "world ENU, m"),
    _row("gps_vel", ("x", "y", "z"), "gps_vel", "world ENU, m/s"),
    _row("baro_alt", ("alt",), "baro_alt", "height above the ground, m"),
    Instrument("attitude", ("roll", "pitch", "yaw"), ("attitude_rp", "attitude_rp", "attitude_yaw"),
               "Z-Y-X Euler, rad (yaw from east, CCW)", wrapped=("yaw",)),
    _row("gyro", ("p", "q", "r"), "gyro", "body FLU, rad/s", imu=True),
    _row("accel", ("x", "y", "z"), "accel", "body FLU specific force, m/s^2", imu=True),
)  # fmt: skip
SENSOR_NAMES: tuple[str, ...] = tuple(i.name for i in INSTRUMENTS)
#: the packed channels, ``"entry.component"`` (error messages, per-channel statistics)
CHANNEL_NAMES: tuple[str, ...] = tuple(f"{i.name}.{c}" for i in INSTRUMENTS for c in i.components)
_BY_NAME: dict[str, Instrument] = {i.name: i for i in INSTRUMENTS}
_OFFSET: dict[str, int] = {i.name: sum(j.width for j in INSTRUMENTS[:k]) for k, i in enumerate(INSTRUMENTS)}
_NUM_CHANNELS = len(CHANNEL_NAMES)
_IMU_NAMES = tuple(i.name for i in INSTRUMENTS if i.imu)
# the IMU's channels are one contiguous block: its sub-sample stream draws them as one vector
_IMU = slice(_OFFSET[_IMU_NAMES[0]], _OFFSET[_IMU_NAMES[-1]] + _BY_NAME[_IMU_NAMES[-1]].width)
assert _IMU.stop - _IMU.start == sum(_BY_NAME[n].width for n in _IMU_NAMES), "IMU rows must be adjacent in INSTRUMENTS"
_NUM_IMU = _IMU.stop - _IMU.start
_STREAM_SENSORS = 201
_STREAM_IMU_SUBSAMPLES = 202
_STREAM_INITIAL_BIAS = 203


def sensor_widths() -> dict[str, int]:
    """``{entry: width}`` of the measurement TensorDict, in table order."""
    return {i.name: i.width for i in INSTRUMENTS}


def pack_channels(entries: TensorDict | dict[str, Tensor], names: tuple[str, ...] = SENSOR_NAMES) -> Tensor:
    """The named entries ``names`` concatenated along the last dimension, in that order."""
    return torch.cat([entries[name] if isinstance(entries, dict) else entry(entries, name) for name in names], -1)


def unpack_channels(packed: Tensor, names: tuple[str, ...] = SENSOR_NAMES) -> TensorDict:
    """Named entries (views of ``packed``) of channels packed in the order of ``names``."""
    parts = packed.split([_BY_NAME[name].width for name in names], -1)
    return unchecked(packed.shape[:-1], dict(zip(names, parts)))


def _gauss_markov_step(ch: SensorChannelConfig, h_s: float) -> tuple[float, float]:
    """``(decay, step_std)`` of the exact discretisation over an interval ``h_s``."""
    if math.isinf(ch.bias_corr_time_s):  # the walk: (1, q sqrt(h))
        return 1.0, ch.bias_drive_std_per_sqrt_s * math.sqrt(h_s)
    return math.exp(-h_s / ch.bias_corr_time_s), ch.bias_std * math.sqrt(-math.expm1(-2.0 * h_s / ch.bias_corr_time_s))


class SensorSuite:
    def __init__(self, cfg: SensorConfig, control_dt_s: float, device: torch.device | str | None = None):
        self.cfg = cfg
        control_hz = 1.0 / control_dt_s
        imu_hz = getattr(cfg, _BY_NAME[_IMU_NAMES[0]].config[0]).rate_hz
        imu_ratio = imu_hz / control_hz
        if imu_ratio > 1 and abs(imu_ratio - round(imu_ratio)) > 1e-6:
            raise ValueError(f"SensorConfig: the IMU ({', '.join(_IMU_NAMES)}) at {imu_hz} Hz must be a whole multiple "
                             f"of the {control_hz:.0f} Hz control rate")
        self.imu_samples_per_step = max(1, round(imu_ratio))
        per_channel: list[SensorChannelConfig] = []
        periods, intervals = [], []
        for ins in INSTRUMENTS:
            for component, field in zip(ins.components, ins.config):
                ch: SensorChannelConfig = getattr(cfg, field)
                ratio = control_hz / ch.rate_hz
                label = f"{ins.name}.{component} (SensorConfig.{field})"
                if ratio >= 1 and abs(ratio - round(ratio)) > 1e-6:
                    raise ValueError(f"{label} at {ch.rate_hz} Hz does not divide the {control_hz:.0f} Hz "
                                     "control rate")
                if ratio < 1 and not ins.imu:
                    raise ValueError(f"{label} at {ch.rate_hz} Hz is faster than the {control_hz:.0f} Hz "
                                     f"control rate; only the IMU ({', '.join(_IMU_NAMES)}) may be")
                period = max(1, round(ratio))
                per_channel.append(ch)
                periods.append(period)
                # an IMU channel's bias steps once per sub-sample
                intervals.append(period * control_dt_s / (self.imu_samples_per_step if ins.imu else 1))
        self.period = torch.tensor(periods, dtype=torch.int64, device=device)
        self.noise_std = torch.tensor([ch.noise_std for ch in per_channel], dtype=torch.float32, device=device)
        steps = [_gauss_markov_step(ch, h) for ch, h in zip(per_channel, intervals)]
        self.bias_decay = torch.tensor([a for a, _ in steps], dtype=torch.float32, device=device)
        self.bias_step_std = torch.tensor([c for _, c in steps], dtype=torch.float32, device=device)
        self.bias_std = torch.tensor([ch.bias_std for ch in per_channel], dtype=torch.float32, device=device)
        wrapped = [c in ins.wrapped for ins in INSTRUMENTS for c in ins.components]
        self.wrapped = torch.tensor(wrapped, dtype=torch.bool, device=device)

    def imu_substeps(self, physics_substeps: int) -> tuple[int, ...]:
        """After which physics substeps of a control step (1-based counts) the simulator must
        capture the IMU's truth for the intermediate samples: the last completed one before each
        sample instant ``j / m`` of the step, ``j = 1 .. m - 1``."""
        m = self.imu_samples_per_step
        return tuple(j * physics_substeps // m for j in range(1, m))

    def ticks(self, step: Tensor, name: str) -> Tensor:
        """bool ``[N, 1]``: whether instrument ``name`` delivers a new sample at ``step``."""
        return (step % self.period[_OFFSET[name]] == 0).unsqueeze(-1)

    def imu_mean(self, state: TensorDict, name: str) -> Tensor:
        """The mean of IMU instrument ``name``'s samples over the last control step."""
        start = _OFFSET[name] - _IMU.start
        return entry(state, "imu_mean")[..., start : start + _BY_NAME[name].width]

    def init(self, sensor_seed: Tensor) -> tuple[TensorDict, TensorDict]:
        """``(params, state)`` of a batch of episodes: the noise seed ``[N]`` and its hash keys of
        the per-step noise streams (an episode's constants, hashed once), and the instruments'
        state (biases from their stationary distribution, nothing held yet), channels packed."""
        n = sensor_seed.shape[0]
        zeros = torch.zeros(n, _NUM_CHANNELS, device=sensor_seed.device)
        bias = self.bias_std * hash_normal(sensor_seed, 0, _STREAM_INITIAL_BIAS, _NUM_CHANNELS)
        params = TensorDict(seed=sensor_seed, noise_key=stream_key(sensor_seed, _STREAM_SENSORS),
                            imu_noise_key=stream_key(sensor_seed, _STREAM_IMU_SUBSAMPLES), batch_size=[n])
        return params, TensorDict(bias=bias, held=zeros, imu_mean=zeros[..., _IMU].clone(), batch_size=[n])

    def measure(
        self,
        params: TensorDict,
        state: TensorDict,
        truth: TensorDict,
        step: Tensor,
        force: Tensor | None = None,
        imu_truth_sub: TensorDict | None = None,
    ) -> tuple[TensorDict, TensorDict]:
        """``(measurements, state)`` at control step ``step`` ``[N]``: the measurements are named
        entries (:data:`INSTRUMENTS`) of the true values ``truth`` (the same entries). ``force``
        (bool ``[N, 1]``) samples every channel, for the first measurement of an episode.
        ``imu_truth_sub`` (batch ``[N, m - 1]``): the true entries of the IMU instruments at the
        IMU's intermediate samples since the last control step (only with ``m > 1``; none at an
        episode's first measurement)."""
        truth_packed = pack_channels(truth)
        if not self.cfg.enabled:
            return unpack_channels(truth_packed), unchecked(
                state.batch_size, dict(bias=entry(state, "bias"), held=entry(state, "held"),
                                       imu_mean=truth_packed[..., _IMU]))
        tick = (step.unsqueeze(-1) % self.period) == 0
        if force is not None:
            tick = tick | force
        bias = entry(state, "bias")
        imu_sum = None
        if imu_truth_sub is not None:
            # the IMU's intermediate samples, in time order, each with its own noise and bias step
            imu_truth = pack_channels(imu_truth_sub, _IMU_NAMES)
            sub = imu_truth.shape[-2]
            draws = keyed_normal(entry(params, "imu_noise_key"), step, 2 * _NUM_IMU * sub)
            draws = draws.unflatten(-1, (sub, 2 * _NUM_IMU))
            imu_bias, imu_sum = bias[..., _IMU], 0.0
            for j in range(sub):
                imu_bias = self.bias_decay[_IMU] * imu_bias + self.bias_step_std[_IMU] * draws[..., j, _NUM_IMU:]
                imu_sum = imu_sum + imu_truth[..., j, :] + imu_bias + self.noise_std[_IMU] * draws[..., j, :_NUM_IMU]
            bias = torch.cat((bias[..., : _IMU.start], imu_bias, bias[..., _IMU.stop :]), -1)
        draws = keyed_normal(entry(params, "noise_key"), step, 2 * _NUM_CHANNELS)
        stepped = self.bias_decay * bias + self.bias_step_std * draws[..., _NUM_CHANNELS:]
        bias = torch.where(tick, stepped, bias)
        sample = truth_packed + bias + self.noise_std * draws[..., :_NUM_CHANNELS]
        # wrap angles to [-pi, pi) with a remainder, not atan2(sin, cos): torch's CPU atan2 rounds
        # differently in a kernel's vectorised body and its scalar tail, which made a row's
        # measurement depend on the batch size (tests/test_sensors.py)
        sample = torch.where(self.wrapped, torch.remainder(sample + math.pi, 2.0 * math.pi) - math.pi, sample)
        held = torch.where(tick, sample, entry(state, "held"))
        imu_mean = held[..., _IMU] if imu_sum is None else (imu_sum + held[..., _IMU]) / self.imu_samples_per_step
        return unpack_channels(held), unchecked(state.batch_size, dict(bias=bias, held=held, imu_mean=imu_mean))
