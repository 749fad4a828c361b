"""Flight phases of the 10 Hz flight record and the horizontal tracking error in each.

Two classifications of every scored sample, both read off the reference path and the true mean
wind, never off what a controller flew, so that every controller of a paired ablation is split
over the same samples (crashes aside):

* ``straight`` / ``turn``: the reference's horizontal heading rate below / at or above
  :attr:`PhaseConfig.turn_rate_deg_s`;
* ``headwind`` / ``crosswind`` / ``tailwind``: the angle between the reference ground-velocity
  direction and the direction the mean wind blows *from* (headwind: flying into the wind).

Samples where the reference flies slower than :attr:`PhaseConfig.min_speed_m_s` (the climb, a
hover, the start of the speed ramp) have no heading and get no phase; a sample whose neighbours
are not both in the record (the first and the last of a flight) has no finite difference and gets
none either. Per episode and phase the table keeps the summed squared error and the sample count
(:func:`phase_columns`); :func:`phase_rmse` makes the RMSE, NaN where the episode has no sample in it.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torch import Tensor

from ..config import EnvConfig, TimingConfig, _check_range
from ..envs.runner import FlightResults, scored_samples
from ..envs.simulator import trajectory_library

TURN_PHASES = ("straight", "turn")
WIND_PHASES = ("headwind", "crosswind", "tailwind")
PHASES = TURN_PHASES + WIND_PHASES
LOG_DT_S = TimingConfig().log_dt_s  # the flight record's sample interval (10 Hz)


@dataclass(frozen=True)
class PhaseConfig:
    """Thresholds of the phase classification."""

    # The horizontal patterns fly at 10 m/s: straight legs (racetrack, lawnmower, the figure-8's
    # crossing) turn at 0 deg/s, the slowest constant turn (the 60 m loiter circle) at 9.5 deg/s,
    # the racetrack's 50 m ends at 11.5, the lawnmower's 30 m ends at 19.1, and the cloverleaf
    # never below 5.8. 3 deg/s is a third of the slowest constant turn and well clear of zero:
    # "turn" is every sample with a centripetal demand of 0.5 m/s^2 or more at cruise, so the
    # racetrack's and the lawnmower's legs and turns split exactly, and the figure-8 splits at
    # its flattest quarter (radius above 190 m).
    turn_rate_deg_s: float = 3.0
    # Half the 10 m/s cruise speed: below it the reference is climbing, hovering or in its
    # start-up speed ramp, where the heading rate understates the path's curvature (the loiter
    # circle turns at under 3 deg/s below 3 m/s) and the heading relative to the wind loads the
    # vehicle little.
    min_speed_m_s: float = 5.0
    # Below this the mean wind has no direction worth naming (every sweep's weakest level is 3 m/s).
    min_wind_m_s: float = 0.5
    # Angle (deg) between the ground velocity and the direction the wind blows from: up to
    # ``headwind_max_deg`` is headwind (flying into the wind), from ``tailwind_min_deg`` tailwind,
    # crosswind between; 45 and 135 split the compass into quarters.
    headwind_max_deg: float = 45.0
    tailwind_min_deg: float = 135.0

    def validate(self) -> "PhaseConfig":
        _check_range("PhaseConfig", "turn_rate_deg_s", self.turn_rate_deg_s, 0.0, 180.0)
        _check_range("PhaseConfig", "min_speed_m_s", self.min_speed_m_s, 0.0, 50.0)
        _check_range("PhaseConfig", "min_wind_m_s", self.min_wind_m_s, 0.0, 50.0)
        _check_range("PhaseConfig", "headwind_max_deg", self.headwind_max_deg, 0.0, 180.0)
        _check_range("PhaseConfig", "tailwind_min_deg", self.tailwind_min_deg, self.headwind_max_deg, 180.0)
        return self


def _neighbours_valid(valid: Tensor) -> Tensor:
    """``[n, T]`` bool: the sample and both its neighbours are in the record (a central
    difference exists)."""
    pad = torch.zeros_like(valid[:, :1])
    before = torch.cat((pad, valid[:, :-1]), 1)
    after = torch.cat((valid[:, 1:], pad), 1)
    return valid & before & after


def reference_motion(ref_pos: Tensor, dt_s: float = LOG_DT_S) -> tuple[Tensor, Tensor]:
    """Horizontal velocity ``[n, T, 2]`` (m/s, central differences) and heading rate ``[n, T]``
    (deg/s: the turn between the steps into and out of each sample, over one interval) of the
    reference positions ``[n, T, 3]``; both zero at the first and last sample (no neighbour)."""
    xy = ref_pos[..., :2].double()
    step = xy[:, 1:] - xy[:, :-1]  # [n, T-1, 2]: displacement between consecutive samples
    into, out = step[:, :-1], step[:, 1:]
    velocity = (into + out) / (2.0 * dt_s)
    cross = into[..., 0] * out[..., 1] - into[..., 1] * out[..., 0]
    dot = (into * out).sum(-1)
    rate = torch.rad2deg(torch.atan2(cross, dot)) / dt_s
    edge_v, edge_r = velocity[:, :1] * 0, rate[:, :1] * 0
    return torch.cat((edge_v, velocity, edge_v), 1), torch.cat((edge_r, rate, edge_r), 1)


def wind_angle_deg(velocity_xy: Tensor, mean_wind: Tensor) -> Tensor:
    """``[n, T]`` angle (deg, 0 to 180) between the ground velocity ``[n, T, 2]`` and the direction
    the mean wind ``[n, T, >=2]`` (ENU air velocity: where it blows to) comes from: 0 is flying
    straight into the wind."""
    upwind = -mean_wind[..., :2].double()
    dot = (velocity_xy * upwind).sum(-1)
    cross = velocity_xy[..., 0] * upwind[..., 1] - velocity_xy[..., 1] * upwind[..., 0]
    return torch.rad2deg(torch.atan2(cross.abs(), dot))


def phase_masks(log: TensorDictBase, pattern_start: Tensor, config: PhaseConfig = PhaseConfig(),
                dt_s: float = LOG_DT_S) -> dict[str, Tensor]:
    """``[n, T]`` bool per phase of :data:`PHASES`: the scored samples of a flight record (with
    ``"ref_pos"``, ``("truth", "mean_wind")``, ``"step"`` and ``"valid"``) in that phase."""
    config.validate()
    velocity, rate = reference_motion(log["ref_pos"], dt_s)
    moving = scored_samples(log, pattern_start) & _neighbours_valid(log["valid"])
    moving &= velocity.norm(dim=-1) >= config.min_speed_m_s
    turning = rate.abs() >= config.turn_rate_deg_s
    mean_wind = log["truth", "mean_wind"]
    windy = moving & (mean_wind[..., :2].double().norm(dim=-1) >= config.min_wind_m_s)
    angle = wind_angle_deg(velocity, mean_wind)
    head, tail = angle <= config.headwind_max_deg, angle >= config.tailwind_min_deg
    return {
        "straight": moving & ~turning,
        "turn": moving & turning,
        "headwind": windy & head,
        "crosswind": windy & ~head & ~tail,
        "tailwind": windy & tail,
    }


def masked_sse_xy(log: TensorDictBase, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Per episode ``[n]``: the sum of the squared horizontal error of the true against the
    reference position over the samples of ``mask`` ``[n, T]`` (m^2), and their count."""
    err = (log["truth", "pos"][..., :2] - log["ref_pos"][..., :2]).double().pow(2).sum(-1)
    return torch.where(mask, err, 0.0).sum(-1), mask.sum(-1)


