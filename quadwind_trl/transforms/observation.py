"""The paper's 23-dimensional policy observation (Section "Observation"), built from the sensors
(:class:`PolicyObservation`), and the transform that removes named inputs from it
(:class:`ZeroInputs`).

=======  ======================  ================================================================
index    name                    source
=======  ======================  ================================================================
0        alt                     barometric altitude (m)
1-3      vel_fwd, vel_left,      GPS velocity (m/s); horizontal part in the heading frame
         vel_U
4-6      acc_bx, acc_by, acc_bz  body kinematic acceleration from the accelerometer and the
                                 measured attitude, ``f_b - R^T (0, 0, g)`` (m/s^2)
7-9      roll, pitch, yaw_err    measured attitude (rad); yaw relative to the reference heading,
                                 wrapped to [-pi, pi) (the estimator features' choice,
                                 docs/features.md)
10-12    rate_p, rate_q, rate_r  gyro body rates (rad/s)
13-14    wind_fwd, wind_left     ``wind_hat`` (m/s, estimated north/east) in the heading frame: the
                                 estimate, the oracle, or zero
15-17    err_fwd, err_left,      the env's ``pos_error`` (horizontal part in the heading frame): the
         err_U                   autopilot's navigation solution minus
                                 the reference (m); with the default
                                 ``ControllerConfig.feedback="estimate"`` a filter over GPS,
                                 barometer and accelerometer (the error the PD itself flies on)
18       pd_thrust_over_weight   the PD collective thrust this step's residual is added to / (m g)
19-22    ff_T, ff_x, ff_y, ff_z  the previously applied feedforward correction divided by the
                                 action scale (10 N, 5, 5, 5 N m): dimensionless, in [-1, 1]
=======  ======================  ================================================================

With the residual on the acceleration (``ResidualConfig.acts_on="acceleration"``) the last block
is three channels, ``ff_acc_fwd, ff_acc_left, ff_acc_U``: the applied correction to the desired
acceleration divided by its scale (3, 3, 1.5 m/s^2), in the reference heading's frame in which it
is applied (22 channels; :func:`~quadwind_trl.keys.observation_channels`).

Channels 0-12 are computed by the estimator feature extractor's own code (the first 13 channels of
:class:`~quadwind_trl.estimator.features.FeatureExtractor`, evaluated at every control step), so the
policy and the estimator see identical definitions. Everything comes from the sensors, the
reference and the controller's own outputs: no simulator truth enters the observation (except
``wind_hat`` under the oracle ``source="truth"``, and ``pos_error`` if the env's controller is
configured to fly on the truth, ``ControllerConfig.feedback="truth"``). Velocities are the raw GPS
ones, as in the estimator features.

**The heading frame.** The paper lists the wind estimate as (north, east) and the position error
without a frame. The policy acts through body torques, and our vehicles fly nose-first along the
path, so the body turns continuously: in world axes the same error needs opposite torques on
opposite legs, and the heading itself is not among the inputs (the third Euler channel is the yaw
*relative to the reference heading*, as in the estimator features). So the three horizontal
vectors (velocity, wind estimate, position error) enter rotated by the measured yaw into
(forward, left): the same information, still 23 channels, with the wind in two fixed channels for
the ablation (:class:`ZeroInputs`). Our first PPO run, with world-frame inputs, learned a policy
worse than PD.
"""
from __future__ import annotations

from typing import Sequence

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from ..config import GRAVITY_M_S2, EnvConfig
from ..envs.controller import make_base_controller
from ..estimator.features import FeatureExtractor
from ..keys import (BASE_STATE_GROUPS, BASE_STATE_KEY, MEAS_KEY, OBSERVATION_KEY, PREVIEW_CHANNELS, PRIVILEGED_CHANNELS,
                    PRIVILEGED_KEY, REFERENCE_AHEAD_S, RESIDUAL_ENTRY, WIND_KEY, observation_channels, observation_index)

#: the env entry :class:`ReferenceAhead` writes
REFERENCE_AHEAD_KEY = "ref_ahead"

#: base-state group -> the entries of the base law's state (``env.base``) it is computed from (any of them)
BASE_STATE_SOURCES: dict[str, tuple[str, ...]] = {
    "force": ("force_hat",),  # disturbance observer, L1
    "thrust": ("thrust_hat",),  # disturbance observer, L1
    "integral": ("integral",),  # integral action (PID)
    "vel_err": ("vel_hat",),  # L1
    "ff": ("integral", "force_hat"),  # -Ki I - F_hat / m: integral action and / or a force estimate
}


