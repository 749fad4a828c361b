"""Saved policies against PD on their regime's validation sweep, as training evaluates them, with
or without the runtime monitor (``MonitorConfig``; docs/rl.md, "Runtime monitor"), episode by
episode against the flight envelope.

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

Several policies of one regime are validated on the same episodes: PD flies them once, each
policy in turn (:func:`validate_policies`); they must share the env config they trained in, so
that PD's episodes are each policy's worlds, and each policy's metrics are the ones it gets
validated alone. Each episode's airspeed demand is the one :mod:`~quadwind_trl.evaluation.envelope`
defines (pattern speed + mean wind + ``GUST_SIGMAS`` sigma_u, and the sustained demand without
the gusts) at its own shear and its flight altitude, against the envelope of the policies' own
vehicle and PD cascade; the summary splits the episodes at a gust margin of zero (``within``,
``beyond``), since a vehicle flying beyond its envelope loses ground whatever flies it.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable, Sequence

import torch
from tensordict import TensorDict, TensorDictBase

from ..config import EnvConfig, MonitorConfig, config_differences, with_monitor
from ..envs.envelope import FlightEnvelope, flight_envelope
from ..envs.runner import FlightResults, scored_samples
from ..envs.trajectories import fixed_altitude_mask, trajectory_name
from ..estimator import load_estimator
from ..keys import MONITOR_KEY
from ..quick import PPO_QUICK
from ..rl.envs import DEFAULT_RANGES
from ..rl.paired import improvement, paired_metrics, validation_scenarios, win_rate
from ..rl.policy import load_policy
from .ablation import WIND_INPUT, fly_controllers, policy_compile_step, policy_env_config
from .envelope import airspeed_demand, pattern_speed
from .phases import pattern_starts

# the ablation controllers that fly the main policy, one per wind input (``WIND_INPUT``)
POLICY_CONTROLLERS = ("aware", "blind", "oracle")
RMSE_KEYS = ("rmse_xy", "rmse_z", "rmse")
SCENARIO_KEYS = ("traj_id", "wind_speed_ref_m_s", "turb_intensity", "shear_alpha")


@dataclass(frozen=True)
class PolicyValidation:
    """What :func:`validate_policies` measured."""

    metrics: dict[str, dict[str, float]]  # per policy label, in the order given: validate_policy's metrics
    episodes: TensorDict  # [N] per-episode table (:func:`episode_table`)
    envelope: FlightEnvelope  # of the policies' vehicle and PD cascade
    pattern_speed_m_s: float  # the horizontal speed the demand counts the regime's patterns at


def validate_policy(policy_path: str | Path, estimator_path: str | Path | None = None, *,
                    monitor: MonitorConfig | None = None, episodes: int | None = None, quick: bool = False,
                    compile_step: bool | None = None, progress: bool = False) -> dict:
    """The trainer's evaluation metrics of the policy at ``policy_path`` against PD on ``episodes``
    of its regime's validation sweep (None: all), with ``monitor`` on (None: off).

    ``estimator_path``: default the one the policy trained with. ``quick``: the PPO recipes'
    ``--quick`` flights (:data:`~quadwind_trl.quick.PPO_QUICK`). ``compile_step``: default as the
    policy trained."""
    result = validate_policies([policy_path], estimator_path, monitor=monitor, episodes=episodes, quick=quick,
                               compile_step=compile_step, progress=progress)
    return next(iter(result.metrics.values()))


def validate_policies(policy_paths: Sequence[str | Path], estimator_path: str | Path | None = None, *,
                      monitor: MonitorConfig | None = None, episodes: int | None = None, quick: bool = False,
                      compile_step: bool | None = None, progress: bool = False) -> PolicyValidation:
    """:func:`validate_policy` for each policy of ``policy_paths`` (one regime, one env config) on
    the same episodes, PD flown once, with the per-episode table against the flight envelope.

    ``estimator_path``: default each policy's own; the other arguments as :func:`validate_policy`'s."""
    payloads = [load_policy(path)[1] for path in policy_paths]
    check_policies(policy_paths, payloads, compile_step)
    regime = payloads[0]["env_spec"]["regime"]
    scenarios, override = validation_setup(regime, episodes, quick, monitor)
    config = override(policy_env_config(payloads[0]))  # every policy's (check_policies)
    fly = partial(fly_controllers, regime, scenarios, progress=progress, config_override=override,
                  compile_step=compile_step, log_keys=("step",) + ((MONITOR_KEY,) if monitor is not None else ()))
    # PD ignores its observation, so any of the policies' envs flies the same PD episodes
    pd = fly(policy_paths[0], None, ("pd",))["pd"]
    flown, metrics = {}, {}
    for label, path, payload in zip(policy_labels(policy_paths), policy_paths, payloads):
        flown[label] = fly_policy(fly, path, payload, estimator_path, config)
        metrics[label] = paired_metrics(flown[label], pd)
        if monitor is not None:
            metrics[label].update(monitor_authority(flown[label], pattern_starts(scenarios, config)))
    envelope = flight_envelope(config.vehicle, config.controller)
    speed = pattern_speed(config, regime)
    return PolicyValidation(metrics, episode_table(scenarios, config, speed, envelope, pd, flown), envelope, speed)


def validation_setup(regime: str, episodes: int | None, quick: bool,
                     monitor: MonitorConfig | None) -> tuple[TensorDictBase, Callable[[EnvConfig], EnvConfig]]:
    """The validation episodes (:func:`~quadwind_trl.rl.paired.validation_scenarios`) and the change
    to a policy's env config they fly with: the monitor on, the PPO recipes' quick flights."""
    scenarios = validation_scenarios(regime, episodes)
    changes = [partial(with_monitor, monitor=monitor)] if monitor is not None else []
    if quick:
        scenarios = PPO_QUICK[regime].scenarios(scenarios, DEFAULT_RANGES[regime].top_altitude_m)
        changes.append(PPO_QUICK[regime].config)

    def override(config: EnvConfig) -> EnvConfig:
        for change in changes:
            config = change(config)
        return config

    return scenarios, override


def fly_policy(fly: Callable[..., dict[str, FlightResults]], path: str | Path, payload: dict,
               estimator_path: str | Path | None, config: EnvConfig) -> FlightResults:
    """The policy at ``path`` flown by ``fly`` (``fly_controllers`` with the episodes bound) as it
    trained: the controller of its wind input, its estimator unless ``estimator_path`` is given."""
    spec = payload["env_spec"]
    controller = next(c for c in POLICY_CONTROLLERS if WIND_INPUT[c] == spec.get("wind_input", "estimate"))
    estimator = None if controller == "oracle" else load_estimator(
        spec["regime"], estimator_path or spec.get("estimator_path"), untrained=spec.get("untrained_estimator", False),
        config=config)
    return fly(path, estimator, (controller,))[controller]


def check_policies(paths: Sequence[str | Path], payloads: Sequence[dict], compile_step: bool | None) -> None:
    """A ``ValueError`` naming the policies and the field unless the policies can share PD's
    flights: at least one, none twice, one regime (one validation sweep), one env config (the
    same worlds) and one simulator step (compiled or eager; ``compile_step`` None: as each trained)."""
    if not paths:
        raise ValueError("policy_paths: no policy given; allowed: one or more policy files of one regime")
    resolved = [Path(p).resolve() for p in paths]
    twice = sorted({str(p) for p in paths if resolved.count(Path(p).resolve()) > 1})
    if twice:
        raise ValueError(f"policy_paths: {', '.join(twice)} given more than once; each policy flies once")
    first, regime = paths[0], payloads[0]["env_spec"]["regime"]
    for path, payload in zip(paths[1:], payloads[1:]):
        other = payload["env_spec"]["regime"]
        if other != regime:
            raise ValueError(f"policies of one regime share a validation sweep: {first} has regime={regime!r}, "
                             f"{path} regime={other!r}; validate them separately")
        differ = config_differences(policy_env_config(payloads[0]), policy_env_config(payload))
        if differ:
            raise ValueError(f"{first} and {path} trained on env configs that differ in {', '.join(differ)}: "
                             "PD's episodes would not be the same worlds for both; validate them separately")
        steps = [policy_compile_step(p) if compile_step is None else compile_step for p in (payloads[0], payload)]
        if steps[0] != steps[1]:
            raise ValueError(f"{first} trained with compile_step={steps[0]}, {path} with compile_step={steps[1]}: "
                             "PD flies once for all; pass compile_step=False (--eager) to fly every one eagerly")


def policy_labels(paths: Sequence[str | Path]) -> list[str]:
    """A short name per policy: its file's stem, or its path as given where two stems agree
    (``runs/a/policy.pt``, ``runs/b/policy.pt``)."""
    stems = [Path(p).stem for p in paths]
    return stems if len(set(stems)) == len(stems) else [str(p) for p in paths]


def flight_altitude(scenarios: TensorDictBase, config: EnvConfig) -> torch.Tensor:
    """``[N]`` altitude (m) each episode flies its pattern at: its own for a level pattern, the
    climb's top (``TrajectoryConfig.vertical_top_m``, where its wind is strongest) for a climbing one."""
    level = fixed_altitude_mask(scenarios.device)[scenarios["traj_id"]]
    return torch.where(level, scenarios["altitude_m"], config.trajectories.vertical_top_m)


