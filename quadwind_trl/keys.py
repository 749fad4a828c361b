"""Tensordict keys and the policy observation layout, in one place.

The sensors' measurements are the env observation :data:`MEAS_KEY`, a sub-tensordict of named
entries, one per instrument of :data:`quadwind_trl.envs.sensors.INSTRUMENTS` (``("meas",
"attitude")``, ...). The policy's ``observation`` is a flat vector whose channels are named by
:data:`OBSERVATION_CHANNELS`; code that needs a channel looks its index up by name
(:func:`observation_index`), never by a number, so the layout can change in this file only.
The kinematic block (:func:`kinematic_channels`) is shared with the estimator features, which
import it from here. A leaf module: it imports nothing from the package, so every layer can use it.
"""
from __future__ import annotations

from typing import Literal

#: the held sensor measurements: a sub-tensordict with one entry per sensor instrument
MEAS_KEY = "meas"
#: (north, east) mean-wind estimate, m/s, written by ``WindEstimate``
WIND_KEY = "wind_hat"
#: the policy input vector written by ``PolicyObservation``
OBSERVATION_KEY = "observation"
#: the true turbulence-free mean wind at the vehicle (ENU), the oracle's source
MEAN_WIND_KEY = ("truth", "mean_wind")
#: bool [1]: the runtime monitor held the residual at zero over the last control step (an env
#: observation entry only while ``ResidualConfig.monitor`` is on)
MONITOR_KEY = "monitor_active"

YawMode = Literal["ref_relative", "wrapped"]


def kinematic_channels(yaw_mode: YawMode = "ref_relative") -> tuple[str, ...]:
    """The 13 controller-agnostic kinematic channels of sensor17 (the estimator features' first
    block, shared by both schemas, and the policy observation's)."""
    yaw = "yaw_err" if yaw_mode == "ref_relative" else "yaw"
    return (
        "alt",
        "vel_E", "vel_N", "vel_U",
        "acc_bx", "acc_by", "acc_bz",
        "roll", "pitch", yaw,
        "rate_p", "rate_q", "rate_r",
    )  # fmt: skip


#: the policy observation, channel by channel (heading frame: forward, left; see transforms.observation)
OBSERVATION_CHANNELS: tuple[str, ...] = ("alt", "vel_fwd", "vel_left") + kinematic_channels("ref_relative")[3:] + (
    "wind_fwd", "wind_left",
    "err_fwd", "err_left", "err_U",
    "pd_thrust_over_weight",
    "ff_T", "ff_x", "ff_y", "ff_z",
)  # fmt: skip
OBSERVATION_DIM = len(OBSERVATION_CHANNELS)


def observation_index(name: str) -> int:
    """Index of channel ``name`` in the policy observation."""
    if name not in OBSERVATION_CHANNELS:
        raise ValueError(f"observation channel {name!r} unknown; channels: {OBSERVATION_CHANNELS}")
    return OBSERVATION_CHANNELS.index(name)


#: the two wind channels of the observation (what ``WindZero`` zeroes)
WIND_INDICES: tuple[int, int] = (observation_index("wind_fwd"), observation_index("wind_left"))
