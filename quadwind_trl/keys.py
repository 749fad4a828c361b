"""Tensordict keys and the policy observation layout, in one place.

The sensors' measurements are the env observation :data:`MEAS_KEY`, a sub-tensordict of named
entries, one per instrument of :data:`quadwind_trl.envs.sensors.INSTRUMENTS` (``("meas",
"attitude")``, ...). The policy's ``observation`` is a flat vector whose channels are named by
:data:`OBSERVATION_CHANNELS` (:func:`observation_channels` for a residual on the acceleration,
whose own-correction channels are three); code that needs a channel looks its index up by name
(:func:`observation_index`), never by a number, so the layout can change in this file only.
The kinematic block (:func:`kinematic_channels`) is shared with the estimator features, which
import it from here. :data:`INPUT_GROUPS` names the groups of channels a policy can be trained
without (:func:`input_channels` expands them). A leaf module: it imports nothing from the
package, so every layer can use it.
"""
from __future__ import annotations

from typing import Literal, Sequence

#: the held sensor measurements: a sub-tensordict with one entry per sensor instrument
MEAS_KEY = "meas"
#: (north, east) mean-wind estimate, m/s, written by ``WindEstimate``
WIND_KEY = "wind_hat"
#: the policy input vector written by ``PolicyObservation``
OBSERVATION_KEY = "observation"
#: the true turbulence-free mean wind at the vehicle (ENU), the oracle's source
MEAN_WIND_KEY = ("truth", "mean_wind")
#: (north, east) wind estimate, m/s, that a wind feed-forward base controller flies on: an input
#: of the env's step (its ``state_spec``), written by ``transforms.BaseWindInput``
BASE_WIND_KEY = "base_wind_ne"
#: the base controller's state, a sub-tensordict of the env's observation (only for a base law with
#: state: ``envs.controller.CascadeController.init_state`` names its entries)
BASE_STATE_KEY = "base"
#: the privileged inputs of an asymmetric critic (simulator truth, training only), written by
#: ``transforms.PrivilegedObservation``
PRIVILEGED_KEY = "privileged"
#: a recurrent policy's hidden state ([1, H] per row), carried by the env between decisions
#: (``RLEnvSpec.recurrent_hidden``) and reset with the episode (``is_init``)
RECURRENT_KEY = "recurrent_state"
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


#: the observation entry holding the residual applied over the last control step, by what the
#: residual acts on (``ResidualConfig.acts_on``): the wrench (N, N m) or the desired acceleration (m/s^2)
RESIDUAL_ENTRY: dict[str, str] = {"wrench": "ff_wrench", "acceleration": "ff_acc"}
#: the policy observation's last channels: that residual divided by its action scale, by ``acts_on``
#: (the acceleration's in the reference heading's frame, as it is applied)
RESIDUAL_CHANNELS: dict[str, tuple[str, ...]] = {
    "wrench": ("ff_T", "ff_x", "ff_y", "ff_z"),
    "acceleration": ("ff_acc_fwd", "ff_acc_left", "ff_acc_U"),
}
_SHARED_CHANNELS: tuple[str, ...] = ("alt", "vel_fwd", "vel_left") + kinematic_channels("ref_relative")[3:] + (
    "wind_fwd", "wind_left",
    "err_fwd", "err_left", "err_U",
    "pd_thrust_over_weight",
)  # fmt: skip


def observation_channels(residual_on: str = "wrench") -> tuple[str, ...]:
    """The policy observation, channel by channel, for a residual on ``residual_on``
    (``ResidualConfig.acts_on``; heading frame: forward, left; see transforms.observation)."""
    if residual_on not in RESIDUAL_CHANNELS:
        raise ValueError(f"residual_on={residual_on!r}; allowed: {tuple(RESIDUAL_CHANNELS)}")
    return _SHARED_CHANNELS + RESIDUAL_CHANNELS[residual_on]


#: the policy observation of the paper's residual (on the wrench), channel by channel
OBSERVATION_CHANNELS: tuple[str, ...] = observation_channels("wrench")
OBSERVATION_DIM = len(OBSERVATION_CHANNELS)


def observation_index(name: str) -> int:
    """Index of channel ``name`` in the policy observation (either residual's layout: they differ
    only in their last channels, which start at the same index)."""
    for channels in RESIDUAL_CHANNELS.values():
        if name in channels:
            return len(_SHARED_CHANNELS) + channels.index(name)
    if name not in _SHARED_CHANNELS:
        raise ValueError(f"observation channel {name!r} unknown; channels: {_SHARED_CHANNELS} followed by those of "
                         f"the residual, {RESIDUAL_CHANNELS}")
    return _SHARED_CHANNELS.index(name)


#: the two wind channels of the observation (what ``wind_input="zero"`` zeroes)
WIND_CHANNELS: tuple[str, str] = ("wind_fwd", "wind_left")
WIND_INDICES: tuple[int, int] = (observation_index(WIND_CHANNELS[0]), observation_index(WIND_CHANNELS[1]))

#: named groups of policy inputs a policy can be trained and flown without (``RLEnvSpec.zero_inputs``,
#: ``--zero-inputs``): the channels through which a memoryless policy could see a steady wind, as
#: the tilt and the thrust the PD holds against it. Here, beside the layout, because a group is a
#: set of its channel names and must change with it; the wind channels are not a group: a policy
#: trains and flies without them by ``wind_input="zero"``, the one way the ablation recognises
INPUT_GROUPS: dict[str, tuple[str, ...]] = {
    "attitude": ("roll", "pitch"),
    "accel": ("acc_bx", "acc_by", "acc_bz"),
    "pd_thrust": ("pd_thrust_over_weight",),
}
#: the channels ``zero_inputs`` may name (of the residual on the wrench): every one but the wind's
ZEROABLE_CHANNELS: tuple[str, ...] = tuple(c for c in OBSERVATION_CHANNELS if c not in WIND_CHANNELS)