def to_heading_frame(east: torch.Tensor, north: torch.Tensor, yaw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World (east, north) components -> (forward, left) in the frame of heading ``yaw`` (rad from
    east, counter-clockwise)."""
    c, s = torch.cos(yaw), torch.sin(yaw)
    return c * east + s * north, -s * east + c * north


def base_state_channels(config: EnvConfig) -> tuple[str, ...]:
    """The :data:`~quadwind_trl.keys.BASE_STATE_CHANNELS` the base controller of ``config`` has
    (none for the paper's stateless PD or the wind feed-forward law), in catalogue order."""
    c = config.controller
    state = make_base_controller(c, config.vehicle, config.timing.control_dt_s).init_state(1, torch.device("cpu"))
    entries = set(state.keys()) if state is not None else set()
    return tuple(ch for group, chans in BASE_STATE_GROUPS.items() if entries & set(BASE_STATE_SOURCES[group])
                 for ch in chans)


def _heading_vector(vec: torch.Tensor, yaw: torch.Tensor) -> dict[str, torch.Tensor]:
    """World ENU ``[N, 3]`` -> {fwd, left, U} ``[N, 1]`` each (heading frame of ``yaw`` ``[N, 1]``)."""
    fwd, left = to_heading_frame(vec[..., 0:1], vec[..., 1:2], yaw)
    return {"fwd": fwd, "left": left, "U": vec[..., 2:3]}


class _StatelessEntry(Transform):
    """A transform that writes ``out_key`` (``out_shape`` per row) from the entries of the same
    step alone: a reset computes it as a step does, and so does a direct call."""

    out_key: str
    out_shape: tuple[int, ...]

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[self.out_key] = Unbounded(shape=(*observation_spec.shape, *self.out_shape),
                                                   device=observation_spec.device)
        return observation_spec


class PolicyObservation(_StatelessEntry):
    """Concatenates the 23 policy inputs (22 with the residual on the acceleration) into
    ``out_key`` (default ``"observation"``), and after them the base controller's state channels
    ``base_channels`` (names of :data:`~quadwind_trl.keys.BASE_STATE_CHANNELS`, read from the
    env's ``base`` entry; default none: the paper's 23), then the ``preview_channels`` (names of
    :data:`~quadwind_trl.keys.PREVIEW_CHANNELS`, read from ``ref_ahead``, which
    :class:`ReferenceAhead` writes; default none).

    Reads ``meas``, ``ref_pos``, ``ref_yaw``, ``pos_error``, ``pd_wrench``, the applied residual
    (``ff_wrench``, or ``ff_acc`` on the acceleration: ``keys.RESIDUAL_ENTRY``) and ``wind_key``
    (``"wind_hat"``, written by :class:`~quadwind_trl.transforms.wind.WindEstimate`); leaves them
    in place. Stateless.
    """

    def __init__(self, config: EnvConfig | None = None, *, wind_key: str = WIND_KEY, out_key: str = OBSERVATION_KEY,
                 base_channels: Sequence[str] = (), preview_channels: Sequence[str] = ()):
        cfg = config or EnvConfig()
        self.ff_key = RESIDUAL_ENTRY[cfg.residual.acts_on]
        self.dim = len(observation_channels(cfg.residual.acts_on))
        in_keys = [MEAS_KEY, "ref_pos", "ref_yaw", "pos_error", "pd_wrench", self.ff_key, wind_key]
        self.base_channels = tuple(base_channels)
        if self.base_channels:
            have = base_state_channels(cfg)
            wrong = [c for c in self.base_channels if c not in have]
            if wrong:
                raise ValueError(f"PolicyObservation(base_channels={self.base_channels!r}): {wrong} are not channels of "
                                 f"this base controller; allowed: {have}")
            in_keys.append("nav_vel")
        self.preview_channels = tuple(preview_channels)
        wrong = [c for c in self.preview_channels if c not in PREVIEW_CHANNELS]
        if wrong:
            raise ValueError(f"PolicyObservation(preview_channels={self.preview_channels!r}): {wrong} unknown; allowed: "
                             f"{PREVIEW_CHANNELS}")
        if self.preview_channels:
            in_keys.append(REFERENCE_AHEAD_KEY)
        super().__init__(in_keys=in_keys, out_keys=[out_key])
        self.wind_key, self.out_key = wind_key, out_key
        self.out_shape = (self.dim + len(self.base_channels) + len(self.preview_channels),)
        self.mass_kg = cfg.vehicle.mass_kg
        self.register_buffer("ki", torch.tensor(cfg.controller.ki_pos, dtype=torch.float32), persistent=False)
        # the kinematic block through the feature code itself (a stateless vertical-schema step;
        # its 13 first channels are the shared kinematic channels)
        self._kin = FeatureExtractor("vertical", mass_kg=cfg.vehicle.mass_kg, log_dt_s=cfg.timing.log_dt_s)
        self.weight_n = cfg.vehicle.mass_kg * GRAVITY_M_S2
        # the applied residual in units of its action scale: the action's own units
        self.register_buffer("action_scale", torch.tensor(cfg.residual.scale, dtype=torch.float32), persistent=False)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        record = {k: next_tensordict.get(k) for k in self._kin.raw_keys}
        ref_yaw = record["ref_yaw"]
        _, feats = self._kin.step(self._kin.init_state(ref_yaw.shape[0], ref_yaw.device), record)
        ff = next_tensordict.get(self.ff_key) / self.action_scale.to(ref_yaw.device)
        _, _, yaw = next_tensordict.get((MEAS_KEY, "attitude")).unbind(-1)  # (roll, pitch, yaw): the measured yaw
        vel_f, vel_l = to_heading_frame(feats[..., 1], feats[..., 2], yaw)
        wind = next_tensordict.get(self.wind_key)  # (north, east)
        wind_f, wind_l = to_heading_frame(wind[..., 1], wind[..., 0], yaw)
        err = next_tensordict.get("pos_error")  # ENU
        err_f, err_l = to_heading_frame(err[..., 0], err[..., 1], yaw)
        obs = torch.cat(
            (
                feats[..., :1],
                torch.stack((vel_f, vel_l), -1),
                feats[..., 3:13],
                torch.stack((wind_f, wind_l), -1),
                torch.stack((err_f, err_l), -1),
                err[..., 2:],
                next_tensordict.get("pd_wrench")[..., :1] / self.weight_n,
                ff,
            ),
            -1,
        )
        if self.base_channels:  # a constructor constant: without them the observation is the paper's, bit for bit
            obs = torch.cat((obs, self._base_state(next_tensordict, yaw.unsqueeze(-1))), -1)
        if self.preview_channels:  # likewise
            obs = torch.cat((obs, self._preview(next_tensordict, yaw.unsqueeze(-1))), -1)
        next_tensordict.set(self.out_key, obs)
        return next_tensordict

    def _base_state(self, td: TensorDictBase, yaw: torch.Tensor) -> torch.Tensor:
        """The ``base_channels`` of the base law's state after this step, ``[N, B]``."""
        state = td.get(BASE_STATE_KEY)
        parts: dict[str, torch.Tensor] = {}
        force = state.get("force_hat", None)
        integral = state.get("integral", None)
        if force is not None:
            parts.update({f"base_force_{k}": v for k, v in _heading_vector(force, yaw).items()})
            parts["base_thrust_over_weight"] = state.get("thrust_hat") / (self.mass_kg * GRAVITY_M_S2)
        if integral is not None:
            parts.update({f"base_int_{k}": v for k, v in _heading_vector(integral, yaw).items()})
        vel_hat = state.get("vel_hat", None)
        if vel_hat is not None:
            parts.update({f"base_vel_err_{k}": v for k, v in _heading_vector(vel_hat - td.get("nav_vel"), yaw).items()})
        # what the base's additions put into the outer loop's desired acceleration
        # (envs.controller.CascadeController); a residual on the acceleration is not among them: its
        # own channels show it
        ff = None if integral is None else -self.ki.to(yaw.device) * integral
        if force is not None:
            ff = -force / self.mass_kg if ff is None else ff - force / self.mass_kg
        if ff is not None:
            parts.update({f"base_ff_{k}": v for k, v in _heading_vector(ff, yaw).items()})
        return torch.cat([parts[c] for c in self.base_channels], -1)

    def _preview(self, td: TensorDictBase, yaw: torch.Tensor) -> torch.Tensor:
        """The ``preview_channels`` of the reference ahead, ``[N, P]``."""
        ahead = td.get(REFERENCE_AHEAD_KEY)  # [N, K, 3] ENU
        parts: dict[str, torch.Tensor] = {}
        for k, horizon in enumerate(REFERENCE_AHEAD_S):
            parts.update({f"ahead_{horizon:g}s_{c}": v for c, v in _heading_vector(ahead[:, k], yaw).items()})
        return torch.cat([parts[c] for c in self.preview_channels], -1)


class ReferenceAhead(_StatelessEntry):
    """Where the reference will be :data:`~quadwind_trl.keys.REFERENCE_AHEAD_S` seconds from now,
    from the vehicle's navigation position: ``ref_ahead`` ``[N, K, 3]`` (ENU, m), the input of a
    policy that plans (``PolicyObservation(preview_channels=...)`` reads it in the heading frame).

    Reads ``step`` and ``nav_pos`` and asks the env it transforms for the trajectory ahead
    (:meth:`~quadwind_trl.envs.quad_env.QuadWindEnv.reference_at`): the planned path is known to the
    vehicle, as the reference now is, so no simulator truth enters. Stateless.
    """

    def __init__(self, control_dt_s: float, *, out_key: str = REFERENCE_AHEAD_KEY):
        if not control_dt_s > 0:
            raise ValueError(f"ReferenceAhead(control_dt_s={control_dt_s!r}); allowed: > 0 s")
        super().__init__(in_keys=["step", "nav_pos"], out_keys=[out_key])
        self.out_key, self.out_shape = out_key, (len(REFERENCE_AHEAD_S), 3)
        self.steps_ahead = tuple(round(h / control_dt_s) for h in REFERENCE_AHEAD_S)  # control steps, per horizon

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        td = next_tensordict
        env = self.parent.base_env
        steps = td.get("step")  # [N, 1]
        ahead = torch.stack([env.reference_at((steps + k)[:, 0]).pos for k in self.steps_ahead], -2)
        td.set(self.out_key, ahead - td.get("nav_pos").unsqueeze(-2))
        return td


class PrivilegedObservation(_StatelessEntry):
    """The simulator truth an asymmetric critic reads at training time: ``channels`` (names of
    :data:`~quadwind_trl.keys.PRIVILEGED_CHANNELS`) into ``out_key`` (default ``"privileged"``),
    horizontal parts in the heading frame of the measured yaw, as the observation's.

    Reads the env's ``truth`` entries (``mean_wind``, ``wind``, ``pos``, ``vel``) and the reference
    (``ref_pos``, ``ref_vel``); leaves them in place. Stateless. Only the training env has it: the
    actor never reads ``out_key``, so a policy flies without it.
    """

    def __init__(self, channels: Sequence[str], *, out_key: str = PRIVILEGED_KEY):
        self.channels = tuple(channels)
        unknown = [c for c in self.channels if c not in PRIVILEGED_CHANNELS]
        if unknown or not self.channels:
            raise ValueError(f"PrivilegedObservation(channels={self.channels!r}): unknown {unknown}; allowed: one or "
                             f"more of {PRIVILEGED_CHANNELS}")
        in_keys = [("truth", "mean_wind"), ("truth", "wind"), ("truth", "pos"), ("truth", "vel"), "ref_pos", "ref_vel",
                   (MEAS_KEY, "attitude")]
        super().__init__(in_keys=in_keys, out_keys=[out_key])
        self.out_key, self.out_shape = out_key, (len(self.channels),)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        td = next_tensordict
        yaw = td.get((MEAS_KEY, "attitude"))[..., 2:3]
        mean = td.get(("truth", "mean_wind"))
        vectors = {"mean_wind": mean, "turb": td.get(("truth", "wind")) - mean,
                   "true_err": td.get(("truth", "pos")) - td.get("ref_pos"),
                   "true_vel_err": td.get(("truth", "vel")) - td.get("ref_vel")}
        parts = {}
        for prefix, vec in vectors.items():
            if any(c.startswith(prefix + "_") for c in self.channels):
                parts.update({f"{prefix}_{k}": v for k, v in _heading_vector(vec, yaw).items()})
        td.set(self.out_key, torch.cat([parts[c] for c in self.channels], -1))
        return td


class ZeroInputs(Transform):
    """Forces named policy inputs to exactly zero (the input ablations); specs unchanged.

    ``ZeroInputs(channels)`` zeroes those channels (names of
    :data:`~quadwind_trl.keys.OBSERVATION_CHANNELS`) of ``"observation"``: placed last in the stack
    (after normalisation and clipping) it makes those inputs exactly 0 and leaves every other one
    bit-identical. ``ZeroInputs(keys.WIND_CHANNELS)`` is the perception ablation
    (``wind_input="zero"``); ``RLEnvSpec.zero_inputs`` adds other channels. ``ZeroInputs(None,
    in_key="wind_hat")`` zeroes a whole entry instead (here the raw estimate, before normalisation).
    """

    def __init__(self, channels: Sequence[str] | None, *, in_key: str = OBSERVATION_KEY):
        super().__init__(in_keys=[in_key], out_keys=[in_key])
        if channels is not None and in_key != OBSERVATION_KEY:
            raise ValueError(f"ZeroInputs(channels={channels!r}, in_key={in_key!r}): channel names address "
                             f"{OBSERVATION_KEY!r}; allowed for another entry: channels=None (the whole entry)")
        self.channels = None if channels is None else tuple(channels)
        if self.channels is not None:  # a buffer: moves with the transform, no copy per step
            index = [observation_index(name) for name in self.channels]
            self.register_buffer("_index", torch.tensor(index), persistent=False)

    def _apply_transform(self, x: torch.Tensor) -> torch.Tensor:
        if self.channels is None:
            return torch.zeros_like(x)
        return x.index_fill(-1, self._index.to(x.device), 0.0)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)
