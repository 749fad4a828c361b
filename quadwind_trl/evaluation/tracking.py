"""Fly evaluation sweeps and tabulate tracking RMSE by wind level and by trajectory."""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from ..config import EnvConfig
from ..envs.runner import fly
from ..envs.trajectories import trajectory_name
from ..regimes import EvalSweep
from .grouping import group_stats, summarize


def fly_sweep(
    env: EnvBase,
    scenarios: TensorDictBase,
    policy: Callable[[TensorDictBase], TensorDictBase] | None = None,
    progress: bool = False,
) -> TensorDict:
    """Per-episode results of ``scenarios`` (their order): ``rmse_xy``, ``rmse_z``, ``rmse``
    (combined), ``crashed``, and the navigation error ``nav_rmse_xy``, ``nav_rmse_z`` (what the
    vehicle cannot see), alongside the scenario fields that label them."""
    res = fly(env, scenarios, policy=policy, progress=progress)
    out = scenarios.select("traj_id", "wind_speed_ref_m_s", "turb_intensity", "case_id", strict=False).clone()
    out["rmse_xy"] = res.rmse_xy
    out["rmse_z"] = res.rmse_z
    out["rmse"] = res.rmse
    out["crashed"] = res.crashed
    out["nav_rmse_xy"] = res.nav_rmse_xy
    out["nav_rmse_z"] = res.nav_rmse_z
    return out


def tracking_tables(episodes: TensorDictBase, metric: str = "rmse_xy") -> dict:
    """JSON-ready summaries of ``metric``: overall, by wind level and by trajectory."""
    values = episodes[metric]
    by_wind = group_stats(values, episodes["wind_speed_ref_m_s"])
    by_traj = group_stats(values, episodes["traj_id"])
    return {
        "metric": metric,
        "all": summarize(values).as_dict(),
        "by_wind": {f"{k:g}": v.as_dict() for k, v in by_wind.items()},
        "by_trajectory": {trajectory_name(k): v.as_dict() for k, v in by_traj.items()},
        "crashed": int(episodes["crashed"].sum()),
    }


QUICK_ALTITUDE_M = 20.0


def quick_config(cfg: EnvConfig) -> EnvConfig:
    """``cfg`` with the short flights of the smoke runs: 10 s patterns, vertical climbs to 30 m."""
    return replace(cfg, trajectories=replace(cfg.trajectories, horizontal_duration_s=10.0, vertical_top_m=30.0))


def quick_subset(sweep: EvalSweep, scenarios: TensorDictBase) -> TensorDictBase:
    """A small, still factorial, smoke subset: one seed, the middle intensity, the weakest and
    strongest wind levels, every trajectory; fixed-altitude patterns flown at 20 m, every flight
    started airborne at its pattern (no climb to fly: a smoke run's seconds go to the pattern)."""
    mid = sweep.intensities[len(sweep.intensities) // 2]
    speeds = scenarios["wind_speed_ref_m_s"]
    keep = (scenarios["seed_index"] == 0) & ((scenarios["turb_intensity"] - mid).abs() < 1e-6)
    keep &= (speeds == min(sweep.wind_speeds)) | (speeds == max(sweep.wind_speeds))
    out = scenarios[keep].clone()
    out["altitude_m"] = torch.where(out["altitude_m"] < sweep.ranges.top_altitude_m, QUICK_ALTITUDE_M, out["altitude_m"])
    out["start_step"] = torch.full_like(out["start_step"], -1)
    return out


def sweep_setup(sweep: EvalSweep, quick: bool = False) -> tuple[TensorDict, Callable[[EnvConfig], EnvConfig] | None]:
    """The episodes of ``sweep`` and the env-config change to fly them with: the sweep as
    designed (no change), or with ``quick`` its smoke subset on short flights."""
    scenarios = sweep.scenarios()
    if not quick:
        return scenarios, None
    return quick_subset(sweep, scenarios), quick_config
