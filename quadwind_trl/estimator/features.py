"""Estimator input features: one incremental, batched, stateful code path for the dataset and the
online transform (docs/architecture.md, "One feature code path").

A :class:`FeatureExtractor` consumes the raw flight record one 10 Hz tick at a time::

    fx = FeatureExtractor("horizontal")            # or "vertical"
    state = fx.init_state(batch=N, device=dev)
    state, f_t = fx.step(state, record_t)          # record_t: {key: [N, ...]} for key in fx.raw_keys
                                                   # (record_t["meas"]: the sensors' named entries)
    state = fx.reset_rows(state, mask)             # restart the rows of a bool [N] mask

``step`` is pure: it never mutates ``state`` or ``record_t`` and returns a new state. The offline
helper :meth:`FeatureExtractor.scan` runs exactly the same ``step`` over the time axis of an
``[n, T]`` record (batched over flights, a Python loop over T only), so dataset features and
online features are the same numbers (``tests/test_features.py`` checks them bit for bit).

The raw record (``RAW_RECORD_KEYS``, all of them observation keys of ``QuadWindEnv``):

=================  ====  ==========================================================================
key                size  content
=================  ====  ==========================================================================
``meas``           -     the sensors' named entries (``quadwind_trl.envs.sensors.INSTRUMENTS``):
                         ``gps_pos`` [3], ``gps_vel`` [3], ``baro_alt`` [1], ``attitude`` [3],
                         ``gyro`` [3], ``accel`` [3]; read here by name
``cmd_wrench``     4     commanded collective thrust ``u_T`` (N), body torques (N m), last step
``tilt_cmd``       1     PD commanded tilt from vertical (rad)
``tilt_saturated`` 1     bool, the PD tilt limit was active
``ref_pos``        3     reference position, world ENU (m)
``ref_yaw``        1     reference heading (rad, continuous/unwrapped, from east, CCW)
=================  ====  ==========================================================================

Channel definitions, units and the choices made where the paper is ambiguous are in
``docs/features.md``; the channel names are ``HORIZONTAL_CHANNELS`` (48) and
``VERTICAL_CHANNELS`` (22).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Literal, Mapping

import torch
from torch import Tensor

from tensordict import TensorDict

from ..config import GRAVITY_M_S2, EnvConfig
from ..envs.sensors import sensor_widths
from ..keys import MEAS_KEY, YawMode, kinematic_channels

Schema = Literal["horizontal", "vertical"]

#: everything any schema reads from the flight record / env observation, in one list
RAW_RECORD_KEYS: tuple[str, ...] = (MEAS_KEY, "cmd_wrench", "tilt_cmd", "tilt_saturated", "ref_pos", "ref_yaw")
RAW_KEYS_BY_SCHEMA: dict[str, tuple[str, ...]] = {
    "horizontal": (MEAS_KEY, "cmd_wrench", "tilt_cmd", "tilt_saturated", "ref_yaw"),
    "vertical": (MEAS_KEY, "ref_pos", "ref_yaw"),
}

LOG_DT_S = 0.1  # the 10 Hz record
TRAILING_WINDOWS: tuple[int, ...] = (100, 300)  # paper, horizontal schema: 10 s and 30 s at 10 Hz
#: each schema's trailing-mean lengths (samples) when none are asked for: the paper's (the vertical
#: model has none)
DEFAULT_TRAILING_WINDOWS: dict[str, tuple[int, ...]] = {"horizontal": TRAILING_WINDOWS, "vertical": ()}
MAX_TRAILING_WINDOW = 3000  # 300 s at 10 Hz: longer than any flight the recipes make


def raw_record_template(*shape: int) -> TensorDict:
    """Zero-storage (expanded) entries of the raw record (:data:`RAW_RECORD_KEYS`) of batch
    ``shape``, the sensors nested under ``MEAS_KEY``: the record's layout, in one place."""

    def zero(width: int, dtype: torch.dtype = torch.float32) -> Tensor:
        return torch.zeros((1,) * (len(shape) + 1), dtype=dtype).expand(*shape, width)

    meas = TensorDict({name: zero(w) for name, w in sensor_widths().items()}, batch_size=shape)
    flat = {"cmd_wrench": zero(4), "tilt_cmd": zero(1), "tilt_saturated": zero(1, torch.bool), "ref_pos": zero(3),
            "ref_yaw": zero(1)}
    return TensorDict({MEAS_KEY: meas, **flat}, batch_size=shape)


