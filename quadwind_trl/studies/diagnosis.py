"""Where a residual policy's worst episodes come from: per-step flight diagnostics against the
vehicle's and the policy's limits, beside PD on the same replayed worlds (docs/rl.md, "Where the
tail comes from").

The ablation's episodes are re-flown by :func:`~quadwind_trl.evaluation.ablation.fly_controllers`
in the batch layout their results file records (only that layout replays bit for bit), with a
richer 10 Hz record (:data:`DIAGNOSIS_LOG_KEYS`). From it, per step and episode:

* the position error against the reference (the truth, as the RMSE scores it);
* the PD's commanded tilt and the actual tilt against ``ControllerConfig.max_tilt_deg``, and the
  commanded collective thrust against the rotors' collective limit;
* the residual: the policy's action (re-evaluated from its logged input, deterministic) and the
  applied, smoothed correction ``ff`` / action scale;
* the policy's observation normalised by the frozen running statistics of training, *before*
  the clip (recomputed from the logged inputs by the env's own transforms): a value beyond
  :data:`OUT_OF_RANGE_Z` standard deviations from the training mean is an input training rarely
  or never showed the policy; beyond the clip (``RLEnvSpec.obs_clip``) the policy sees the clip
  (inputs it trained without, ``RLEnvSpec.zero_inputs``, are 0);
* the wind estimate against the true mean wind.

:func:`episode_indicators` reduces these to per-episode fractions over the scored part of the
flight, which :func:`compare_groups` and :func:`correlations` set against the excess error.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor

from ..config import EnvConfig
from ..envs.rotations import quat_to_rotmat
from ..envs.runner import FlightResults, NestedKey, scored_samples
from ..envs.vehicle import VehicleParams
from ..evaluation.ablation import TRACE_KEYS, fly_controllers, policy_env_config
from ..evaluation.figures import COLORS, LABELS, plt, save_figure
from ..keys import (MEAN_WIND_KEY, MEAS_KEY, OBSERVATION_KEY, RESIDUAL_CHANNELS, RESIDUAL_ENTRY, WIND_KEY,
                    observation_channels)
from ..rl.envs import find_transform, make_env, policy_env_settings, vecnorm
from ..rl.policy import load_policy
from ..transforms import PolicyObservation, ZeroInputs

#: the 10 Hz record a diagnosis needs: the ablation's trace, every input of the policy
#: observation (so that it can be recomputed before normalisation), the policy's normalised and
#: clipped input itself, the PD and total commands and the attitude (of a residual on the wrench:
#: :func:`diagnosis_log_keys` names the residual's entry of another)
DIAGNOSIS_LOG_KEYS: tuple[NestedKey, ...] = TRACE_KEYS + (
    MEAS_KEY, "ref_yaw", "pos_error", "pd_wrench", "ff_wrench", "cmd_wrench", "tilt_cmd", "tilt_saturated",
    ("truth", "quat"), WIND_KEY, OBSERVATION_KEY,
)


def diagnosis_log_keys(config: EnvConfig) -> tuple[NestedKey, ...]:
    """:data:`DIAGNOSIS_LOG_KEYS` for a policy of ``config``: its residual's entry (``ff_wrench`` or ``ff_acc``)."""
    ff = RESIDUAL_ENTRY["wrench"]
    return tuple(RESIDUAL_ENTRY[config.residual.acts_on] if key == ff else key for key in DIAGNOSIS_LOG_KEYS)


#: |normalised observation| beyond which an input is outside what training showed the policy
#: (running mean and std over all training rollouts: a Gaussian channel passes 5 sigma once in
#: ~3.5 million samples, about two training runs of steps)
OUT_OF_RANGE_Z = 5.0
#: |action| at or above this is at the tanh's end: the residual is saturated
ACTION_SATURATED = 0.95
#: commanded collective thrust at or above this fraction of the limit counts as thrust-saturated
THRUST_SATURATED = 0.98


@dataclass(frozen=True)
class Limits:
    """The limits the diagnostics are measured against, from the env config the policy flew."""

    max_tilt_rad: float
    thrust_max_n: float  # the collective the rotors can give (all four at full speed, or the config's cap)
    obs_clip: float | None

    @classmethod
    def of(cls, config: EnvConfig, obs_clip: float | None) -> "Limits":
        return cls(math.radians(config.controller.max_tilt_deg), VehicleParams.from_config(config.vehicle).collective_limit,
                   obs_clip)