def _heading_vector(prefix: str) -> tuple[str, str, str]:
    return f"{prefix}_fwd", f"{prefix}_left", f"{prefix}_U"


#: the base controller's state a policy may read beside the observation (``RLEnvSpec.base_state_inputs``,
#: ``--base-state-inputs``), by group; appended after :data:`OBSERVATION_CHANNELS` in this order.
#: Horizontal parts in the heading frame, as the observation's. What each is, and which base law
#: has it: ``transforms.observation.BASE_STATE_SOURCES``
BASE_STATE_GROUPS: dict[str, tuple[str, ...]] = {
    "force": _heading_vector("base_force"),  # the observer's (or L1's) external force estimate, N
    "thrust": ("base_thrust_over_weight",),  # the thrust the observer models the rotors giving / (m g)
    "integral": _heading_vector("base_int"),  # the integral of the position error, m s
    "vel_err": _heading_vector("base_vel_err"),  # L1's predicted minus measured velocity, m/s
    "ff": _heading_vector("base_ff"),  # the acceleration the base's additions put into its outer loop, m/s^2
}
BASE_STATE_CHANNELS: tuple[str, ...] = tuple(c for group in BASE_STATE_GROUPS.values() for c in group)
#: simulator truth an asymmetric critic may read at training time (``RLEnvSpec.privileged_inputs``,
#: ``--privileged-inputs``), never the actor, by group; horizontal parts in the heading frame
PRIVILEGED_GROUPS: dict[str, tuple[str, ...]] = {
    "mean_wind": _heading_vector("mean_wind"),  # the true turbulence-free mean wind at the vehicle, m/s
    "turbulence": _heading_vector("turb"),  # the true air velocity minus that mean: the turbulence, m/s
    "true_error": _heading_vector("true_err"),  # true position minus the reference, m
    "true_vel_error": _heading_vector("true_vel_err"),  # true velocity minus the reference, m/s
}
PRIVILEGED_CHANNELS: tuple[str, ...] = tuple(c for group in PRIVILEGED_GROUPS.values() for c in group)
#: s: how far ahead of now the reference preview looks (``RLEnvSpec.preview_inputs``). Half a second
#: is about the position loop's time constant (the paper's kp 5 /s^2, kd 3.5 /s: 1 / (zeta omega_n) =
#: 0.57 s); two seconds are 20 m of path at the 10 m/s cruise speed, over which a 50 m radius turn
#: (the racetrack's) turns the heading by 23 deg: long enough to see a turn coming and start it early,
#: as a model-predictive controller does over its horizon
REFERENCE_AHEAD_S: tuple[float, ...] = (0.5, 1.0, 2.0)
#: the reference ahead a policy may read beside the observation (``RLEnvSpec.preview_inputs``,
#: ``--preview-inputs``), one group per horizon of :data:`REFERENCE_AHEAD_S`: where the reference will
#: be that long from now, from the vehicle's navigation position (m; horizontal parts in the heading
#: frame, as the observation's). What a controller that plans can read and a reactive one cannot
PREVIEW_GROUPS: dict[str, tuple[str, ...]] = {
    f"ahead_{h:g}s": _heading_vector(f"ahead_{h:g}s") for h in REFERENCE_AHEAD_S
}
PREVIEW_CHANNELS: tuple[str, ...] = tuple(c for group in PREVIEW_GROUPS.values() for c in group)


def named_channels(names: Sequence[str], groups: dict[str, tuple[str, ...]], field: str,
                   allowed: Sequence[str] | None = None) -> tuple[str, ...]:
    """The channels of ``names`` (group names of ``groups`` or channel names), each once, in the
    groups' order; a ``ValueError`` naming ``field``, the unknown names and the allowed ones
    unless every channel is in ``allowed`` (default: all the groups' channels)."""
    catalogue = tuple(c for group in groups.values() for c in group)
    allowed = catalogue if allowed is None else tuple(allowed)
    if isinstance(names, str) or not all(isinstance(n, str) for n in names):
        raise ValueError(f"{field}={names!r}; allowed: a sequence of names of the groups {sorted(groups)} or the "
                         f"channels {allowed}")
    usable = sorted(g for g, cs in groups.items() if all(c in allowed for c in cs))
    unknown = [n for n in names if n not in groups and n not in catalogue]
    if unknown:
        raise ValueError(f"{field}={tuple(names)!r}: unknown {unknown}; allowed: the groups {usable} or the "
                         f"channels {allowed}")
    missing = [n for n in names if any(c not in allowed for c in groups.get(n, (n,)))]
    if missing:
        raise ValueError(f"{field}={tuple(names)!r}: {missing} not available here; allowed: the groups {usable} or "
                         f"the channels {allowed}")
    chosen = {c for n in names for c in groups.get(n, (n,))}
    return tuple(c for c in catalogue if c in chosen)


def input_channels(names: Sequence[str]) -> tuple[str, ...]:
    """The channels of ``names`` (group names of :data:`INPUT_GROUPS` or channel names), each once,
    in observation order (one spelling per set of channels, so that two runs zeroing the same
    inputs record the same ``zero_inputs``)."""
    unknown = [n for n in names if n not in INPUT_GROUPS and n not in OBSERVATION_CHANNELS]
    if unknown:
        raise ValueError(f"zero_inputs: unknown {unknown}; allowed: the groups {sorted(INPUT_GROUPS)} "
                         f"or the channels {ZEROABLE_CHANNELS}")
    chosen = {c for n in names for c in INPUT_GROUPS.get(n, (n,))}
    return tuple(c for c in OBSERVATION_CHANNELS if c in chosen)