#: the 11 signals whose causal trailing means are taken (paper: horizontal velocities and
#: accelerations, the four aero components, roll and pitch, commanded thrust)
TRAILING_SIGNALS: tuple[str, ...] = (
    "vel_N", "vel_E", "acc_N", "acc_E", "aero_N", "aero_E", "aero_U", "aero_horiz", "roll", "pitch", "u_T",
)  # fmt: skip
#: the vertical schema's trailing signals (not in the paper, whose vertical model has none; issue
#: 27's experiments). Its record carries no commanded thrust, so no aerodynamic force; and the
#: vertical patterns turn, so body-frame angles and accelerations average out. What a steady wind
#: leaves in a long mean, world frame (N, E): the ground velocity, the thrust axis's tilt (which
#: leans into the wind), the accelerometer's rotor-plane specific force (drag over mass: thrust
#: has no component there) and the horizontal position error (a steady wind offsets it)
VERTICAL_TRAILING_SIGNALS: tuple[str, ...] = ("vel_N", "vel_E", "tilt_N", "tilt_E", "sfp_N", "sfp_E", "dX", "dY")
TRAILING_SIGNALS_BY_SCHEMA: dict[str, tuple[str, ...]] = {"horizontal": TRAILING_SIGNALS, "vertical": VERTICAL_TRAILING_SIGNALS}


def horizontal_channels(yaw_mode: YawMode = "ref_relative") -> tuple[str, ...]:
    return (
        kinematic_channels(yaw_mode)
        + ("u_T", "tau_x", "tau_y", "tau_z")  # 17: sensor17
        + ("sf_bx", "sf_by", "sf_bz")  # 20: raw accelerometer
        + ("aero_N", "aero_E", "aero_U", "aero_horiz", "tilt_cmd", "tilt_sat")  # 26
        + trailing_channels(TRAILING_WINDOWS)  # 48
    )


def trailing_channels(windows: tuple[int, ...], signals: tuple[str, ...] = TRAILING_SIGNALS) -> tuple[str, ...]:
    """The trailing-mean channel names, ``avg<w>_<signal>``, window by window."""
    return tuple(f"avg{w}_{s}" for w in windows for s in signals)


def trailing_windows_of(channels: tuple[str, ...]) -> tuple[int, ...]:
    """The trailing windows (samples) named by a channel list's ``avg<w>_`` channels, in order
    (empty if none): what a checkpoint's channel names say its features were."""
    found = []
    for name in channels:
        m = re.fullmatch(r"avg(\d+)_(.+)", name)
        if m and int(m.group(1)) not in found:
            found.append(int(m.group(1)))
    return tuple(found)


def vertical_channels(yaw_mode: YawMode = "ref_relative") -> tuple[str, ...]:
    return kinematic_channels(yaw_mode) + (
        "dX", "dY", "dZ",
        "vx_ref", "vy_ref", "vz_ref",
        "ax_ref", "ay_ref", "az_ref",
    )  # fmt: skip


HORIZONTAL_CHANNELS = horizontal_channels()
VERTICAL_CHANNELS = vertical_channels()
assert len(HORIZONTAL_CHANNELS) == 48 and len(set(HORIZONTAL_CHANNELS)) == 48
assert len(VERTICAL_CHANNELS) == 22 and len(set(VERTICAL_CHANNELS)) == 22


def wrap_angle(x: Tensor) -> Tensor:
    """Wrap to ``[-pi, pi)`` by ``remainder`` (elementwise exact arithmetic: unlike ``atan2``, its
    result does not depend on the batch layout, which keeps online and offline bit-identical)."""
    return torch.remainder(x + math.pi, 2.0 * math.pi) - math.pi