def episode_envelope(scenarios: TensorDictBase, config: EnvConfig, speed_m_s: float,
                     envelope: FlightEnvelope) -> TensorDict:
    """``[N]`` each episode's :func:`~quadwind_trl.evaluation.envelope.airspeed_demand` at its own
    shear and flight altitude (:func:`flight_altitude`) and its margins to ``envelope``: ``margin``
    (envelope minus the gust demand, positive inside) and ``sustained_margin`` (without the gusts)."""
    at_altitude = scenarios.clone()
    at_altitude["altitude_m"] = flight_altitude(scenarios, config)
    demand = TensorDict(airspeed_demand(at_altitude, config, speed_m_s), batch_size=scenarios.batch_size)
    demand["margin"] = envelope.airspeed_m_s - demand["demand"]
    demand["sustained_margin"] = envelope.airspeed_m_s - demand["sustained"]
    return demand


def _flight_columns(res: FlightResults) -> TensorDict:
    return TensorDict({"rmse_xy": res.rmse_xy, "rmse_z": res.rmse_z, "rmse": res.rmse, "crashed": res.crashed},
                      batch_size=res.rmse.shape)


def episode_table(scenarios: TensorDictBase, config: EnvConfig, speed_m_s: float, envelope: FlightEnvelope,
                  pd: FlightResults, policies: dict[str, FlightResults]) -> TensorDict:
    """``[N]`` per episode: its row in the flown selection (``episode``), the scenario fields that
    identify its case (:data:`SCENARIO_KEYS`, ``altitude_m`` the flight altitude), its demand and
    margins (``envelope``, :func:`episode_envelope`), PD's and each policy's (``policies``, by
    label) RMSEs and crash flag."""
    n = scenarios.batch_size[0]
    table = scenarios.select(*SCENARIO_KEYS).clone()
    table["episode"] = torch.arange(n)
    table["altitude_m"] = flight_altitude(scenarios, config)
    table["envelope"] = episode_envelope(scenarios, config, speed_m_s, envelope)
    table["pd"] = _flight_columns(pd)
    table["policies"] = TensorDict({label: _flight_columns(res) for label, res in policies.items()}, batch_size=[n])
    return table


