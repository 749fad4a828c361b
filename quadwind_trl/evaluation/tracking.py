"""Fly evaluation sweeps and tabulate tracking RMSE by wind level and by trajectory."""
from __future__ import annotations

from functools import partial, reduce
from typing import Callable

from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase

from ..config import EnvConfig, MonitorConfig, with_monitor
from ..envs.runner import fly
from ..envs.trajectories import trajectory_name
from ..quick import SWEEP_QUICK
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


def quick_subset(sweep: EvalSweep, scenarios: TensorDictBase) -> TensorDictBase:
    """A small, still factorial, smoke subset: one seed, the middle intensity, the weakest and
    strongest wind levels, every trajectory; flown as :data:`~quadwind_trl.quick.SWEEP_QUICK`
    says (airborne from the pattern start, fixed-altitude patterns at 20 m)."""
    mid = sweep.intensities[len(sweep.intensities) // 2]
    speeds = scenarios["wind_speed_ref_m_s"]
    keep = (scenarios["seed_index"] == 0) & ((scenarios["turb_intensity"] - mid).abs() < 1e-6)
    keep &= (speeds == min(sweep.wind_speeds)) | (speeds == max(sweep.wind_speeds))
    return SWEEP_QUICK.scenarios(scenarios[keep], sweep.ranges.top_altitude_m)


def sweep_setup(sweep: EvalSweep, quick: bool = False, monitor: MonitorConfig | None = None
                ) -> tuple[TensorDict, Callable[[EnvConfig], EnvConfig] | None]:
    """The episodes of ``sweep`` and the env-config change to fly them with: the sweep as
    designed (no change), or with ``quick`` its smoke subset on the short flights of
    :data:`~quadwind_trl.quick.SWEEP_QUICK`; with ``monitor``, the runtime monitor switched on
    (:func:`~quadwind_trl.config.with_monitor`: a trained policy flown with it unretrained; PD's
    zero residual is left unchanged)."""
    scenarios = sweep.scenarios()
    changes = [SWEEP_QUICK.config] if quick else []
    if quick:
        scenarios = quick_subset(sweep, scenarios)
    if monitor is not None:
        changes.append(partial(with_monitor, monitor=monitor))
    if not changes:
        return scenarios, None
    return scenarios, lambda cfg: reduce(lambda c, change: change(c), changes, cfg)
