"""A saved policy against PD on its regime's validation sweep, as training evaluates it, with or
without the runtime monitor (``MonitorConfig``; docs/rl.md, "Runtime monitor").

The flights are the trainer's periodic evaluation (:func:`~quadwind_trl.rl.paired.validation_scenarios`,
the whole selection in one batch, the policy's own env) flown through
:func:`~quadwind_trl.evaluation.ablation.fly_controllers`, and the metrics are the trainer's
(:func:`~quadwind_trl.rl.paired.paired_metrics`, including ``validation_score``). The monitor is a
config override, so a policy trained without it flies with it unretrained; PD flies in the same
env (its residual is zero, which the monitor leaves zero: its flights do not change). With the
monitor, ``monitor_active_fraction`` is the share of the flight record's scored 10 Hz samples
(all episodes together) at which the monitor held the residual at zero over the last control
step, ``monitor_active_fraction_max`` the largest share in one episode; with the RL regimes' one
decision per 10 Hz tick, every scored step is a sample.
"""
from __future__ import annotations

from functools import partial
from pathlib import Path

import torch

from ..config import EnvConfig, MonitorConfig, with_monitor
from ..envs.runner import FlightResults, scored_samples
from ..envs.simulator import trajectory_library
from ..estimator import load_estimator
from ..keys import MONITOR_KEY
from ..quick import PPO_QUICK
from ..rl.envs import DEFAULT_RANGES
from ..rl.paired import paired_metrics, validation_scenarios
from ..rl.policy import load_policy
from .ablation import WIND_INPUT, fly_controllers, policy_env_config

# the ablation controllers that fly the main policy, one per wind input (``WIND_INPUT``)
POLICY_CONTROLLERS = ("aware", "blind", "oracle")


def validate_policy(policy_path: str | Path, estimator_path: str | Path | None = None, *,
                    monitor: MonitorConfig | None = None, episodes: int | None = None, quick: bool = False,
                    compile_step: bool | None = None, progress: bool = False) -> dict:
    """The trainer's evaluation metrics of the policy at ``policy_path`` against PD on ``episodes``
    of its regime's validation sweep (None: all), with ``monitor`` on (None: off).

    ``estimator_path``: default the one the policy trained with. ``quick``: the PPO recipes'
    ``--quick`` flights (:data:`~quadwind_trl.quick.PPO_QUICK`). ``compile_step``: default as the
    policy trained."""
    payload = load_policy(policy_path)[1]
    spec = payload["env_spec"]
    regime = spec["regime"]
    scenarios = validation_scenarios(regime, episodes)
    changes = [partial(with_monitor, monitor=monitor)] if monitor is not None else []
    if quick:
        scenarios = PPO_QUICK[regime].scenarios(scenarios, DEFAULT_RANGES[regime].top_altitude_m)
        changes.append(PPO_QUICK[regime].config)

    def override(config: EnvConfig) -> EnvConfig:
        for change in changes:
            config = change(config)
        return config

    config = override(policy_env_config(payload))
    wind_input = spec.get("wind_input", "estimate")
    controller = next(c for c in POLICY_CONTROLLERS if WIND_INPUT[c] == wind_input)  # flown as it trained
    estimator = None if controller == "oracle" else load_estimator(
        regime, estimator_path or spec.get("estimator_path"), untrained=spec.get("untrained_estimator", False),
        config=config)
    flown = fly_controllers(regime, scenarios, policy_path, estimator, ("pd", controller), progress=progress,
                            config_override=override, compile_step=compile_step,
                            log_keys=("step",) + ((MONITOR_KEY,) if monitor is not None else ()))
    metrics = paired_metrics(flown[controller], flown["pd"])
    if monitor is not None:
        pattern_start, _ = trajectory_library(config, torch.device("cpu")).schedule(scenarios["traj_id"],
                                                                                   scenarios["altitude_m"])
        metrics.update(monitor_authority(flown[controller], pattern_start))
    return metrics


def monitor_authority(res: FlightResults, pattern_start: torch.Tensor) -> dict[str, float]:
    """The share of scored samples with the monitor active (all episodes together) and the largest
    share in one episode, from a flight record holding :data:`~quadwind_trl.keys.MONITOR_KEY`."""
    scored = scored_samples(res.log, pattern_start)
    active = res.log[MONITOR_KEY].squeeze(-1) & scored
    per_episode = active.sum(-1).double() / scored.sum(-1).clamp_min(1)
    return {"monitor_active_fraction": int(active.sum()) / max(int(scored.sum()), 1),
            "monitor_active_fraction_max": float(per_episode.max())}