def rotation_from_euler(roll: Tensor, pitch: Tensor, yaw: Tensor) -> tuple[tuple[Tensor, Tensor, Tensor], ...]:
    """Z-Y-X body-to-world rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)`` as nested rows of ``[N]``
    tensors (elementwise arithmetic only: no matmul, so no batch-size-dependent reductions)."""
    sr, cr = torch.sin(roll), torch.cos(roll)
    sp, cp = torch.sin(pitch), torch.cos(pitch)
    sy, cy = torch.sin(yaw), torch.cos(yaw)
    return (
        (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
        (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
        (-sp, cp * sr, cp * cr),
    )


def _apply(r, v: tuple[Tensor, Tensor, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
    return tuple(row[0] * v[0] + row[1] * v[1] + row[2] * v[2] for row in r)  # type: ignore[return-value]


@dataclass(frozen=True)
class FeatureExtractor:
    """Incremental feature extractor for one schema (``"horizontal"``, 48 channels, or
    ``"vertical"``, 22 channels).

    ``mass_kg`` converts the specific-force residual to the aerodynamic force (N); ``yaw_mode``
    picks the third Euler channel: ``"ref_relative"`` (default, ``yaw_err`` = measured yaw minus
    the reference heading, wrapped) or ``"wrapped"`` (the paper-literal raw yaw in ``[-pi, pi)``);
    see docs/features.md for why the default is not the raw yaw.
    """

    schema: Schema = "horizontal"
    mass_kg: float = 2.59
    gravity_m_s2: float = GRAVITY_M_S2
    log_dt_s: float = LOG_DT_S
    windows: tuple[int, ...] | None = None  # trailing-mean lengths, samples (None: DEFAULT_TRAILING_WINDOWS)
    yaw_mode: YawMode = "ref_relative"

    def __post_init__(self):
        if self.schema not in ("horizontal", "vertical"):
            raise ValueError(f"FeatureExtractor.schema={self.schema!r}; allowed: 'horizontal', 'vertical'")
        if self.yaw_mode not in ("ref_relative", "wrapped"):
            raise ValueError(f"FeatureExtractor.yaw_mode={self.yaw_mode!r}; allowed: 'ref_relative', 'wrapped'")
        w = DEFAULT_TRAILING_WINDOWS[self.schema] if self.windows is None else tuple(self.windows)
        if any(not isinstance(k, int) for k in w) or list(w) != sorted(set(w)) or not all(0 < k <= MAX_TRAILING_WINDOW for k in w):
            raise ValueError(
                f"FeatureExtractor.windows={self.windows!r}: distinct, increasing integer sample counts "
                f"in [1, {MAX_TRAILING_WINDOW}] allowed (none: no trailing means)"
            )
        object.__setattr__(self, "windows", w)

    @classmethod
    def from_config(cls, schema: Schema, config: EnvConfig | None = None, **kwargs) -> "FeatureExtractor":
        cfg = config or EnvConfig()
        return cls(schema=schema, mass_kg=cfg.vehicle.mass_kg, log_dt_s=cfg.timing.log_dt_s, **kwargs)

    # --- schema ---------------------------------------------------------------------------------

    @property
    def trailing_signals(self) -> tuple[str, ...]:
        return TRAILING_SIGNALS_BY_SCHEMA[self.schema]

    @property
    def channels(self) -> tuple[str, ...]:
        if self.schema == "horizontal":
            names = kinematic_channels(self.yaw_mode) + horizontal_channels(self.yaw_mode)[13:26]
        else:
            names = vertical_channels(self.yaw_mode)
        return names + trailing_channels(self.windows, self.trailing_signals)

    @property
    def num_channels(self) -> int:
        return len(self.channels)

    @property
    def raw_keys(self) -> tuple[str, ...]:
        return RAW_KEYS_BY_SCHEMA[self.schema]

    # --- state ----------------------------------------------------------------------------------

    def init_state(self, batch: int, device: torch.device | str | None = None) -> dict:
        """The state before a flight's first sample, for ``batch`` rows."""
        state = {"count": torch.zeros(batch, dtype=torch.int64, device=device)}
        if self.schema == "vertical":
            z3 = torch.zeros(batch, 3, device=device)
            state.update(prev_ref_pos=z3, prev_ref_vel=z3)
        if self.windows:
            k = len(self.trailing_signals)
            zero = torch.zeros(batch, k, device=device)
            # one row of sums per window; history[-j] is the trailing-signal sample j ticks before
            # the current one, a tuple of tensors (shifted by reference, never copied or mutated)
            # that keeps ``step`` pure and O(1)
            state["sums"] = torch.zeros(batch, len(self.windows), k, dtype=torch.float64, device=device)
            state["history"] = (zero,) * self.windows[-1]
        return state

    def reset_rows(self, state: dict, mask: Tensor) -> dict:
        """Restart the rows of bool ``mask`` ``[N]`` (their next sample is a flight's first)."""
        mask = mask.reshape(-1)
        out = dict(state)
        out["count"] = torch.where(mask, 0, state["count"])
        for key in ("sums", "prev_ref_pos", "prev_ref_vel"):
            if key in state:
                m = mask.reshape(-1, *(1,) * (state[key].dim() - 1))
                out[key] = torch.where(m, torch.zeros_like(state[key]), state[key])
        # history rows need no reset: samples from before the restart are masked by ``count``
        return out

    # --- one tick -------------------------------------------------------------------------------

    def step(self, state: dict, record: Mapping[str, Tensor | TensorDict]) -> tuple[dict, Tensor]:
        """Consume one 10 Hz sample per row; returns ``(new_state, features [N, C] float32)``."""
        # the features boundary: the named sensor entries become the packed feature channels
        meas = record[MEAS_KEY]
        g = self.gravity_m_s2
        roll, pitch, yaw = meas["attitude"].to(torch.float32).unbind(-1)
        r = rotation_from_euler(roll, pitch, yaw)
        sf_b = meas["accel"].to(torch.float32).unbind(-1)
        # kinematic body acceleration a_b = f_b + R^T (0, 0, -g); R^T e_z is R's third row
        acc_b = tuple(f - g * r[2][i] for i, f in enumerate(sf_b))
        if self.yaw_mode == "ref_relative":
            yaw_ch = wrap_angle(yaw - record["ref_yaw"][..., 0].to(torch.float32))
        else:
            yaw_ch = wrap_angle(yaw)
        kin = [
            meas["baro_alt"][..., 0].to(torch.float32),
            *meas["gps_vel"].to(torch.float32).unbind(-1),
            *acc_b,
            roll, pitch, yaw_ch,
            *meas["gyro"].to(torch.float32).unbind(-1),
        ]  # fmt: skip
        step = self._vertical if self.schema == "vertical" else self._horizontal
        new, inst, x = step(state, record, meas, kin, r, sf_b)
        new["count"] = state["count"] + 1
        if not self.windows:
            return new, inst
        avgs, trailing = self._trailing(state, x, new["count"])
        return {**new, **trailing}, torch.cat((inst, avgs), -1)

    def _trailing(self, state: dict, x: Tensor, count: Tensor) -> tuple[Tensor, dict]:
        """The trailing means of this tick's signals ``x`` ``[N, k]`` (in the schema's
        ``trailing_signals`` order), window by window, and their new running state."""
        hist = state["history"]
        prev = state["count"].unsqueeze(-1)
        # the sample leaving each window, once the flight is longer than the window
        leaving = torch.stack([torch.where(prev >= w, hist[-w].to(torch.float64), 0.0) for w in self.windows], -2)
        sums = state["sums"] + x.to(torch.float64).unsqueeze(-2) - leaving  # [N, windows, signals]
        c = count.unsqueeze(-1).to(torch.float64)
        avgs = torch.cat([(sums[..., i, :] / c.clamp_max(w)).to(torch.float32) for i, w in enumerate(self.windows)], -1)
        return avgs, {"sums": sums, "history": hist[1:] + (x,)}

    def _horizontal(self, state, record, meas, kin, r, sf_b) -> tuple[dict, Tensor, Tensor]:
        """``(state entries, instantaneous channels, trailing signals)`` of one tick."""
        cmd = record["cmd_wrench"].to(torch.float32)
        u_t = cmd[..., 0]
        m = self.mass_kg
        f_w = _apply(r, sf_b)  # realised specific force, world ENU
        b3 = (r[0][2], r[1][2], r[2][2])  # measured body z axis in world
        aero_e, aero_n, aero_u = (m * f - u_t * b for f, b in zip(f_w, b3))  # N
        aero_h = torch.sqrt(aero_n * aero_n + aero_e * aero_e)
        acc_e, acc_n = f_w[0], f_w[1]  # world kinematic horizontal acceleration (gravity is vertical)
        tilt = record["tilt_cmd"][..., 0].to(torch.float32)
        sat = record["tilt_saturated"][..., 0].to(torch.float32)

        x = torch.stack(
            (kin[2], kin[1], acc_n, acc_e, aero_n, aero_e, aero_u, aero_h, kin[7], kin[8], u_t), -1
        )  # TRAILING_SIGNALS order
        inst = torch.stack(
            kin + [cmd[..., 0], cmd[..., 1], cmd[..., 2], cmd[..., 3], *sf_b, aero_n, aero_e, aero_u, aero_h, tilt, sat], -1
        )
        return {}, inst, x

    def _vertical(self, state, record, meas, kin, r, sf_b) -> tuple[dict, Tensor, Tensor | None]:
        """``(state entries, instantaneous channels, trailing signals or None without trailing
        means)`` of one tick."""
        ref = record["ref_pos"].to(torch.float32)
        # the horizontal GPS position and the barometric altitude (the vehicle's altitude source)
        measured = torch.cat((meas["gps_pos"][..., :2], meas["baro_alt"]), -1).to(torch.float32)
        d = measured - ref
        started = (state["count"] > 0).unsqueeze(-1)
        # causal backward differences of the reference position on the 10 Hz grid; zero at a
        # flight's first sample (flights start at rest)
        v_ref = torch.where(started, (ref - state["prev_ref_pos"]) / self.log_dt_s, 0.0)
        a_ref = torch.where(started, (v_ref - state["prev_ref_vel"]) / self.log_dt_s, 0.0)
        inst = torch.cat((torch.stack(kin, -1), d, v_ref, a_ref), -1)
        x = None
        if self.windows:
            # the rotor-plane part of the specific force, in the world frame: R (f_bx, f_by, 0)
            sfp_e, sfp_n = (r[i][0] * sf_b[0] + r[i][1] * sf_b[1] for i in (0, 1))
            # VERTICAL_TRAILING_SIGNALS order; r[i][2] is the body z axis's world component i (E, N)
            x = torch.stack((kin[2], kin[1], r[1][2], r[0][2], sfp_n, sfp_e, d[..., 0], d[..., 1]), -1)
        return {"prev_ref_pos": ref, "prev_ref_vel": v_ref}, inst, x

    # --- offline --------------------------------------------------------------------------------

    def scan(self, record: Mapping[str, Tensor | TensorDict], out: Tensor | None = None, progress: bool = False) -> Tensor:
        """Features ``[n, T, C]`` of ``n`` flights' records ``{key: [n, T, ...]}`` (each row starts
        at its flight's first sample): :meth:`step` over the time axis, batched over flights.

        ``out`` (e.g. a slice of a memory-mapped tensor) receives the result if given.
        """
        ref_yaw = record["ref_yaw"]  # a plain tensor every schema reads: the batch shape and device
        n, t_len = ref_yaw.shape[:2]
        device = ref_yaw.device
        # time-major contiguous copies: each tick's input is laid out exactly as online
        series = {k: record[k].transpose(0, 1).contiguous() for k in self.raw_keys}
        if out is None:
            out = torch.empty(n, t_len, self.num_channels, dtype=torch.float32, device=device)
        state = self.init_state(n, device)
        ticks = range(t_len)
        if progress:
            from tqdm.auto import tqdm

            ticks = tqdm(ticks, desc=f"{self.schema} features", unit="tick")
        for t in ticks:
            state, f = self.step(state, {k: v[t] for k, v in series.items()})
            out[:, t] = f
        return out


def make_extractor(
    schema: Schema, config: EnvConfig | None = None, channels: tuple[str, ...] | None = None, **kwargs
) -> FeatureExtractor:
    """The extractor for ``schema`` with the vehicle mass and log rate of ``config``.

    ``channels`` (an estimator's, e.g. a checkpoint's): the extractor that makes exactly those
    channels, its trailing windows read from their names; a list no extractor makes is refused."""
    if channels is not None:
        kwargs.setdefault("windows", trailing_windows_of(tuple(channels)))
    fx = FeatureExtractor.from_config(schema, config, **kwargs)
    if channels is not None and tuple(channels) != fx.channels:
        missing = [c for c in fx.channels if c not in channels]
        extra = [c for c in channels if c not in fx.channels]
        raise ValueError(
            f"estimator channels ({len(channels)}) are not the {schema!r} feature extractor's ({fx.num_channels}; "
            f"missing {missing[:5]}, unexpected {extra[:5]}): retrain or pick the matching schema"
        )
    return fx