def step_diagnostics(res: FlightResults, scenarios: TensorDictBase, payload: dict, config: EnvConfig,
                     actor=None) -> TensorDict:
    """Per-step diagnostics ``[n, T]`` of one controller's flights (recorded with
    :data:`DIAGNOSIS_LOG_KEYS`) flown with the policy of checkpoint ``payload`` (its frozen
    normalisation and observation clip). ``actor``: the policy, to re-evaluate its action on the
    logged input (omit for PD: its action is zero). ``scored`` marks the steps the RMSE scores
    (after the pattern starts, while the episode runs)."""
    log = res.log
    n, t = log.batch_size
    flat = log.reshape(-1)
    limits = Limits.of(config, payload["env_spec"].get("obs_clip"))
    # the env's own transforms, so the raw and normalised inputs are the policy's by construction
    zero_inputs = policy_env_settings(payload["env_spec"], None)["zero_inputs"]
    env = make_env("horizontal" if payload["env_spec"]["regime"] == "horizontal" else "vertical", None, 1,
                   wind_input="truth", config=config, vecnorm_state=payload["vecnorm"], compile_step=False,
                   zero_inputs=zero_inputs)
    build = find_transform(env, PolicyObservation)
    raw = build(flat.select(*build.in_keys).clone()).select(OBSERVATION_KEY)
    # the frozen normaliser's own step (no update: it is frozen), without the clip that follows it
    normalised = vecnorm(env)._step(raw, raw.clone())
    if zero_inputs:  # inputs the policy trained without: 0 whatever their value, never out of range
        normalised = find_transform(env, ZeroInputs)(normalised)
    normalised = normalised[OBSERVATION_KEY]
    err = flat["truth", "pos"] - flat["ref_pos"]
    up = quat_to_rotmat(flat["truth", "quat"])[..., 2, 2].clamp(-1.0, 1.0)
    mean_wind = flat.get(MEAN_WIND_KEY)
    wind_true_ne = torch.stack((mean_wind[..., 1], mean_wind[..., 0]), -1)
    out = TensorDict(
        err_xy=err[..., :2].norm(dim=-1),
        err_z=err[..., 2],
        tilt_cmd=flat["tilt_cmd"].squeeze(-1) / limits.max_tilt_rad,  # fraction of the limit
        tilt=torch.acos(up) / limits.max_tilt_rad,
        tilt_saturated=flat["tilt_saturated"].squeeze(-1),
        thrust=flat["cmd_wrench"][..., 0] / limits.thrust_max_n,
        ff=flat[RESIDUAL_ENTRY[config.residual.acts_on]] / torch.tensor(config.residual.scale),
        obs_z=normalised,
        clipped_ok=(normalised.clamp(-limits.obs_clip, limits.obs_clip) - flat[OBSERVATION_KEY]).abs().amax(-1)
        if limits.obs_clip is not None else (normalised - flat[OBSERVATION_KEY]).abs().amax(-1),
        wind_err=(flat[WIND_KEY] - wind_true_ne).norm(dim=-1),
        wind_true=wind_true_ne.norm(dim=-1),
        wind_hat=flat[WIND_KEY].norm(dim=-1),
        batch_size=[n * t],
    )
    if actor is not None:
        with torch.no_grad():
            out["action"] = actor(flat.select(OBSERVATION_KEY).clone())["action"]
    else:
        out["action"] = torch.zeros(n * t, config.residual.channels)
    out = out.reshape(n, t)
    pattern_start, _ = env.base_env.sim.trajectories.schedule(scenarios["traj_id"], scenarios["altitude_m"])
    out["scored"] = scored_samples(log, pattern_start)
    out["time_s"] = log["step"].squeeze(-1) * config.timing.control_dt_s
    return out


def fly_recorded_layout(recorded: dict, policy_path, estimator, controllers: Sequence[str] = ("pd", "aware"),
                        progress: bool = True) -> dict[str, FlightResults]:
    """Re-fly every episode of an ablation results file (``recorded``) with ``controllers``, in the
    layout it records (its ``batch`` and ``compile_step``: only that layout replays it bit for
    bit), recording :data:`DIAGNOSIS_LOG_KEYS`."""
    from ..regimes import SWEEP_REGIME, SWEEPS

    if recorded.get("quick"):
        raise ValueError("a diagnosis re-flies the full sweep; this results file holds --quick flights")
    sweep = recorded["sweep"]
    return fly_controllers(SWEEP_REGIME[sweep], SWEEPS[sweep].scenarios(), policy_path, estimator, tuple(controllers),
                           batch=recorded["batch"], progress=progress, compile_step=recorded["compile_step"],
                           log_keys=diagnosis_log_keys(policy_env_config(load_policy(policy_path)[1])))


