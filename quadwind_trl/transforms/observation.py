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
from ..estimator.features import FeatureExtractor
from ..keys import MEAS_KEY, OBSERVATION_DIM, OBSERVATION_KEY, WIND_KEY, observation_index


def to_heading_frame(east: torch.Tensor, north: torch.Tensor, yaw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World (east, north) components -> (forward, left) in the frame of heading ``yaw`` (rad from
    east, counter-clockwise)."""
    c, s = torch.cos(yaw), torch.sin(yaw)
    return c * east + s * north, -s * east + c * north


class PolicyObservation(Transform):
    """Concatenates the 23 policy inputs into ``out_key`` (default ``"observation"``).

    Reads ``meas``, ``ref_pos``, ``ref_yaw``, ``pos_error``, ``pd_wrench``, ``ff_wrench`` and
    ``wind_key`` (``"wind_hat"``, written by :class:`~quadwind_trl.transforms.wind.WindEstimate`);
    leaves them in place. Stateless.
    """

    def __init__(self, config: EnvConfig | None = None, *, wind_key: str = WIND_KEY, out_key: str = OBSERVATION_KEY):
        cfg = config or EnvConfig()
        in_keys = [MEAS_KEY, "ref_pos", "ref_yaw", "pos_error", "pd_wrench", "ff_wrench", wind_key]
        super().__init__(in_keys=in_keys, out_keys=[out_key])
        self.wind_key, self.out_key = wind_key, out_key
        # the kinematic block through the feature code itself (a stateless vertical-schema step;
        # its 13 first channels are the shared kinematic channels)
        self._kin = FeatureExtractor("vertical", mass_kg=cfg.vehicle.mass_kg, log_dt_s=cfg.timing.log_dt_s)
        self.weight_n = cfg.vehicle.mass_kg * GRAVITY_M_S2
        self.register_buffer("action_scale", torch.tensor(cfg.residual.action_scale, dtype=torch.float32), persistent=False)

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        record = {k: next_tensordict.get(k) for k in self._kin.raw_keys}
        ref_yaw = record["ref_yaw"]
        _, feats = self._kin.step(self._kin.init_state(ref_yaw.shape[0], ref_yaw.device), record)
        ff = next_tensordict.get("ff_wrench") / self.action_scale.to(ref_yaw.device)
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
        next_tensordict.set(self.out_key, obs)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict_reset)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self._call(tensordict)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[self.out_key] = Unbounded(
            shape=(*observation_spec.shape, OBSERVATION_DIM), device=observation_spec.device
        )
        return observation_spec


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