def group_metrics(policy: TensorDictBase, pd: TensorDictBase) -> dict[str, float | int | None]:
    """A policy against PD on a group of episodes (columns of :func:`episode_table`): improvement
    in mean RMSE (xy, z, total; None for an empty group, which has no mean), wins, crashes and the
    episode count."""
    wins, pairs = win_rate(pd["rmse"], policy["rmse"])
    out: dict[str, float | int | None] = {
        f"improvement_{key}_pct": improvement(pd[key], policy[key]) if pairs else None for key in RMSE_KEYS}
    out.update(wins=wins, episodes=pairs, crashed=int(policy["crashed"].sum()))
    return out


def envelope_split(table: TensorDictBase) -> dict[str, dict]:
    """The episodes ``within`` the envelope (gust margin >= 0) and ``beyond`` it (< 0): their
    count, PD's crashes and each policy's :func:`group_metrics` (by label)."""
    inside = table["envelope", "margin"] >= 0
    out = {}
    for group, mask in (("within", inside), ("beyond", ~inside)):
        rows = table[mask]
        out[group] = {"episodes": int(mask.sum()), "pd_crashed": int(rows["pd", "crashed"].sum()),
                      "policies": {label: group_metrics(rows["policies", label], rows["pd"])
                                   for label in table["policies"].keys()}}
    return out


def episode_rows(table: TensorDictBase) -> list[dict]:
    """:func:`episode_table` as JSON-ready rows, the trajectory by name (an id is only a position
    in this process's registry)."""
    rows = table.tolist(convert_tensors=True)
    for row in rows:
        row["trajectory"] = trajectory_name(row.pop("traj_id"))
    return rows


def monitor_authority(res: FlightResults, pattern_start: torch.Tensor) -> dict[str, float]:
    """The share of scored samples with the monitor active (all episodes together) and the largest
    share in one episode, from a flight record holding :data:`~quadwind_trl.keys.MONITOR_KEY`."""
    scored = scored_samples(res.log, pattern_start)
    active = res.log[MONITOR_KEY].squeeze(-1) & scored
    per_episode = active.sum(-1).double() / scored.sum(-1).clamp_min(1)
    return {"monitor_active_fraction": int(active.sum()) / max(int(scored.sum()), 1),
            "monitor_active_fraction_max": float(per_episode.max())}