def _scored_mean(x: Tensor, scored: Tensor) -> Tensor:
    """Per-episode mean of ``x`` ``[n, T]`` over the scored steps."""
    return torch.where(scored, x.float(), 0.0).sum(-1) / scored.sum(-1).clamp_min(1)


def episode_indicators(diag: TensorDictBase, obs_clip: float | None) -> TensorDict:
    """Per-episode ``[n]`` reductions of :func:`step_diagnostics` over the scored steps: the time
    fractions at each limit, how far and how often the inputs leave the training range (and which
    channels), the residual's size, and the wind estimate's error."""
    s = diag["scored"]
    z = diag["obs_z"].abs()
    oor = z > OUT_OF_RANGE_Z
    action = diag["action"].abs()
    out = TensorDict(
        tilt_cmd_saturated=_scored_mean(diag["tilt_saturated"], s),
        tilt_beyond_limit=_scored_mean(diag["tilt"] > 1.0, s),
        thrust_saturated=_scored_mean(diag["thrust"] >= THRUST_SATURATED, s),
        obs_out_of_range=_scored_mean(oor.any(-1), s),
        obs_clipped=_scored_mean((z > obs_clip).any(-1) if obs_clip is not None else torch.zeros_like(s), s),
        obs_max_z=torch.where(s.unsqueeze(-1), z, 0.0).amax((-1, -2)),
        # per channel: the fraction of scored steps that channel is out of range
        obs_out_of_range_by_channel=torch.where(s.unsqueeze(-1), oor.float(), 0.0).sum(1) / s.sum(-1, keepdim=True).clamp_min(1),
        action_saturated=_scored_mean((action >= ACTION_SATURATED).any(-1), s),
        action_mean_abs=torch.where(s.unsqueeze(-1), action, 0.0).sum(1) / s.sum(-1, keepdim=True).clamp_min(1),
        wind_estimate_error=_scored_mean(diag["wind_err"], s),
        wind_true=_scored_mean(diag["wind_true"], s),
        err_xy_max=torch.where(s, diag["err_xy"], 0.0).amax(-1),
        height_loss_max=torch.where(s, -diag["err_z"], 0.0).amax(-1),
        batch_size=[diag.batch_size[0]],
    )
    return out