def phase_rmse(sse: Tensor, samples: Tensor) -> Tensor:
    """Per-episode RMSE over a phase from its :func:`phase_columns`; NaN where the episode has no
    sample in the phase."""
    return torch.where(samples > 0, (sse.double() / samples.double().clamp_min(1)).sqrt(), float("nan"))


def phase_columns(results: FlightResults, pattern_start: Tensor, config: PhaseConfig = PhaseConfig(),
                  dt_s: float = LOG_DT_S) -> dict[str, Tensor]:
    """Episode-table columns of one controller's flights: ``sse_xy_<phase>`` (the summed squared
    horizontal error, m^2) and ``samples_<phase>`` (the sample count) for every phase of
    :data:`PHASES`. Sums, not RMSEs: a phase an episode never flies is 0 samples, where an RMSE
    would be NaN, which JSON cannot hold. ``results.log`` must hold
    :data:`~quadwind_trl.evaluation.ablation.TRACE_KEYS`."""
    out = {}
    for phase, mask in phase_masks(results.log, pattern_start, config, dt_s).items():
        sse, count = masked_sse_xy(results.log, mask)
        out[f"sse_xy_{phase}"] = sse.float()
        out[f"samples_{phase}"] = count.float()
    return out


def pattern_starts(scenarios: TensorDictBase, config: EnvConfig) -> Tensor:
    """``[n]`` the control step each scenario's pattern starts at, for the env config it was flown
    with (what :func:`~quadwind_trl.envs.runner.scored_samples` needs)."""
    start, _ = trajectory_library(config, torch.device("cpu")).schedule(scenarios["traj_id"].cpu(),
                                                                         scenarios["altitude_m"].cpu())
    return start