def rank_episodes(table: TensorDictBase, count: int) -> dict[str, list[int]]:
    """Episode rows by the stated rules, worst first: the largest wind-aware xy RMSE (the
    diagnosis's primary selection), the largest wind-aware minus PD xy RMSE, the largest
    wind-aware z RMSE, and the ``count`` episodes around the median wind-aware xy RMSE (the
    contrast group)."""
    order = torch.argsort(table["aware_rmse_xy"], descending=True, stable=True)
    mid = order.numel() // 2
    return {
        "worst_xy": order[:count].tolist(),
        "worst_excess_xy": torch.argsort(table["aware_rmse_xy"] - table["pd_rmse_xy"], descending=True, stable=True)[:count].tolist(),
        "worst_z": torch.argsort(table["aware_rmse_z"], descending=True, stable=True)[:count].tolist(),
        "median_xy": order[mid - count // 2: mid - count // 2 + count].tolist(),
    }


def _ranks(x: Tensor) -> Tensor:
    """Ranks from 0, ties given their mean rank (many indicators are 0 on most episodes)."""
    x = x.double()
    below = (x.unsqueeze(0) < x.unsqueeze(1)).sum(1).double()
    equal = (x.unsqueeze(0) == x.unsqueeze(1)).sum(1).double()
    return below + (equal - 1) / 2


def spearman(x: Tensor, y: Tensor) -> float:
    """Spearman rank correlation (NaN where either variable is constant)."""
    rx, ry = _ranks(x), _ranks(y)
    rx, ry = rx - rx.mean(), ry - ry.mean()
    denom = (rx.norm() * ry.norm()).item()
    return float((rx * ry).sum().item() / denom) if denom > 0 else float("nan")


#: the scalar indicators the group tables and correlations report
SCALAR_INDICATORS = ("tilt_cmd_saturated", "tilt_beyond_limit", "thrust_saturated", "obs_out_of_range", "obs_clipped",
                     "obs_max_z", "action_saturated", "wind_estimate_error", "wind_true", "err_xy_max", "height_loss_max")


def group_summary(indicators: dict[str, TensorDictBase], rows: Sequence[int], residual_on: str = "wrench") -> dict:
    """Mean of every scalar indicator per controller over ``rows``, and the observation channels
    most often out of range (wind-aware flights), named in the layout of a residual on
    ``residual_on`` (``ResidualConfig.acts_on``), as are the action's components."""
    channels = observation_channels(residual_on)
    # the action's components are the observation's own-correction channels without their prefix
    components = tuple(c.removeprefix("ff_acc_").removeprefix("ff_") for c in RESIDUAL_CHANNELS[residual_on])
    idx = torch.tensor(list(rows))
    out = {name: {k: ind[k][idx].double().mean().item() for k in SCALAR_INDICATORS} for name, ind in indicators.items()}
    by_channel = indicators["aware"]["obs_out_of_range_by_channel"][idx].double().mean(0)
    top = torch.argsort(by_channel, descending=True)[:5]
    out["aware"]["channels_out_of_range"] = {channels[i]: by_channel[i].item() for i in top.tolist() if by_channel[i] > 0}
    mean_abs = indicators["aware"]["action_mean_abs"][idx].double().mean(0)
    out["aware"]["action_mean_abs"] = dict(zip(components, mean_abs.tolist(), strict=True))
    return out


def correlations(table: TensorDictBase, indicators: dict[str, TensorDictBase]) -> dict:
    """Spearman correlation over all episodes of the excess error (wind-aware minus PD RMSE, xy
    and z) with each wind-aware indicator, and with its change from PD's flight of the same world."""
    excess = {"xy": table["aware_rmse_xy"] - table["pd_rmse_xy"], "z": table["aware_rmse_z"] - table["pd_rmse_z"]}
    aware, pd = indicators["aware"], indicators["pd"]
    out = {}
    for axis, e in excess.items():
        out[axis] = {
            **{f"aware_{k}": spearman(aware[k], e) for k in SCALAR_INDICATORS},
            **{f"pd_{k}": spearman(pd[k], e) for k in ("tilt_cmd_saturated", "thrust_saturated", "err_xy_max")},
            **{f"delta_{k}": spearman(aware[k] - pd[k], e) for k in ("tilt_cmd_saturated", "tilt_beyond_limit", "thrust_saturated")},
        }
    return out


def reproduction(recorded: dict, results: dict[str, FlightResults], rows: Sequence[int] | None = None) -> dict:
    """The re-flown per-episode RMSEs and crash flags against the recorded episode table, per
    controller: how many are bitwise identical and the largest relative deviation (``rows``:
    only these episodes)."""
    table = recorded["episodes_table"]
    out = {}
    for name, res in results.items():
        idx = list(range(res.rmse_xy.numel())) if rows is None else list(rows)
        values = []
        for metric in ("rmse_xy", "rmse_z"):
            flown = getattr(res, metric)
            values += [(table[f"{name}_{metric}"][i], float(flown[i])) for i in idx]
        rel = [abs(b - a) / abs(a) if a else abs(b) for a, b in values]
        flags = sum(bool(table[f"{name}_crashed"][i]) != bool(res.crashed[i]) for i in idx)
        out[name] = {"values": len(values), "identical": sum(a == b for a, b in values), "max_relative": max(rel),
                     "crash_flags_changed": flags}
    return out


# --- figures --------------------------------------------------------------------------------


def diagnosis_episode(diag: dict[str, TensorDictBase], row: int, title: str, path: Path,
                      out_of_range_z: float, obs_clip: float | None) -> Path:
    """One episode's flight diagnostics (:func:`step_diagnostics` per controller),
    PD beside wind-aware RL over the scored part: position error, commanded (and, for RL, actual)
    tilt and thrust as fractions of their limits, the residual action, the largest normalised
    input against the training range, and the wind estimate against the true mean wind."""
    fig, ax = plt.subplots(6, 1, figsize=(10, 13), sharex=True)
    for name in ("pd", "aware"):
        d = diag[name][row]
        s = d["scored"].numpy()
        t = d["time_s"].numpy()[s]
        t0 = t[0]
        style = dict(color=COLORS[name], lw=0.8)
        ax[0].plot(t - t0, d["err_xy"].numpy()[s], label=f"{LABELS[name]}: xy", **style)
        ax[0].plot(t - t0, d["err_z"].numpy()[s], ls=":", label=f"{LABELS[name]}: z", **style)
        ax[1].plot(t - t0, d["tilt_cmd"].numpy()[s], label=f"{LABELS[name]}: commanded", **style)
        ax[2].plot(t - t0, d["thrust"].numpy()[s], label=LABELS[name], **style)
        if name == "aware":
            ax[1].plot(t - t0, d["tilt"].numpy()[s], color="k", lw=0.5, alpha=0.6, label=f"{LABELS[name]}: actual")
            for k, channel in enumerate(("thrust", "x torque", "y torque", "z torque")):
                ax[3].plot(t - t0, d["action"].numpy()[s][:, k], lw=0.6, label=channel)
            z = d["obs_z"].abs().numpy()[s]
            ax[4].plot(t - t0, z.max(-1), color=COLORS[name], lw=0.6, label="max over channels")
            ax[5].plot(t - t0, d["wind_hat"].numpy()[s], lw=0.8, color=COLORS[name], label="estimate (|wind_hat|)")
            ax[5].plot(t - t0, d["wind_true"].numpy()[s], lw=0.8, color="k", label="true mean wind")
            ax[5].plot(t - t0, d["wind_err"].numpy()[s], lw=0.6, color="tab:gray", label="|estimate - true|")
    ax[0].set(ylabel="position error (m)", title=title)
    ax[1].axhline(1.0, color="k", ls="--", lw=0.7)
    ax[1].set(ylabel="tilt / limit")
    ax[2].axhline(1.0, color="k", ls="--", lw=0.7)
    ax[2].set(ylabel="thrust / limit")
    ax[3].set(ylabel="residual action", ylim=(-1.05, 1.05))
    ax[4].axhline(out_of_range_z, color="k", ls="--", lw=0.7, label=f"training range ({out_of_range_z:g} sigma)")
    if obs_clip is not None:
        ax[4].axhline(obs_clip, color="tab:red", ls="--", lw=0.7, label=f"observation clip ({obs_clip:g})")
    ax[4].set(ylabel="|normalised input|", yscale="log")
    ax[5].set(ylabel="wind speed (m/s)", xlabel="time since the pattern start (s)")
    for a in ax:
        a.legend(fontsize=7, loc="upper right", ncol=2)
        a.grid(alpha=0.3)
    return save_figure(fig, path)


def diagnosis_groups(groups: dict[str, dict], path: Path) -> Path:
    """Per sweep (columns), the worst episodes one by one and the median group's mean (rows):
    xy RMSE, the fraction of the pattern with the PD's tilt command at its limit, the actual tilt
    beyond it, the thrust at its limit, an input outside the training range, and the wind
    estimate's error.
    ``groups[sweep]``: ``{"labels": [...], "<indicator>": {"pd": [...], "aware": [...]}}``, the last
    label the median group."""
    rows = (("rmse_xy", "xy RMSE (m)", ("pd", "aware")),
            ("tilt_cmd_saturated", "time PD tilt\ncommand at limit", ("pd", "aware")),
            ("tilt_beyond_limit", "time actual tilt\nbeyond limit", ("pd", "aware")),
            ("thrust_saturated", "time thrust\nat limit", ("pd", "aware")),
            ("obs_out_of_range", "time with input\noutside training", ("aware",)),
            ("wind_estimate_error", "wind estimate\nerror (m/s)", ("aware",)))
    fig, ax = plt.subplots(len(rows), len(groups), figsize=(6 * len(groups), 1.9 * len(rows) + 1), squeeze=False,
                           sharex="col")
    for j, (sweep, g) in enumerate(groups.items()):
        x = np.arange(len(g["labels"]))
        for i, (key, label, names) in enumerate(rows):
            a = ax[i, j]
            width = 0.8 / len(names)
            for k, name in enumerate(names):
                a.bar(x + (k - (len(names) - 1) / 2) * width, g[key][name], width, color=COLORS[name], label=LABELS[name])
            a.set(ylabel=label)
            a.set_xticks(x, g["labels"], rotation=60, fontsize=7)
            a.grid(alpha=0.3, axis="y")
            if i == 0:
                a.set_title(f"{sweep}: worst 10 by wind-aware xy RMSE; median group")
                a.legend(fontsize=7)
    return save_figure(fig, path)
